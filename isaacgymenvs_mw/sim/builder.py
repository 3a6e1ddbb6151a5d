"""Robot description (URDF or MJCF) + task settings -> one compiled ``mujoco.MjModel``.

MuJoCo compiles URDF directly, but a URDF cannot say which joints are driven and how, where the floor
is, or which solver to use. We load the file into an ``MjSpec`` and add those from the task YAML.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import mujoco
import numpy as np

DRIVE_MODES = ("none", "effort", "position")

_INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}
_SOLVERS = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}
_CONES = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}

# Collision bits: robot geoms touch only the ground unless self-collisions are asked for.
_GROUND_BIT = 1
_ROBOT_BIT = 2


@dataclass
class JointDrive:
    """How one joint is actuated: 'effort' (torque/force command), 'position' (PD target) or 'none'."""

    mode: str = "none"
    stiffness: float = 0.0
    damping: float = 0.0
    torque_limit: float | None = None  # |force| <= this (a DC motor's continuous limit); None: the joint's own


@dataclass
class GroundPlane:
    friction: float = 1.0
    restitution: float = 0.0  # accepted for IsaacGymEnvs configs; MuJoCo contacts are inelastic by default


@dataclass
class SolverOptions:
    """The task YAML ``sim`` section, in MuJoCo terms."""

    dt: float = 0.005
    gravity: Sequence[float] = (0.0, 0.0, -9.81)
    integrator: str = "implicitfast"
    solver: str = "newton"
    cone: str = "pyramidal"
    iterations: int = 10
    ls_iterations: int = 20
    impratio: float = 1.0
    enable_contacts: bool = True


@dataclass
class ModelRequest:
    """Everything needed to build the task's model."""

    asset_file: Path
    fix_base: bool = True
    collapse_fixed_joints: bool = True
    self_collisions: bool = False
    drives: Mapping[str, JointDrive] = field(default_factory=dict)
    armature: Mapping[str, float] = field(default_factory=dict)
    joint_damping: Mapping[str, float] = field(default_factory=dict)
    ground: GroundPlane | None = None
    base_init_pos: Sequence[float] = (0.0, 0.0, 0.0)
    base_init_quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0)  # MuJoCo order (w, x, y, z)
    contact_bodies: Sequence[str] = ()
    options: SolverOptions = field(default_factory=SolverOptions)


def load_spec(asset_file: Path, collapse_fixed_joints: bool = True) -> mujoco.MjSpec:
    """Parse a URDF or MJCF file; fail with the path when it does not exist."""
    asset_file = Path(asset_file)
    if not asset_file.is_file():
        raise FileNotFoundError(
            f"Asset file not found: '{asset_file}'. Set env.asset.assetRoot / env.asset.assetFileName in the task "
            "YAML to an existing URDF or MJCF file."
        )
    spec = mujoco.MjSpec.from_file(str(asset_file))
    spec.compiler.fusestatic = bool(collapse_fixed_joints)
    return spec


def movable_joint_names(spec: mujoco.MjSpec) -> list[str]:
    """Names of the hinge and slide joints, in the order MuJoCo will lay them out in qpos."""
    return [j.name for j in spec.joints if j.type in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)]


def match_joint_values(
    patterns: Mapping[str, object] | None, joint_names: Sequence[str], key: str, default: object | None = None
) -> dict[str, object]:
    """Resolve a {pattern: value} YAML mapping to {joint: value}.

    A pattern selects the joint of that exact name, or otherwise every joint in whose name it is found as a
    regular expression ("HAA" -> all *_HAA joints, like legged_gym). An exact name wins over patterns; among
    patterns the first in YAML order wins. A pattern that selects no joint is an error naming the key.
    """
    patterns = dict(patterns or {})
    resolved: dict[str, object] = {}
    for pattern in patterns:
        name_matches(pattern, joint_names, key, "joints")
    for name in joint_names:
        if name in patterns:
            resolved[name] = patterns[name]
            continue
        for pattern, value in patterns.items():
            if re.search(pattern, name):
                resolved[name] = value
                break
        else:
            if default is not None:
                resolved[name] = default
    return resolved


def name_matches(pattern: str, names: Sequence[str], key: str, kind: str) -> list[int]:  # kind: "joints", ...
    """Indices of the names ``pattern`` selects: the one of that exact name, or else every name in which it is
    found as a regular expression (the rule of ``match_joint_values``). Selecting nothing is an error naming ``key``.
    """
    if pattern in names:
        return [list(names).index(pattern)]
    try:
        hits = [i for i, name in enumerate(names) if re.search(pattern, name)]
    except re.error as err:
        raise ValueError(f"{key}: '{pattern}' is not a valid regular expression ({err})") from None
    if not hits:
        singular = {"bodies": "body"}.get(kind, kind[:-1])
        raise ValueError(f"{key}: '{pattern}' matches no {singular}. {kind.capitalize()} of this asset: {list(names)}")
    return hits


def build_model(request: ModelRequest) -> mujoco.MjModel:
    """Compile the task's model: asset + base + ground + actuators + contact sensors + solver options."""
    spec = load_spec(request.asset_file, request.collapse_fixed_joints)
    joints = movable_joint_names(spec)
    _check_joint_types(spec, request.asset_file)

    root = _root_body(spec)
    if not request.fix_base:
        root.add_freejoint(name="root")
        root.pos = list(request.base_init_pos)
        root.quat = list(request.base_init_quat)

    _set_collision_filter(spec, request.self_collisions)
    if request.ground is not None:
        spec.worldbody.add_geom(
            name="ground",
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            size=[0.0, 0.0, 0.05],  # zero half-sizes: an infinite plane
            friction=[request.ground.friction, 0.005, 0.0001],
            contype=_GROUND_BIT,
            conaffinity=_ROBOT_BIT | _GROUND_BIT,
            condim=3,
            priority=1,  # the ground's friction decides the contact's friction
        )

    for name, value in request.armature.items():
        spec.joint(name).armature = float(value)
    for name, value in request.joint_damping.items():
        spec.joint(name).damping = [float(value)] + list(spec.joint(name).damping)[1:]

    for name in joints:
        drive = request.drives.get(name, JointDrive())
        _add_actuator(spec, name, drive)

    for body_name in request.contact_bodies:
        if spec.body(body_name) is None:
            raise ValueError(f"contact body '{body_name}' is not a body of {request.asset_file}")
        spec.add_sensor(
            name=f"contact_{body_name}",
            type=mujoco.mjtSensor.mjSENS_CONTACT,
            objtype=mujoco.mjtObj.mjOBJ_BODY,
            objname=body_name,
            # data = force (bit 1), reduce = net force (3), one slot
            intprm=[1 << 1, 3, 1],
        )

    _apply_options(spec, request.options)
    return spec.compile()


def _check_joint_types(spec: mujoco.MjSpec, asset_file: Path) -> None:
    for j in spec.joints:
        if j.type not in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            raise ValueError(
                f"{asset_file}: joint '{j.name}' is a {j.type.name}; only revolute/continuous/prismatic joints are "
                "supported (the floating base is added by the framework when env.asset.fixBaseLink is False)"
            )


def _root_body(spec: mujoco.MjSpec) -> mujoco.MjsBody:
    children = [b for b in spec.bodies if b.parent is not None and b.parent.name == spec.worldbody.name]
    children = [b for b in children if b.name != spec.worldbody.name]
    if len(children) != 1:
        raise ValueError(f"expected one root link under the world, found {[b.name for b in children]}")
    return children[0]


def _set_collision_filter(spec: mujoco.MjSpec, self_collisions: bool) -> None:
    for geom in spec.geoms:
        geom.contype = _ROBOT_BIT if self_collisions else 0
        geom.conaffinity = _GROUND_BIT | (_ROBOT_BIT if self_collisions else 0)


def _add_actuator(spec: mujoco.MjSpec, joint_name: str, drive: JointDrive) -> None:
    if drive.mode not in DRIVE_MODES:
        raise ValueError(f"drive mode '{drive.mode}' of joint '{joint_name}' is not one of {DRIVE_MODES}")
    if drive.mode == "none":
        return
    act = spec.add_actuator(name=joint_name, target=joint_name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    if drive.mode == "effort":
        act.set_to_motor()
    else:
        act.set_to_position(kp=float(drive.stiffness), kv=float(drive.damping))
    # Command ranges stay open: the joint's actuatorfrcrange (URDF effort limit) clamps the force.
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
    if drive.torque_limit is not None:
        # A torque-speed limit (sim/actuators.py) rewrites this range per world and physics step.
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-float(drive.torque_limit), float(drive.torque_limit)]


def _apply_options(spec: mujoco.MjSpec, o: SolverOptions) -> None:
    for key, table in (("integrator", _INTEGRATORS), ("solver", _SOLVERS), ("cone", _CONES)):
        if getattr(o, key) not in table:
            raise ValueError(f"sim.{key}: '{getattr(o, key)}' is not one of {sorted(table)}")
    if o.dt <= 0:
        raise ValueError(f"sim.dt must be > 0, got {o.dt}")
    spec.option.timestep = float(o.dt)
    spec.option.gravity = np.asarray(o.gravity, dtype=float)
    spec.option.integrator = _INTEGRATORS[o.integrator]
    spec.option.solver = _SOLVERS[o.solver]
    spec.option.cone = _CONES[o.cone]
    spec.option.iterations = int(o.iterations)
    spec.option.ls_iterations = int(o.ls_iterations)
    spec.option.impratio = float(o.impratio)
    if not o.enable_contacts:
        spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT

