"""Batched MuJoCo Warp state on the device, seen from torch without copies.

One ``Simulator`` holds ``num_worlds`` copies of one model. Tasks read and write the torch views below in place;
the simulator steps all worlds at once. On CUDA each group of kernels (the physics of one env step, a reset,
a kinematics refresh) is captured once into a CUDA graph and replayed; graphs bake in array pointers, so every
write from torch must be in place (``view[:] = ...``, ``copy_``), never a rebinding.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import mujoco
import numpy as np
import torch
import warp as wp

import mujoco_warp as mjw
from isaacgymenvs_mw.sim.actuators import TorqueSpeedLimit
from isaacgymenvs_mw.sim.cameras import CameraSpec
from isaacgymenvs_mw.sim.velocity_limit import FreeBodyVelocity
from isaacgymenvs_mw.sim.forces import BodyForceRequests, BodyForces
from isaacgymenvs_mw.sim.graph_engine import GraphEngine
from isaacgymenvs_mw.sim.kernels import init_warp
from isaacgymenvs_mw.sim.lookups import Lookups
from isaacgymenvs_mw.sim.memory import check_worlds_fit
from isaacgymenvs_mw.sim.overflow import OverflowWatch
from isaacgymenvs_mw.sim.sensor_registry import SensorRegistry
from isaacgymenvs_mw.sim.sensors import Sensor, SensorContext, sensor_columns
from isaacgymenvs_mw.sim.views import TensorViews
from isaacgymenvs_mw.sim.world_state import WorldState
from isaacgymenvs_mw.utils.config import check_num_envs
from isaacgymenvs_mw.utils.errors import ConfigError


def _wp_device(device: str) -> wp.context.Device:
    init_warp(device)
    return wp.get_device(device)


class Simulator(TensorViews, GraphEngine, WorldState, Lookups, BodyForceRequests, OverflowWatch):
    """``num_worlds`` MuJoCo Warp worlds of one model on one device.

    Its jobs live in the files named for them, as parts this class composes: the torch views and IsaacGym-style
    state tensors (sim/views.py), kernel loading and the CUDA graphs of stepping (sim/graph_engine.py), saving,
    writing and resetting the worlds' state (sim/world_state.py), lookups by name (sim/lookups.py), the body-force
    API (sim/forces.py) and the overflow check (sim/overflow.py). This class builds the device model and data, binds
    the sensors and cameras, and holds the simulator's settings.

    Args:
        mj_model: the compiled host model (also kept for viewers and MuJoCo-C comparisons).
        num_worlds: number of parallel worlds (= numEnvs).
        device: "cpu" or "cuda:N".
        substeps: physics steps per ``simulate()`` call (= controlFrequencyInv).
        nconmax: contacts per world (pooled over worlds by MuJoCo Warp).
        njmax: constraint rows per world.
        per_world_fields: Model fields given one value per world (domain randomisation), e.g. "geom_friction";
            "opt.gravity" gives each world its own gravity.
        use_graphs: capture the physics as CUDA graphs (None: on CUDA devices).
        deterministic: MuJoCo Warp's ``opt.deterministic`` (all ``DeterminismType`` bits): floating-point atomic
            sums in a fixed order. With mujoco-warp 4.0.0 that is not enough for identical GPU runs (its contact and
            constraint sorts are not implemented; docs/config.md, "Deterministic mode"). Costs speed on GPU (12x for
            Go1); the CPU device runs kernels serially and reproduces runs either way.
        torque_speed: {joint: (saturation torque, torque limit, no-load speed)} (``ModelRequest.torque_speed``): the
            drives of these joints follow a DC motor's torque-speed curve (``sim/actuators.py``) at every physics
            step; ``self.torque_speed`` then holds the per-world parameter views, which randomisation may rewrite.
        declared_sensors: the sensors ``mj_model`` was built with (``ModelRequest.all_sensors()``, ``env.cameras``
            included), unbound. The registry ``self.sensors`` binds each to its views (``sensor(name)``) and
            refreshes it in its phase (``Sensor.refresh``): the computed ones by ``sense()``, the cameras by
            ``render_cameras()`` (one render for all). The model's MuJoCo sensors are views by name without it.
    """

    def __init__(
        self,
        mj_model: mujoco.MjModel,
        num_worlds: int,
        device: str = "cpu",
        substeps: int = 1,
        nconmax: int | None = None,
        njmax: int | None = None,
        per_world_fields: Sequence[str] = (),
        use_graphs: bool | None = None,
        deterministic: bool = False,
        declared_sensors: Sequence[Sensor] = (),
        torque_speed: Mapping[str, tuple[float, float, float]] | None = None,
        angular_speed_limits: Mapping[int, float] | None = None,
        free_body_damping: Mapping[int, tuple[float, float]] | None = None,
    ) -> None:
        if substeps < 1:
            raise ConfigError(f"controlFrequencyInv must be >= 1, got {substeps}")
        self.mj_model = mj_model
        # num_worlds is MuJoCo Warp's term (its nworld) and stays the sim layer's; the task side says num_envs and
        # the YAML numEnvs. One check of it for all three (utils/config.py).
        self.num_worlds = check_num_envs(num_worlds, "numEnvs")
        self.substeps = int(substeps)
        self.device = torch.device(device)
        self.wp_device = _wp_device(device)
        self.use_graphs = self.wp_device.is_cuda if use_graphs is None else bool(use_graphs)
        if self.use_graphs and self.wp_device.is_cuda and not wp.is_mempool_enabled(self.wp_device):
            # MuJoCo Warp allocates scratch inside step(); capturing that needs the stream-ordered allocator.
            self.use_graphs = False

        # The limit rewrites each world's force ranges from its own joint speeds: they are per world.
        per_world_fields = tuple(dict.fromkeys((*per_world_fields, *(("actuator_forcerange",) if torque_speed else ()))))
        check_worlds_fit(mj_model, self.num_worlds, self.wp_device, nconmax, njmax)  # before the long allocations
        with wp.ScopedDevice(self.wp_device):
            fields = [f for f in per_world_fields if not f.startswith("opt.")]
            self.model = mjw.put_model(mj_model, batch_sizes={f: self.num_worlds for f in fields})
            if "opt.gravity" in per_world_fields:
                # Option fields are not put_model's to batch; the step reads gravity[world % rows] all the same.
                rows = np.tile(np.asarray(mj_model.opt.gravity, dtype=np.float32), (self.num_worlds, 1))
                self.model.opt.gravity = wp.array(rows, dtype=wp.vec3)
            # Device printf per world per step would serialise the GPU; we poll d.overflow instead.
            self.model.opt.warn_overflow = 0
            # Set before anything is compiled or captured: the bits select the kernels (Warp module options).
            self.model.opt.deterministic = int(mjw.DeterminismType.ALL if deterministic else mjw.DeterminismType.NONE)
            self.data = mjw.make_data(mj_model, nworld=self.num_worlds, nconmax=nconmax, njmax=njmax)
        self._sizes = (nconmax, njmax)
        self._torch_views: dict[int, tuple[wp.array, torch.Tensor]] = {}  # torch_view's
        self._bind_views()
        self._start_graph_engine()
        self._overflow_seen = torch.zeros(self.num_worlds, dtype=torch.int32, device=self.device)
        self.torque_speed: TorqueSpeedLimit | None = self._torque_speed_limit(torque_speed) if torque_speed else None
        self.body_forces: BodyForces | None = None  # made by the first apply_body_forces
        # IsaacGym's velocity rules for free bodies, applied after every physics step (sim/velocity_limit.py):
        # angular_speed_limits {free joint index: rad/s} (max_angular_velocity), free_body_damping {free joint index:
        # (linear, angular)} (linear_damping, angular_damping)
        self.free_body_velocity: FreeBodyVelocity | None = (
            FreeBodyVelocity(mj_model, self.data, self.num_worlds, angular_speed_limits or {}, free_body_damping or {})
            if angular_speed_limits or free_body_damping else None)
        self._body_id_cache: dict[tuple, torch.Tensor] = {}
        # {body of the asset file: the body collapseFixedJoints merged it into}, for the error naming one (lookups)
        self.fused_bodies: dict[str, str] = {}
        self.physics_steps = 0  # total mjw.step calls per world, for tests and benchmarks
        # The sensors' owner: it binds each to a context of what sensors read and keeps the sense and render lists.
        context = SensorContext(mj_model, self.model, self.data, self.device, self.num_worlds, self.sensordata,
                                sensor_columns(mj_model), self.state_views())
        self.sensors = SensorRegistry(context, declared_sensors, self.wp_device)
        # The kernels start compiling now, in the background (the render context above launched its own first): a
        # cold start compiles while the task builds the rest of itself, not after it.
        self._kernel_load = self._start_kernel_load()

    @property
    def deterministic(self) -> bool:
        """Whether MuJoCo Warp runs in its deterministic mode (``opt.deterministic``)."""
        return bool(self.model.opt.deterministic)

    @property
    def dt(self) -> float:
        return float(self.mj_model.opt.timestep)

    def _torque_speed_limit(self, limits: Mapping[str, tuple[float, float, float]]) -> TorqueSpeedLimit:
        """The DC-motor limit of each actuator's joint (``inf``: none); the model compiles the limited actuators
        with ``forcelimited``."""
        m = self.mj_model
        joint_of = [m.joint(int(j)).name for j in m.actuator_trnid[:, 0]]
        params = np.array([limits.get(j, (np.inf,) * 3) for j in joint_of], dtype=np.float64).reshape(-1, 3)
        return TorqueSpeedLimit(m, self.model, self.data, self.num_worlds, self.device,
                                params[:, 0], params[:, 1], params[:, 2])

    def sensor(self, name: str, key: str = "sensor", output: str | None = None) -> torch.Tensor:
        """(num_worlds, ...) torch view of the sensor ``name``: a MuJoCo sensor of the model (an MJCF ``<sensor>``
        or an ``env.sensors`` entry: a slice of ``sensordata``, rewritten in place by each physics step) or a bound
        ``Sensor``'s (``contact_forces``, a slice too; ``height_scan``, refreshed by ``sense()``; an ``env.cameras``
        image, ``output`` one of its outputs, refreshed by ``render_cameras()``); no copy (sim/sensors.py says which
        state each describes). Look it up once and keep it. ``key``: the YAML key that named the sensor, for the
        error when there is none of that name (``sensors.outputs(name)`` lists a sensor's outputs)."""
        return self.sensors.view(name, key, output)

    def sense(self) -> None:
        """The step's sense phase: refresh every computed sensor from the current state (device torch work, no host
        sync, capturable). MuJoCo's sensors need nothing here: the physics step rewrote them."""
        self.sensors.sense()

    @property
    def cameras(self) -> dict[str, CameraSpec]:
        """The model's cameras (``env.cameras``) by name, in YAML order: the sensors the render refreshes
        (``camera_terms(sim.cameras)`` observes them; their images are ``sensor(name, output=...)``)."""
        return self.sensors.cameras

    def render_cameras(self) -> None:
        """The render phase: draw every camera of every world (the sensors refreshed by the render) from the current
        ``qpos`` (poses, BVH refit, render, unpack: one graph replay on CUDA); their views then hold the new
        images."""
        self.sensors.render(self._run)

    def save_model(self, path: str) -> None:
        """Write the compiled host model (nominal values, no per-world randomisation) as MuJoCo's binary ``.mjb``.

        ``mujoco.MjModel.from_binary_path`` loads it back, with the same MuJoCo version, as the very model that was
        trained on: actuators (PD gains), solver options, contact sensors and the floor included.
        """
        mujoco.mj_saveModel(self.mj_model, str(path), None)

    def model_bytes(self) -> bytes:
        """The same ``.mjb`` as ``save_model``, in memory (the caller decides how it reaches the disk)."""
        buffer = np.zeros(mujoco.mj_sizeModel(self.mj_model), dtype=np.uint8)
        mujoco.mj_saveModel(self.mj_model, None, buffer)
        return buffer.tobytes()
