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
    except ValueError as err:  # MuJoCo's parser: a bad attribute, an unknown element, a repeated name, ...
        said, hint = _said_and_hint(err, f"fix the file, or give another with {key}.assetFileName")
        raise ConfigError(f"{key}: MuJoCo cannot load '{asset_file}': {said} ({hint})") from err
    if Path(asset_file).suffix.lower() != ".xml":
        lock_joints(spec, locked_urdf_joints(Path(asset_file)))
    return spec


# What to do about the MuJoCo errors a port meets most, by a phrase of MuJoCo's message.
_HINTS = {
    "repeated name": "give each element its own name in the asset",
    "more than 6 dofs": "the framework gives a floating base (env.asset.fixBaseLink: False) its free joint, so the "
                        "root body must have no joints of its own: set env.asset.fixBaseLink: True or remove them",
    "opening file": "check that the file exists: a path in the asset is relative to the asset's folder (or its "
                    "meshdir)",
    "mesh": "check that the mesh file is one MuJoCo reads (STL, OBJ, MSH) and not empty",
}


def _said_and_hint(err: ValueError, default_hint: str) -> tuple[str, str]:
    """MuJoCo's message on one line (its first two lines: what, and which element), and what to do about it."""
    lines = [line.strip() for line in str(err).strip().splitlines() if line.strip()]
    said = "; ".join(lines[:2]) or type(err).__name__
    return said, next((h for phrase, h in _HINTS.items() if phrase in said.lower()), default_hint)


def compile_error(err: ValueError, asset_file: Path | str) -> ConfigError:
    """MuJoCo's compile error of the model built from ``asset_file`` as one line: its message, and what to do."""
    said, hint = _said_and_hint(err, "fix the asset")
    return ConfigError(f"MuJoCo cannot compile the model of '{asset_file}': {said} ({hint})")
