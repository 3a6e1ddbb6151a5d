"""The simulator layer: the only package that imports mujoco / mujoco_warp."""

from isaacgymenvs_mw.sim.builder import (
    DRIVE_MODES,
    GroundPlane,
    JointDrive,
    ModelRequest,
    SolverOptions,
    build_model,
    load_spec,
    match_joint_values,
    movable_joint_names,
)
from isaacgymenvs_mw.sim.simulator import Simulator

__all__ = [
    "DRIVE_MODES",
    "GroundPlane",
    "JointDrive",
    "ModelRequest",
    "SolverOptions",
    "Simulator",
    "build_model",
    "load_spec",
    "match_joint_values",
    "movable_joint_names",
]
