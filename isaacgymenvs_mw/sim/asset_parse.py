"""Parsing an asset file into a MuJoCo spec: what MuJoCo's parser refuses is one line naming the file, and URDF
joints whose lower and upper limits are equal are locked, as IsaacGym/PhysX treats them.

MuJoCo's URDF importer ignores such a limit ("equal lower and upper limits, limit ignored") and leaves the joint
free to turn, which silently changes a ported robot. Here each one is removed from the spec before it compiles, which
welds its child body to its parent (MuJoCo's fusestatic may then merge the two, as for a URDF fixed joint).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco

from isaacgymenvs_mw.utils.errors import ConfigError

_MOVABLE = ("revolute", "prismatic")


def locked_urdf_joints(urdf_file: Path) -> list[str]:
    """The names of the URDF's revolute and prismatic joints whose <limit> has lower == upper."""
    try:
        root = ET.parse(urdf_file).getroot()
    except (ET.ParseError, OSError):
        return []  # MuJoCo's own parser reports a file it cannot read
    locked = []
    for joint in root.iter("joint"):
        limit = joint.find("limit")
        if joint.get("type") not in _MOVABLE or limit is None:
            continue
        try:
            lower, upper = float(limit.get("lower", "0")), float(limit.get("upper", "0"))
        except ValueError:
            continue
        if lower == upper and joint.get("name"):
            locked.append(joint.get("name"))
    return locked


def lock_joints(spec: mujoco.MjSpec, names: list[str]) -> None:
    """Remove the named joints from ``spec``: their bodies move with their parents."""
    for name in names:
        joint = spec.joint(name)
        if joint is not None:
            spec.delete(joint)


def parse_asset(asset_file: Path, key: str) -> mujoco.MjSpec:
    """``asset_file`` as a spec (MJCF by its .xml extension, else URDF); ``key``: the YAML section naming it."""
    try:
        spec = mujoco.MjSpec.from_file(str(asset_file))
    except ValueError as err:  # MuJoCo's parser: a bad attribute, an unknown element, a file it cannot decode
        first = (str(err).strip() or "parse error").splitlines()[0]
        raise ConfigError(f"{key}: MuJoCo cannot load '{asset_file}': {first} (fix the file, or give another with "
                          f"{key}.assetFileName)") from err
    if Path(asset_file).suffix.lower() != ".xml":
        lock_joints(spec, locked_urdf_joints(Path(asset_file)))
    return spec
