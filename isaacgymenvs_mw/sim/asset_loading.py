"""Loading an asset (URDF or MJCF) into an ``MjSpec``, reading its joints and actuators, placing its root body
(fixed or floating) and attaching a scene asset (``env.assets``) under its name prefix (sim/builder.py composes the
model)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco

from isaacgymenvs_mw.sim.asset_parse import parse_asset
from isaacgymenvs_mw.sim.ground import GROUND_BIT, ROBOT_BIT
from isaacgymenvs_mw.sim.scene import SCENE_TEXT_PREFIX
from isaacgymenvs_mw.utils.errors import ConfigError, MissingFileError


@dataclass
class SceneAsset:
    """One asset of a scene beside the main one (``env.assets.<name>``): attached to the main model with every
    body, joint, geom, site, actuator and sensor name prefixed by ``prefix``.

    Its own actuators and sensors come along (after the main asset's actuators); YAML drives are the main asset's
    only. A free asset (``fix_base`` False) gets a free joint named ``<prefix>root`` unless its root body has one.
    """

    name: str
    asset_file: Path
    prefix: str
    fix_base: bool = False
    # The root body's pose in the world (w, x, y, z); None keeps the file's (as env.baseInitState for the main one).
    pos: Sequence[float] | None = None
    quat: Sequence[float] | None = None
    # True: the asset's own contype/conaffinity stay; False: its geoms collide as the ground does (with the main
    # asset, the ground and the other objects).
    keep_asset_contacts: bool = False
    spec: mujoco.MjSpec | None = None  # the parsed file (sim/request.py parses it once); None: parse asset_file
    max_angular_velocity: float | None = None  # rad/s cap on its free body's angular speed (sim/velocity_limit.py)
    damping: tuple[float, float] = (0.0, 0.0)  # its free body's (linear, angular) velocity damping, 1/s (likewise)


def load_spec(asset_file: Path, collapse_fixed_joints: bool = True, key: str = "env.asset") -> mujoco.MjSpec:
    """Parse a URDF or MJCF file; fail with the path when it does not exist (``key``: the YAML section naming it)."""
    asset_file = Path(asset_file)
    if not asset_file.is_file():
        raise MissingFileError(
            f"Asset file not found: '{asset_file}'. Set {key}.assetRoot / {key}.assetFileName in the task "
            "YAML to an existing URDF or MJCF file."
        )
    spec = parse_asset(asset_file, key)  # a file MuJoCo refuses is one line; URDF joints with lower == upper locked
    spec.compiler.fusestatic = bool(collapse_fixed_joints)
    return spec


def movable_joint_names(spec: mujoco.MjSpec) -> list[str]:
    """Names of the hinge and slide joints, in the order MuJoCo will lay them out in qpos."""
    return [j.name for j in spec.joints if j.type in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)]


def is_mjcf(asset_file: Path) -> bool:
    """MJCF by extension (``.xml``); everything else (``.urdf``) is compiled as URDF by MuJoCo."""
    return Path(asset_file).suffix.lower() == ".xml"


def actuated_joints(spec: mujoco.MjSpec) -> dict[str, str]:
    """{joint: actuator} for the joints that the asset's own actuators drive (joint transmissions)."""
    out: dict[str, str] = {}
    for act in spec.actuators:
        if act.trntype == mujoco.mjtTrn.mjTRN_JOINT and act.target:
            out.setdefault(act.target, act.name)
    return out


def check_joint(spec: mujoco.MjSpec, name: str, key: str) -> None:
    if spec.joint(name) is None:
        raise ConfigError(f"{key}: '{name}' is not a joint of the asset; joints: {movable_joint_names(spec)}")


def _check_joint_types(spec: mujoco.MjSpec, asset_file: Path, root: mujoco.MjsBody) -> bool:
    """Only hinge/slide joints, plus at most a free joint on the root body (the floating base); True if it has one."""
    free_root = False
    for j in spec.joints:
        if j.type in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            continue
        if j.type == mujoco.mjtJoint.mjJNT_FREE and j.parent.name == root.name and not free_root:
            free_root = True
            continue
        raise ConfigError(
            f"{asset_file}: joint '{j.name}' is a {j.type.name}; only revolute/continuous/prismatic (hinge/slide) "
            "joints are supported, plus one free joint on the root body (the floating base; without it the "
            "framework adds one when env.asset.fixBaseLink is False)"
        )
    if free_root and next(iter(root.joints)).type != mujoco.mjtJoint.mjJNT_FREE:
        raise ConfigError(f"{asset_file}: the free joint of root body '{root.name}' must be its first joint")
    return free_root


def place_root(spec: mujoco.MjSpec, asset_file: Path, fix_base: bool, pos: Sequence[float] | None,
               quat: Sequence[float] | None, key: str) -> mujoco.MjsBody:
    """Fixed or free root body (a free joint added where the asset has none) at ``pos`` / ``quat`` where given."""
    root = _root_body(spec)
    has_free_root = _check_joint_types(spec, asset_file, root)
    if has_free_root and fix_base:
        raise ConfigError(
            f"{asset_file}: the root body '{root.name}' has a free joint (a floating base) but "
            f"{key}.fixBaseLink is True; set fixBaseLink: False, or remove the free joint to weld it to the world"
        )
    if not fix_base and not has_free_root:
        root.add_freejoint(name="root")
    if pos is not None:
        root.pos = list(pos)
    if quat is not None:
        root.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT  # replaces an euler/axisangle in the file
        root.quat = list(quat)
    return root


def attach(spec: mujoco.MjSpec, asset: SceneAsset) -> None:
    """Attach one scene asset's root body (and the actuators, sensors and assets that refer to its subtree) under
    the world body, every name prefixed; record its name and prefix in the model."""
    key = f"env.assets.{asset.name}"
    # Fixed joints are collapsed (or not) as the main asset says: fusestatic is one compiler flag for the model.
    child = asset.spec.copy() if asset.spec is not None else load_spec(asset.asset_file, spec.compiler.fusestatic,
                                                                       key)
    root = place_root(child, asset.asset_file, asset.fix_base, asset.pos, asset.quat, key)
    if not asset.keep_asset_contacts:
        # Like the ground (bit 1 both ways): the main asset's geoms (conaffinity holds bit 1), the ground and the
        # other objects all meet it.
        for geom in child.geoms:
            geom.contype = GROUND_BIT
            geom.conaffinity = GROUND_BIT | ROBOT_BIT
    spec.worldbody.add_frame().attach_body(root, asset.prefix, "")
    spec.add_text(name=f"{SCENE_TEXT_PREFIX}{asset.name}", data=asset.prefix)


def _root_body(spec: mujoco.MjSpec) -> mujoco.MjsBody:
    children = [b for b in spec.bodies if b.parent is not None and b.parent.name == spec.worldbody.name]
    children = [b for b in children if b.name != spec.worldbody.name]
    if len(children) != 1:
        raise ConfigError(f"expected one root link under the world, found {[b.name for b in children]}")
    return children[0]

