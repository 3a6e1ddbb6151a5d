"""The actuators of the main asset: one per movable joint, as the YAML drives it (``effort``, ``position`` or
``none``; ``env.control.driveMode``), the asset's own actuators rewritten in place where the YAML drives their joint,
and the YAML's ``gear`` / ``ctrlRange`` applied to the actuators they select (sim/builder.py composes the model)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import mujoco

from isaacgymenvs_mw.sim.asset_loading import actuated_joints, check_joint
from isaacgymenvs_mw.sim.names import compile_pattern, no_match_error
from isaacgymenvs_mw.utils.errors import ConfigError

DRIVE_MODES = ("none", "effort", "position")


@dataclass
class JointDrive:
    """How one joint is actuated: 'effort' (torque/force command), 'position' (PD target) or 'none'."""

    mode: str = "none"
    stiffness: float = 0.0
    damping: float = 0.0
    torque_limit: float | None = None  # |force| <= this (a DC motor's continuous limit); None: the joint's own


def add_drives(spec: mujoco.MjSpec, joints: Sequence[str], drives: Mapping[str, JointDrive],
               gear: Mapping[str, float], ctrl_range: Mapping[str, Sequence[float]]) -> None:
    """The YAML's ``drives`` on the movable ``joints``, then ``gear`` and ``ctrl_range`` on the actuators."""
    owned = actuated_joints(spec)
    for name in drives:
        check_joint(spec, name, "env.control.driveMode")
    # A YAML drive on a joint the asset's own actuator drives rewrites that actuator in place (its name, ctrl column
    # and force range stay): one actuator per joint, so ctrl[:, i] never silently reaches only one of two.
    for name, drive in drives.items():
        if name in owned:
            _rewrite_actuator(spec.actuator(owned[name]), spec.joint(name), drive)
    for name in joints:
        if name not in owned:
            _add_actuator(spec, name, drives.get(name, JointDrive()))
    _override_actuators(spec, gear, "env.control.gear", _set_gear)
    _override_actuators(spec, ctrl_range, "env.control.ctrlRange", _set_ctrl_range)


def _add_actuator(spec: mujoco.MjSpec, joint_name: str, drive: JointDrive) -> None:
    if drive.mode not in DRIVE_MODES:
        raise ConfigError(f"drive mode '{drive.mode}' of joint '{joint_name}' is not one of {DRIVE_MODES}")
    if drive.mode == "none":
        return
    joint = spec.joint(joint_name)
    if drive.mode == "effort" and drive.torque_limit is None and not _force_capped(joint):
        raise ConfigError(
            f"env.control.driveMode: joint '{joint_name}' has an effort drive but no torque cap: the asset gives "
            "none (URDF <limit effort>, MJCF actuatorfrcrange); set env.control.effortLimit: {" + joint_name
            + ": <N m>}"
        )
    act = spec.add_actuator(name=joint_name, target=joint_name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    if drive.mode == "effort":
        act.set_to_motor()
    else:
        act.set_to_position(kp=float(drive.stiffness), kv=float(drive.damping))
    # Command ranges stay open: the joint's actuatorfrcrange (URDF effort limit / effortLimit) clamps the force.
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
    if drive.torque_limit is not None:
        # A torque-speed limit (sim/actuators.py) rewrites this range per world and physics step.
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-float(drive.torque_limit), float(drive.torque_limit)]


def _rewrite_actuator(act: mujoco.MjsActuator, joint: mujoco.MjsJoint, drive: JointDrive) -> None:
    """Turn the asset's own actuator on ``joint_name`` into the YAML's drive, keeping its name, ctrl column and
    force range: ``position`` -> a PD servo with the YAML gains, ``effort`` -> a motor (commands uncapped, the force
    capped by the actuator's forcerange or the joint's actuatorfrcrange)."""
    joint_name = joint.name
    if drive.mode not in DRIVE_MODES:
        raise ConfigError(f"drive mode '{drive.mode}' of joint '{joint_name}' is not one of {DRIVE_MODES}")
    if drive.mode == "none":
        raise ConfigError(
            f"env.control.driveMode: joint '{joint_name}' is driven by the asset's own actuator '{act.name}', which "
            "a drive mode of 'none' cannot remove: give 'position' or 'effort', or remove the entry"
        )
    if drive.mode == "effort":
        capped = act.forcelimited != mujoco.mjtLimited.mjLIMITED_FALSE and act.forcerange[0] < act.forcerange[1]
        if not (capped or _force_capped(joint)) and drive.torque_limit is None:
            raise ConfigError(
                f"env.control.driveMode: joint '{joint_name}' has an effort drive but its actuator '{act.name}' "
                "and its joint have no force range: set env.control.effortLimit: {" + joint_name + ": <N m>}"
            )
        act.set_to_motor()
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE  # a range of joint targets must not clamp torques
    else:
        act.set_to_position(kp=float(drive.stiffness), kv=float(drive.damping))  # the ctrlrange of targets stays
    if drive.torque_limit is not None:
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-float(drive.torque_limit), float(drive.torque_limit)]


def _force_capped(joint: mujoco.MjsJoint) -> bool:
    lo, hi = (float(v) for v in joint.actfrcrange)
    return joint.actfrclimited != mujoco.mjtLimited.mjLIMITED_FALSE and lo < hi


def _override_actuators(spec: mujoco.MjSpec, patterns: Mapping[str, object], key: str, apply) -> None:
    """Apply {pattern: value} to the actuators selected (``name_matches``' rule: a full match of the actuator's own
    name or of the joint it drives)."""
    actuators = list(spec.actuators)
    for pattern, value in (patterns or {}).items():
        regex = compile_pattern(pattern, key)
        hits = [a for a in actuators if any(n and regex.fullmatch(n) for n in (a.name, a.target))]
        if not hits:
            raise no_match_error(key, pattern, "actuators", [f"{a.name} -> {a.target}" for a in actuators],
                                 " by actuator name or by the joint it drives")
        for act in hits:
            apply(act, value, f"{key}.{pattern}")


def _set_gear(act: mujoco.MjsActuator, value: object, key: str) -> None:
    try:
        gear = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{key}={value!r} is invalid: give a number (the actuator's gear ratio)") from None
    act.gear = [gear] + [0.0] * 5


def _set_ctrl_range(act: mujoco.MjsActuator, value: object, key: str) -> None:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ConfigError(f"{key}={value!r} is invalid: give [low, high]") from None
    if not lo < hi:
        raise ConfigError(f"{key}={value!r} is invalid: low must be < high")
    act.ctrlrange = [lo, hi]
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE

