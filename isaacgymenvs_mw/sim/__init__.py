"""The simulator layer: the only package that imports mujoco / mujoco_warp."""

import os as _os
import sys as _sys


def _choose_mujoco_gl() -> None:
    """Pick MuJoCo's headless OpenGL backend before mujoco is first imported (it reads MUJOCO_GL on import).

    Only on Linux without a display, and never over a MUJOCO_GL the user set: EGL where an NVIDIA GPU is visible,
    OSMesa otherwise. A backend whose library is missing is not chosen: mujoco's import would then fail outright,
    and only video recording needs one (sim/video.py says what to install).
    """
    if _os.environ.get("MUJOCO_GL") or not _sys.platform.startswith("linux"):
        return
    if _os.environ.get("DISPLAY") or _os.environ.get("WAYLAND_DISPLAY"):
        return
    from ctypes.util import find_library

    if _os.path.exists("/dev/nvidia0") and find_library("EGL"):
        _os.environ["MUJOCO_GL"] = "egl"
    elif find_library("OSMesa"):
        _os.environ["MUJOCO_GL"] = "osmesa"


_choose_mujoco_gl()

from isaacgymenvs_mw.sim.gl import import_mujoco  # noqa: E402

import_mujoco()  # a MUJOCO_GL whose library is missing: one line saying what to install, not PyOpenGL's traceback

from isaacgymenvs_mw.sim.builder import (  # noqa: E402
    DRIVE_MODES,
    GroundPlane,
    JointDrive,
    ModelRequest,
    SceneAsset,
    SolverOptions,
    actuated_joints,
    build_model,
    is_mjcf,
    load_spec,
    match_body_names,
    match_joint_numbers,
    match_joint_values,
    movable_joint_names,
)
from isaacgymenvs_mw.sim.kernels import set_verbose  # noqa: E402
from isaacgymenvs_mw.sim.names import name_matches  # noqa: E402
from isaacgymenvs_mw.sim.randomization import InertiaConstants, model_names  # noqa: E402
from isaacgymenvs_mw.sim.request import (  # noqa: E402
    SIM_KEYS,
    asset_path,
    check_sim_keys,
    request_from_config,
    sim_dt,
    solver_options,
    torque_speed_limits,
)
from isaacgymenvs_mw.sim.scene import AssetView  # noqa: E402
from isaacgymenvs_mw.sim.sensors import (  # noqa: E402
    SENSOR_TYPES,
    ContactForces,
    HeightScan,
    Sensor,
    SensorSpec,
    sensor_specs,
)
from isaacgymenvs_mw.sim.simulator import Simulator  # noqa: E402
from isaacgymenvs_mw.sim.terrain import (  # noqa: E402
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
    "SensorSpec",
    "sensor_specs",
    "asset_path",
    "check_sim_keys",
    "request_from_config",
    "sim_dt",
    "solver_options",
    "torque_speed_limits",
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
