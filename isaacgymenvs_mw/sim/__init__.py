"""The simulator layer: the only package that imports mujoco / mujoco_warp."""

# No OpenGL backend is chosen here: importing the package (or make(), or the tests) loads no GL library. Only video
# recording needs one, and sim/video.py chooses it when a recorder starts: OSMesa's LLVM, loaded at import, crashed
# processes that later loaded a CUDA build of torch's Triton.
from isaacgymenvs_mw.sim.gl import import_mujoco  # noqa: E402

import_mujoco()  # a MUJOCO_GL you set whose library is missing: one line saying what to install, not a traceback

from isaacgymenvs_mw.sim.asset_loading import (  # noqa: E402
    SceneAsset,
    actuated_joints,
    is_mjcf,
    load_spec,
    movable_joint_names,
)
from isaacgymenvs_mw.sim.builder import ModelRequest, build_model
from isaacgymenvs_mw.sim.drives import DRIVE_MODES, JointDrive
from isaacgymenvs_mw.sim.ground import GroundPlane
from isaacgymenvs_mw.sim.joint_tables import (
    match_body_names,
    match_joint_numbers,
    match_joint_values,
)
from isaacgymenvs_mw.sim.kernels import set_verbose
from isaacgymenvs_mw.sim.names import name_matches
from isaacgymenvs_mw.sim.options import SolverOptions
from isaacgymenvs_mw.sim.randomization import InertiaConstants, model_names
from isaacgymenvs_mw.sim.request import (
    SIM_KEYS,
    asset_path,
    check_sim_keys,
    request_from_config,
    sim_dt,
    solver_options,
    torque_speed_limits,
)
from isaacgymenvs_mw.sim.scene import AssetView
from isaacgymenvs_mw.sim.sensor_registry import SensorRegistry
from isaacgymenvs_mw.sim.sensors import (
    SENSOR_TYPES,
    ContactForces,
    HeightScan,
    Sensor,
    SensorContext,
    SensorSpec,
    sensor_specs,
)
from isaacgymenvs_mw.sim.simulator import Simulator
from isaacgymenvs_mw.sim.velocity_limit import free_joint_damping, free_joint_speed_limits
from isaacgymenvs_mw.sim.terrain import (
    TERRAIN_TYPES,
    Terrain,
    TerrainConfig,
    generate_terrain,
    ground_geoms,
    heightfield_grid,
    parse_terrain_config,
)

__all__ = [
    "AssetView",
    "DRIVE_MODES",
    "SIM_KEYS",
    "SceneAsset",
    "SENSOR_TYPES",
    "ContactForces",
    "HeightScan",
    "Sensor",
    "SensorContext",
    "SensorRegistry",
    "SensorSpec",
    "sensor_specs",
    "asset_path",
    "check_sim_keys",
    "request_from_config",
    "sim_dt",
    "solver_options",
    "torque_speed_limits",
    "free_joint_damping",
    "free_joint_speed_limits",
    "GroundPlane",
    "InertiaConstants",
    "JointDrive",
    "ModelRequest",
    "SolverOptions",
    "Simulator",
    "actuated_joints",
    "build_model",
    "is_mjcf",
    "load_spec",
    "match_body_names",
    "match_joint_numbers",
    "match_joint_values",
    "model_names",
    "movable_joint_names",
    "set_verbose",
    "name_matches",
    "TERRAIN_TYPES",
    "Terrain",
    "TerrainConfig",
    "generate_terrain",
    "ground_geoms",
    "heightfield_grid",
    "parse_terrain_config",
]
