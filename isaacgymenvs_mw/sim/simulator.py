"""Batched MuJoCo Warp state on the device, seen from torch without copies.

One ``Simulator`` holds ``num_worlds`` copies of one model. Tasks read and write the torch views below in place;
the simulator steps all worlds at once. On CUDA each group of kernels (the physics of one env step, a reset,
a kinematics refresh) is captured once into a CUDA graph and replayed; graphs bake in array pointers, so every
write from torch must be in place (``view[:] = ...``, ``copy_``), never a rebinding.
"""

from __future__ import annotations

import itertools
import warnings
import weakref
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import mujoco
import numpy as np
import torch
import warp as wp

import mujoco_warp as mjw
from isaacgymenvs_mw.sim.actuators import TorqueSpeedLimit
from isaacgymenvs_mw.sim.cameras import Cameras, CameraView
from isaacgymenvs_mw.sim.forces import FRAMES, BodyForces
from isaacgymenvs_mw.sim.kernels import KernelLoad, init_warp
from isaacgymenvs_mw.sim.memory import check_worlds_fit
from isaacgymenvs_mw.sim.scene import SCENE_TEXT_PREFIX, AssetView, main_ends, main_joints, scene_prefixes
from isaacgymenvs_mw.sim.sensors import REFRESH_PHASES, Sensor, SensorViews
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import quat_rotate

# A world with any joint speed above this (m/s or rad/s) has diverged and is reset as a NaN one is. Such speeds are
# physically meaningless at millisecond steps (50 m per 5 ms step), and a world one step from NaN can hold 1e7: its
# squared penalty (dof_acc) pushed a logged per-episode mean to -1.5e7 on the GPU and spiked PPO's value loss.
DIVERGED_SPEED = 1.0e4
# A world with an equality constraint (a pinned foot, a closed chain) violated by more than this has diverged too:
# MuJoCo's constraint residual of any one equality row (efc_pos: m for connect and weld positions, rad for weld
# orientations and joint equalities). Soft constraints under load give millimetres; a closed chain whose drives
# diverge can drift metres apart at finite, modest speeds (sim/stability.py).
EQUALITY_DIVERGED = 0.1
# The constraint type of an equality row, as a plain int read once: the compiled step must not convert MuJoCo's enum
# itself (torch.compile's tracing of int() on it recursed without end under torch 2.13).
_EQUALITY_ROW = int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)

# Overflow bits we report, and the task YAML key that fixes each.
_OVERFLOW_KEYS = {
    int(mjw.OverflowType.NEFC): "sim.njmax",
    int(mjw.OverflowType.BROADPHASE): "sim.nconmax",
    int(mjw.OverflowType.NARROWPHASE): "sim.nconmax",
    int(mjw.OverflowType.CONTACT_MATCH): "sim.nconmax",
    # More heightfield prisms touch one geom than MuJoCo keeps per pair: a coarser terrain grid has fewer.
    int(mjw.OverflowType.HFIELD): "env.terrain.horizontalScale",
}


# A kinematics refresh inside the compiled post-physics step (a reset that writes qpos and then observes body or site
# poses): torch.compile cannot trace Warp's launches, so there the refresh is an op of the graph (``_kinematics_op``)
# that names what MuJoCo Warp's ``kinematics`` reads and writes, for torch to keep it in order with the torch work
# around it. Data fields it reads, Model fields it reads that torch may write (the randomiser's), Data fields it writes:
_KINEMATICS_READS = ("qpos", "mocap_pos", "mocap_quat")
_KINEMATICS_MODEL_READS = ("qpos0", "body_pos", "body_quat", "body_ipos", "body_iquat", "jnt_pos", "jnt_axis",
                           "geom_pos", "geom_quat", "site_pos", "site_quat")
_KINEMATICS_WRITES = ("xpos", "xquat", "xanchor", "xaxis", "xmat", "xipos", "ximat", "geom_xpos", "geom_xmat",
                      "site_xpos", "site_xmat")
# The op's int argument names its simulator.
_SIMULATORS: weakref.WeakValueDictionary[int, Simulator] = weakref.WeakValueDictionary()
_SIMULATOR_IDS = itertools.count()


@torch.library.custom_op("isaacgymenvs_mw::kinematics", mutates_args=("poses",))
def _kinematics_op(sim: int, state: list[torch.Tensor], poses: list[torch.Tensor]) -> None:
    _SIMULATORS[sim]._kinematics_on(state, poses)


@_kinematics_op.register_fake
def _(sim: int, state: list[torch.Tensor], poses: list[torch.Tensor]) -> None:
    return None


@dataclass
class ContactSensor:
    body: str
    adr: int


def _wp_device(device: str) -> wp.context.Device:
    init_warp(device)
    return wp.get_device(device)


class Simulator:
    """``num_worlds`` MuJoCo Warp worlds of one model on one device.

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
        sensors: the sensors ``mj_model`` was built with (``ModelRequest.all_sensors()``, ``env.cameras`` included):
            each is bound to its views (``sensor(name)``) and refreshed in its phase (``Sensor.refresh``): the computed
            ones by ``sense()``, the cameras by ``render_cameras()`` (one render for all). The model's MuJoCo sensors
            are views by name without it.
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
        sensors: Sequence[Sensor] = (),
        torque_speed: Mapping[str, tuple[float, float, float]] | None = None,
    ) -> None:
        if num_worlds < 1:
            raise ConfigError(f"numEnvs must be >= 1, got {num_worlds}")
        if substeps < 1:
            raise ConfigError(f"controlFrequencyInv must be >= 1, got {substeps}")
        self.mj_model = mj_model
        self.num_worlds = int(num_worlds)
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
        # Kernels load on the first launch, or earlier when the owner calls load_kernels (VecTask does, so that it can
        # compile its step meanwhile).
        self._sizes = (nconmax, njmax)
        self._kernels_recorded: bool | None = None  # None: not loaded yet
        self._kernel_load: KernelLoad | None = None

        self._torch_views: dict[int, tuple[wp.array, torch.Tensor]] = {}  # torch_view's
        self._bind_views()
        self._id = next(_SIMULATOR_IDS)
        _SIMULATORS[self._id] = self
        self._overflow_seen = torch.zeros(self.num_worlds, dtype=torch.int32, device=self.device)
        self._graphs: dict[str, object] = {}
        self.torque_speed: TorqueSpeedLimit | None = self._torque_speed_limit(torque_speed) if torque_speed else None
        self.body_forces: BodyForces | None = None  # made by the first apply_body_forces
        self._body_id_cache: dict[tuple, torch.Tensor] = {}
        self.physics_steps = 0  # total mjw.step calls per world, for tests and benchmarks
        names = [s.name for s in sensors]
        for sensor in sensors:
            if names.count(sensor.name) > 1:
                raise ConfigError(f"two sensors of the model are named {sensor.name!r} (sensors and cameras share one "
                                  "namespace); give one another name")
            if sensor.refresh not in REFRESH_PHASES:
                raise ValueError(f"sensor {sensor.name!r}: refresh={sensor.refresh!r}; give one of {REFRESH_PHASES}")
        # The render phase: one render context draws every rendered sensor (a camera of the model) at once.
        rendered = [s for s in sensors if s.refresh == "render"]
        self.cameras: Cameras | None = None
        if rendered:
            self.cameras = Cameras(mj_model, self.model, self.data, rendered, self.num_worlds, self.wp_device)
        for sensor in sensors:
            self.sensors.add(sensor, sensor.bind(self))
        self._computed_sensors = [s for s in sensors if s.refresh == "sense" and type(s).sense is not Sensor.sense]
        # The kernels start compiling now, in the background (the render context above launched its own first): a
        # cold start compiles while the task builds the rest of itself, not after it.
        self._kernel_load = self._start_kernel_load()

    def load_kernels(self, alongside: Callable[[], None] | None = None) -> None:
        """Compile every kernel module that stepping, forward and kinematics use, in parallel, before the first launch
        (a dry run on scratch data of one world records them; see sim/kernels.py). ``alongside`` runs in this thread
        meanwhile and must not launch Warp kernels; its exceptions and the compiler's are raised here.

        Loads once: a later call only runs ``alongside``. The first launch through the simulator calls it when its
        owner has not."""
        if self._kernels_recorded is not None:
            if alongside is not None:
                alongside()
            return
        load, self._kernel_load = self._kernel_load or self._start_kernel_load(), None
        with wp.ScopedDevice(self.wp_device):
            loaded = load.wait(alongside)
        self._kernels_recorded = loaded is not None

    def _start_kernel_load(self) -> KernelLoad:
        """Record the modules of step, forward and kinematics (a dry run on scratch data of one world) and start
        compiling them on a pool of threads (sim/kernels.py); ``load_kernels`` waits for them."""
        with wp.ScopedDevice(self.wp_device):
            scratch = mjw.make_data(self.mj_model, nworld=1, nconmax=self._sizes[0], njmax=self._sizes[1])
            entry_points = [lambda: mjw.step(self.model, scratch), lambda: mjw.forward(self.model, scratch),
                            lambda: mjw.kinematics(self.model, scratch)]
            return KernelLoad(self.wp_device, entry_points)

    # ------------------------------------------------------------------ views
    def _bind_views(self) -> None:
        d, m = self.data, self.mj_model
        self.qpos = self.torch_view(d.qpos)
        self.qvel = self.torch_view(d.qvel)
        self.ctrl = self.torch_view(d.ctrl)
        self.qacc = self.torch_view(d.qacc)
        self.qfrc_actuator = self.torch_view(d.qfrc_actuator)
        self.actuator_force = self.torch_view(d.actuator_force)  # per actuator, after its force range
        self.xpos = self.torch_view(d.xpos)
        self.xquat = self.torch_view(d.xquat)
        self.xipos = self.torch_view(d.xipos)  # centres of mass, world frame
        self.xmat = self.torch_view(d.xmat)  # (N, nbody, 3, 3) body orientations: columns are the body axes, world
        self.site_xpos = self.torch_view(d.site_xpos)  # (N, nsite, 3) site positions, world frame
        self.site_xmat = self.torch_view(d.site_xmat)  # (N, nsite, 3, 3) site orientations
        # (N, nmocap, 3) / (N, nmocap, 4) poses of the mocap bodies (world frame, (w, x, y, z)): bodies a task moves
        # by writing them (a goal marker), not the physics; the next step's kinematics reads them.
        self.mocap_pos = self.torch_view(d.mocap_pos)
        self.mocap_quat = self.torch_view(d.mocap_quat)
        # Body velocities as MuJoCo keeps them: (angular, linear) in world axes, about the subtree centre of mass of
        # the body's root (see body_lin_vel).
        self.cvel = self.torch_view(d.cvel)
        self.subtree_com = self.torch_view(d.subtree_com)
        self._body_rootid = torch.tensor(m.body_rootid, device=self.device, dtype=torch.long)
        self.sensordata = self.torch_view(d.sensordata)
        self.sensors = SensorViews(m, self.sensordata)  # named slices of sensordata: self.sensor(name)
        self.xfrc_applied = self.torch_view(d.xfrc_applied)
        self.overflow = self.torch_view(d.overflow)
        self._qpos0 = self.torch_view(self.model.qpos0)
        self._kinematics_state = tuple(self.torch_view(getattr(d, f)) for f in _KINEMATICS_READS) + tuple(
            self.model_field(f) for f in _KINEMATICS_MODEL_READS)
        self._kinematics_poses = tuple(self.torch_view(getattr(d, f)) for f in _KINEMATICS_WRITES)
        # Equality-constraint rows of the last step's constraint set (MuJoCo Warp keeps them per world, computed at
        # the start of the step from its state): read by equality_violation, only in models that have any.
        self._efc = None
        if m.neq:
            efc_type = self.torch_view(d.efc.type)
            self._efc = (efc_type, self.torch_view(d.efc.id), self.torch_view(d.efc.pos),
                         self.torch_view(d.nefc), torch.arange(efc_type.shape[1], device=self.device))
        # What one physics step hands to the next; everything else (poses, contacts, sensors) is recomputed.
        self._carried_state = {
            "qpos": self.qpos, "qvel": self.qvel, "ctrl": self.ctrl, "act": self.torch_view(d.act),
            "qacc_warmstart": self.torch_view(d.qacc_warmstart), "time": self.torch_view(d.time),
            "xfrc_applied": self.xfrc_applied, "qfrc_applied": self.torch_view(d.qfrc_applied),
        }
        # A reset zeroes all carried state but the positions (set to qpos0), and the sensors and overflow bits.
        self._zeroed_on_reset = [view for name, view in self._carried_state.items() if name != "qpos"]
        self._zeroed_on_reset += [self.sensordata, self.overflow]

        # The main asset (env.asset) owns the unprefixed names and the first qpos columns; the Simulator's own
        # dof and root views are its. Each env.assets entry has an AssetView (self.asset(name)).
        prefixes = scene_prefixes(m, SCENE_TEXT_PREFIX)
        self.assets = {name: AssetView(name, prefix, m, self.qpos, self.qvel, self.ctrl)
                       for name, prefix in prefixes.items()}
        main = main_joints(m, list(prefixes.values()))
        self.floating_base = bool(main) and int(m.jnt_type[main[0]]) == int(mujoco.mjtJoint.mjJNT_FREE)
        q0, v0 = (7, 6) if self.floating_base else (0, 0)
        q1, v1 = main_ends(m, main)
        self.dof_pos = self.qpos[:, q0:q1]
        self.dof_vel = self.qvel[:, v0:v1]
        if self.floating_base:
            self.root_pos = self.qpos[:, 0:3]
            self.root_quat = self.qpos[:, 3:7]  # (w, x, y, z)
            self.root_lin_vel = self.qvel[:, 0:3]  # world frame
            self.root_ang_vel = self.qvel[:, 3:6]  # body frame (MuJoCo free-joint convention)

        self.dof_names = [  # the main asset's hinge and slide joints: the columns of dof_pos
            mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
            for j in main
            if int(m.jnt_type[j]) in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
        ]
        self.body_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(m.nbody)]
        # ctrl[:, i] is the command of actuator i: the asset's own actuators in file order, then one per joint the
        # YAML drives, in joint order. actuator_joints[i] is the joint it drives (None: tendon, site, ... transmission).
        self.actuator_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"actuator{a}"
                               for a in range(m.nu)]
        self.actuator_joints = [
            mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.actuator_trnid[a, 0]))
            if int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT) else None
            for a in range(m.nu)
        ]
        self.contact_sensors: dict[str, ContactSensor] = {}
        for s in range(m.nsensor):
            is_contact = int(m.sensor_type[s]) == int(mujoco.mjtSensor.mjSENS_CONTACT)
            if is_contact and int(m.sensor_objtype[s]) == int(mujoco.mjtObj.mjOBJ_BODY):
                body = self.body_names[m.sensor_objid[s]]
                self.contact_sensors[body] = ContactSensor(body, int(m.sensor_adr[s]))

    @property
    def num_dof(self) -> int:
        return self.dof_pos.shape[1]

    def asset(self, name: str) -> AssetView:
        """The views of scene asset ``name`` (an ``env.assets`` key): root pose and velocity of a free one, dof
        and actuator columns of an articulated one (sim/scene.py)."""
        if name not in self.assets:
            raise KeyError(f"no scene asset named {name!r}; env.assets of this model: {list(self.assets)}")
        return self.assets[name]

    @property
    def num_actuators(self) -> int:
        """Columns of ``ctrl`` (MuJoCo's nu)."""
        return int(self.mj_model.nu)

    @property
    def deterministic(self) -> bool:
        """Whether MuJoCo Warp runs in its deterministic mode (``opt.deterministic``)."""
        return bool(self.model.opt.deterministic)

    @property
    def dt(self) -> float:
        return float(self.mj_model.opt.timestep)

    def torch_view(self, array: wp.array) -> torch.Tensor:
        """The torch tensor of one of the simulator's Warp arrays, the same object at every call. torch.compile
        knows two tensors share memory only by their storage, and ``wp.to_torch`` makes a new storage per call: a
        compiled step that wrote through one view and read through another could order the two wrongly."""
        kept = self._torch_views.get(id(array))
        if kept is None:  # the array is kept beside its view: its id names no other array while the entry exists
            kept = self._torch_views[id(array)] = (array, wp.to_torch(array))
        return kept[1]

    def model_field(self, name: str) -> torch.Tensor:
        """Torch view of a Model array (per-world fields have num_worlds rows); "opt.gravity" for gravity."""
        if name.startswith("opt."):
            return self.torch_view(getattr(self.model.opt, name[len("opt."):]))
        return self.torch_view(getattr(self.model, name))

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
        for sensor in self._computed_sensors:
            sensor.sense()

    def contact_columns(self, bodies: Sequence[str]) -> torch.Tensor:
        """Columns of ``sensordata`` holding each body's net contact force, (len(bodies), 3); build once, reuse.

        ``sensordata[:, contact_columns(bodies)]`` is then (num_worlds, len(bodies), 3) with no host transfer.
        """
        missing = [b for b in bodies if b not in self.contact_sensors]
        if missing:
            raise KeyError(f"no contact sensor on bodies {missing}; sensed bodies: {list(self.contact_sensors)}")
        return torch.tensor([[self.contact_sensors[b].adr + k for k in range(3)] for b in bodies],
                            device=self.device, dtype=torch.long).view(len(bodies), 3)

    def contact_forces(self, bodies: Sequence[str]) -> torch.Tensor:
        """Net contact force on each named body, (num_worlds, len(bodies), 3). Bodies need a contact sensor."""
        return self.sensordata[:, self.contact_columns(bodies)]

    # ------------------------------------------------------------ execution
    def _run(self, name: str, fn: Callable[[], None], keep_state: bool = False) -> None:
        """Run a fixed sequence of Warp launches, from a captured graph where graphs are on.

        Before a graph is first captured ``fn`` runs once eagerly (to compile its kernels); with ``keep_state`` the
        carried state is put back after that run, so that a first physics call advances the worlds once, not twice.
        """
        if self._kernels_recorded is None:
            self.load_kernels()
        if self.use_graphs and self.wp_device.is_cuda and torch.cuda.is_current_stream_capturing():
            # torch is capturing the step (a reset's kinematics refresh in the captured post-physics step): the
            # launches go to torch's capturing stream and become part of its graph. On Warp's own stream they
            # would run once, now, and never when torch replays the step.
            with wp.ScopedDevice(self.wp_device), wp.ScopedStream(
                    wp.stream_from_torch(torch.cuda.current_stream()), sync_enter=False, sync_exit=False):
                fn()
            return
        if not self.use_graphs:
            with wp.ScopedDevice(self.wp_device):
                fn()
            return
        graph = self._graphs.get(name)
        if graph is None:
            with wp.ScopedDevice(self.wp_device):
                saved = self._snapshot() if keep_state else None
                fn()  # compiles the kernels outside the capture
                if saved is not None:
                    self._restore(saved)
                # By default Warp loads every module imported so far before a capture: all of MuJoCo Warp's,
                # dozens this model never launches. After a recorded dry run the ones it does are loaded.
                with wp.ScopedCapture(device=self.wp_device, force_module_load=not self._kernels_recorded) as capture:
                    fn()
            graph = self._graphs[name] = capture.graph
        wp.capture_launch(graph)

    def simulate(self) -> None:
        """Advance every world by ``substeps`` physics steps."""

        limiter = self.torque_speed
        forces = self.body_forces if self.body_forces is not None and self.body_forces.active else None
        pose = forces is not None and forces.needs_kinematics

        def physics() -> None:
            if forces is not None:
                forces.save_user()
            for _ in range(self.substeps):
                if limiter is not None:
                    limiter.launch()
                if pose:
                    mjw.kinematics(self.model, self.data)
                if forces is not None:
                    forces.launch()
                mjw.step(self.model, self.data)
            if forces is not None:
                forces.end_step()

        # One graph per variant: the force kernel (and its pose refresh) costs nothing until forces are used.
        self._run("physics" + ("+forces" if forces is not None else "") + ("+pose" if pose else ""), physics,
                  keep_state=True)
        self.physics_steps += self.substeps

    def forward(self) -> None:
        """Recompute every derived quantity (kinematics, contacts, sensors) from qpos/qvel/ctrl."""
        self._run("forward", lambda: mjw.forward(self.model, self.data))

    def camera(self, name: str) -> CameraView:
        """The images of camera ``name`` (an ``env.cameras`` key) for every world: ``rgb`` (N, 3, H, W) uint8,
        ``depth`` (N, 1, H, W) float32 metres, ``segmentation`` (N, 1, H, W) int32 geom ids (sim/cameras.py)."""
        views = self.cameras.views if self.cameras is not None else {}
        if name not in views:
            raise ConfigError(f"camera '{name}' is not declared in env.cameras; cameras: {list(views)}")
        return views[name]

    def render_cameras(self) -> None:
        """The render phase: draw every camera of every world (the sensors refreshed by the render) from the current
        ``qpos`` (poses, BVH refit, render, unpack: one graph replay on CUDA); their views then hold the new
        images."""
        if self.cameras is not None:
            self._run("render", self.cameras.launch)
            self.cameras.renders += 1

    def refresh_kinematics(self) -> None:
        """Recompute body poses (xpos, xquat, ...) after writing qpos, without collisions or dynamics."""
        if torch.compiler.is_compiling():  # traced into the compiled step as one op, not a graph break
            _kinematics_op(self._id, list(self._kinematics_state), list(self._kinematics_poses))
        else:
            self._run("kinematics", lambda: mjw.kinematics(self.model, self.data))

    def _kinematics_on(self, state: list[torch.Tensor], poses: list[torch.Tensor]) -> None:
        """The refresh as the compiled step's op runs it: from the values ``state`` into ``poses``. Compiled code may
        hand over a tensor of its own in place of the simulator's (a value it writes back later, or not at all):
        the refresh then reads or fills that one, and the simulator's is left as it was."""
        pairs = [*zip(self._kinematics_state, state), *zip(self._kinematics_poses, poses)]
        moved = [(mine, given, mine.clone()) for mine, given in pairs if given.data_ptr() != mine.data_ptr()]
        for mine, given, _ in moved:
            mine.copy_(given)
        self._run("kinematics", lambda: mjw.kinematics(self.model, self.data))
        for mine, given, kept in moved:
            given.copy_(mine)  # the poses computed (the state read is unchanged)
            mine.copy_(kept)

    def reset_worlds(self, mask: torch.Tensor) -> None:
        """Return the masked worlds to the model's initial state (qpos0, zero velocity, no controls or forces).

        The state that carries from one step to the next is reset with torch ops (like ``mujoco_warp.reset_data``,
        whose other fields, contacts and mass matrix, are recomputed by the next step anyway), so that a task's
        whole post-physics step is plain torch work that a CUDA graph can hold. Overflow bits of those worlds are
        folded into the run's record first: a reset clears them.
        """
        self._overflow_seen |= self.overflow
        rows = mask.view(-1, 1)
        self.qpos.copy_(torch.where(rows, self._qpos0, self.qpos))
        for view in self._zeroed_on_reset:
            view.masked_fill_(mask.view((-1,) + (1,) * (view.dim() - 1)), 0)
        if self.body_forces is not None:
            self.body_forces.clear(mask)

    def save_state(self) -> dict[str, torch.Tensor]:
        """A copy of every world's carried state (positions, velocities, controls, forces, solver warm start)."""
        return {name: view.clone() for name, view in self._carried_state.items()}

    def load_state(self, state: dict[str, torch.Tensor]) -> None:
        """Put back a ``save_state`` copy in place; the next physics step continues from it."""
        for name, view in self._carried_state.items():
            view.copy_(state[name])

    def _snapshot(self) -> dict[str, torch.Tensor]:
        state = self.save_state()
        if self.body_forces is not None:
            state["body_forces"] = self.body_forces.wrench.clone()
        return state

    def _restore(self, state: dict[str, torch.Tensor]) -> None:
        self.load_state(state)
        if "body_forces" in state:
            self.body_forces.wrench.copy_(state["body_forces"])

    def equality_violation(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Each world's largest equality-constraint residual (|efc_pos| of any equality row, m or rad) in the last
        physics step, and the equality constraint it belongs to: two (num_worlds,) tensors; None when the model has
        no equality constraints. Device work only (no host sync)."""
        if self._efc is None:
            return None
        efc_type, efc_id, efc_pos, nefc, column = self._efc
        # Rows past a world's count hold what an earlier step left there.
        rows = (efc_type == _EQUALITY_ROW) & (column < nefc.view(-1, 1))
        residual = torch.where(rows, efc_pos.abs(), torch.zeros_like(efc_pos))
        worst = residual.argmax(dim=1, keepdim=True)
        return residual.gather(1, worst).squeeze(1), efc_id.gather(1, worst).squeeze(1)

    def reset_nonfinite(self) -> torch.Tensor:
        """Reset worlds whose qpos or qvel holds NaN/inf, whose qvel exceeds ``DIVERGED_SPEED`` (a world on its
        way to NaN), or whose equality constraints are violated by more than ``EQUALITY_DIVERGED`` (see
        ``reset_worlds``); returns their mask."""
        bad = ~(torch.isfinite(self.qpos).all(dim=1) & (self.qvel.abs() <= DIVERGED_SPEED).all(dim=1))
        violation = self.equality_violation()
        if violation is not None:
            bad |= violation[0] > EQUALITY_DIVERGED
        self.reset_worlds(bad)
        return bad

    def write_state(
        self,
        mask: torch.Tensor,
        dof_pos: torch.Tensor | None = None,
        dof_vel: torch.Tensor | None = None,
        root_pos: torch.Tensor | None = None,
        root_quat: torch.Tensor | None = None,
        root_lin_vel: torch.Tensor | None = None,
        root_ang_vel: torch.Tensor | None = None,
        refresh: bool = True,
        asset: str | None = None,
    ) -> None:
        """Write state for the masked worlds only, then (``refresh``) recompute body poses from it.

        Each value is a full (num_worlds, ...) tensor; rows outside the mask are ignored. Selecting by mask keeps
        this free of host syncs. Root velocities: linear in the world frame, angular in the body frame.
        A caller that reads only qpos/qvel until the next physics step may skip the refresh.
        ``asset``: the name of an ``env.assets`` entry whose state this is (``self.asset(name)``); None: the main
        asset's (``env.asset``).
        """
        rows = mask.view(-1, 1)
        views = self if asset is None else self.asset(asset)
        pairs = [(views.dof_pos, dof_pos), (views.dof_vel, dof_vel)]
        if views.floating_base:
            pairs += [(views.root_pos, root_pos), (views.root_quat, root_quat),
                      (views.root_lin_vel, root_lin_vel), (views.root_ang_vel, root_ang_vel)]
        elif any(v is not None for v in (root_pos, root_quat, root_lin_vel, root_ang_vel)):
            key = "env.asset.fixBaseLink" if asset is None else f"env.assets.{asset}.fixBaseLink"
            raise ValueError(f"root state written to a fixed-base asset ({key} is True)")
        for view, value in pairs:
            if value is not None:
                view.copy_(torch.where(rows, value, view))
        if refresh:
            self.refresh_kinematics()

    def joint_pd_gains(self) -> dict[str, tuple[float, float]]:
        """{joint: (stiffness, damping)} of the joints driven by position actuators (MuJoCo's kp and kv)."""
        m, out = self.mj_model, {}
        for a in range(m.nu):
            is_joint = int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT)
            # A position actuator: force = kp * ctrl - kp * q - kv * qdot (gain kp, bias (0, -kp, -kv)).
            is_position = float(m.actuator_gainprm[a, 0]) != 0.0 and float(m.actuator_biasprm[a, 1]) != 0.0
            if is_joint and is_position:
                name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.actuator_trnid[a, 0]))
                out[name] = (float(m.actuator_gainprm[a, 0]), -float(m.actuator_biasprm[a, 2]))
        return out

    def save_model(self, path: str) -> None:
        """Write the compiled host model (nominal values, no per-world randomisation) as MuJoCo's binary ``.mjb``.

        ``mujoco.MjModel.from_binary_path`` loads it back, with the same MuJoCo version, as the very model that was
        trained on: actuators (PD gains), solver options, contact sensors and the floor included.
        """
        mujoco.mj_saveModel(self.mj_model, str(path), None)

    def geom_id(self, name: str) -> int:
        gid = mujoco.mj_name2id(self.mj_model, mujoco.mjtObj.mjOBJ_GEOM, name)
        if gid < 0:
            raise KeyError(f"no geom named '{name}'")
        return gid

    def body_lin_vel(self, body_ids: torch.Tensor | slice, com: bool = False) -> torch.Tensor:
        """(N, len(body_ids), 3) world-frame linear velocity of each body's origin (MuJoCo's mj_objectVelocity,
        world axes), or of its centre of mass with ``com``, from the last physics step's forward pass."""
        roots = self._body_rootid[body_ids]
        vel = self.cvel[:, body_ids]
        point = (self.xipos if com else self.xpos)[:, body_ids]
        return vel[..., 3:] + torch.cross(vel[..., :3], point - self.subtree_com[:, roots], dim=-1)

    def body_states(self, body_ids: torch.Tensor | None = None, com: bool = False) -> torch.Tensor:
        """IsaacGym's rigid body state tensor: (N, nbody or len(body_ids), 13), all in the world frame.

        Columns: position of the body frame's origin (0:3), orientation quaternion **(w, x, y, z)**, MuJoCo's order
        (3:7; IsaacGym's is x, y, z, w), linear velocity of the body origin (7:10; with ``com`` of the centre of
        mass, which is what PhysX reports), angular velocity (10:13). Body indices are MuJoCo's (0 is the world
        body; ``body_names``). A new tensor, computed on the device from ``xpos``, ``xquat``, ``cvel``: the values
        of the last forward pass, which after ``simulate()`` describe the start of its last physics step (call
        ``forward()`` first for the current ``qpos``/``qvel``).
        """
        ids = slice(None) if body_ids is None else body_ids
        return torch.cat((self.xpos[:, ids], self.xquat[:, ids], self.body_lin_vel(ids, com=com),
                          self.cvel[:, ids, :3]), dim=-1)

    def joint_limits(self, names: list[str] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(lower, upper): the model's range of each named joint (default: ``dof_names``, the columns of
        ``dof_pos``), float32 on the device; m or rad."""
        m = self.mj_model
        ranges = m.jnt_range[[m.joint(name).id for name in (self.dof_names if names is None else names)]]
        limits = torch.tensor(ranges, dtype=torch.float32, device=self.device)
        return limits[:, 0], limits[:, 1]

    def root_ang_vel_world(self) -> torch.Tensor:
        """(N, 3) floating base angular velocity in the world frame (``root_ang_vel`` is in the body frame), from
        the current ``qpos``/``qvel``."""
        self._require_floating_base("root_ang_vel_world")
        return quat_rotate(self.root_quat, self.root_ang_vel)

    def root_states(self) -> torch.Tensor:
        """IsaacGym's root state layout, (N, 13): position, quaternion **(w, x, y, z)**, linear and angular velocity,
        all in the world frame, from the current ``qpos``/``qvel``; a new tensor (write with ``write_state``)."""
        self._require_floating_base("root_states")
        return torch.cat((self.root_pos, self.root_quat, self.root_lin_vel, self.root_ang_vel_world()), dim=-1)

    def _require_floating_base(self, what: str) -> None:
        if not self.floating_base:
            raise ValueError(f"{what} needs a floating base, but the model's root is fixed (env.asset.fixBaseLink)")

    # ------------------------------------------------------- external forces
    def body_ids(self, bodies: Sequence[str | int] | torch.Tensor | None = None) -> torch.Tensor:
        """Body indices on the device from names or indices (None: every body, the world body 0 included).

        Lists are resolved once and cached, so calling this inside a step costs no host-to-device copy after the
        first time; a tensor is taken as it is (its range is not checked: that would sync).
        """
        if isinstance(bodies, torch.Tensor):
            return bodies.to(self.device, torch.long)
        key = ("all",) if bodies is None else tuple(bodies)
        ids = self._body_id_cache.get(key)
        if ids is None:
            if bodies is None:
                rows = list(range(len(self.body_names)))
            else:
                rows = [self._body_index(b) for b in bodies]
            ids = self._body_id_cache[key] = torch.tensor(rows, dtype=torch.long, device=self.device)
        return ids

    def _body_index(self, body: str | int) -> int:
        if isinstance(body, str):
            if body not in self.body_names:
                raise ValueError(f"bodies: no body named {body!r}; valid: {self.body_names}")
            return self.body_names.index(body)
        if not 0 <= int(body) < len(self.body_names):
            raise ValueError(f"bodies: index {body} is out of range; valid: 0..{len(self.body_names) - 1}")
        return int(body)

    def apply_body_forces(
        self,
        forces: torch.Tensor | None = None,
        torques: torch.Tensor | None = None,
        bodies: Sequence[str | int] | torch.Tensor | None = None,
        positions: torch.Tensor | None = None,
        frame: str = "world",
        persist: bool = False,
    ) -> None:
        """Push bodies with forces and torques, (N, len(bodies), 3) each, from the next ``simulate()`` on.

        IsaacGym's ``apply_rigid_body_force_tensors`` / ``..._at_pos_tensors``, which act for one simulate call.
        - ``persist=False``: acts during the next ``simulate()`` only (all its physics steps), then is dropped;
          ``persist=True``: acts every step until ``clear_body_forces()`` or a reset of the world. Calls add up.
        - ``frame="world"``: forces and torques in world axes, fixed over the step; ``positions`` are world points
          that stay put while the body moves (MuJoCo's ``mj_applyFT`` at each physics step: torque about the
          centre of mass ``t + (p - com) x f``). ``frame="body"``: forces, torques and ``positions`` in the body's
          own frame (points relative to the body origin); the wrench turns with the body at every physics step.
        - Without ``positions`` forces act at the centre of mass.
        Torch ops only (no host sync), so it may sit in a captured ``pre_physics_step``; bodies given as a list are
        resolved once and cached. Once used, each step launches one small kernel per physics step (plus a pose
        refresh when a body-frame wrench or a point was used) until ``clear_body_forces()``. ``xfrc_applied`` keeps
        the user's own writes only: these forces are added to it inside the physics and do not show there.
        """
        if frame not in FRAMES:
            raise ValueError(f"frame={frame!r} is invalid: give one of {list(FRAMES)}")
        if forces is None and torques is None:
            raise ValueError("apply_body_forces: give forces, torques or both (both are None)")
        if positions is not None and forces is None:
            raise ValueError("positions given without forces: a point of application needs a force")
        ids = self.body_ids(bodies)
        expected = (self.num_worlds, int(ids.shape[0]), 3)
        values = []
        for name, value in (("forces", forces), ("torques", torques), ("positions", positions)):
            if value is not None and tuple(value.shape) != expected:
                raise ValueError(f"{name} has shape {tuple(value.shape)}; valid: (num_envs, len(bodies), 3) = "
                                 f"{expected}")
            values.append(None if value is None else value.to(self.device, torch.float32))
        if self.body_forces is None:
            self.body_forces = BodyForces(self.data, self.num_worlds, self.mj_model.nbody,
                                          self.model_field("body_ipos"), self.device)
        self.body_forces.add(ids, *values, frame=frame, persist=bool(persist))

    def clear_body_forces(self) -> None:
        """Drop every force of ``apply_body_forces`` (one-step and persistent) and stop launching its kernel."""
        if self.body_forces is not None:
            self.body_forces.clear()
            self.body_forces.active = self.body_forces.needs_kinematics = False

    def site_id(self, name: str) -> int:
        """The model index of the site ``name`` (a column of ``site_xpos`` / ``site_xmat``)."""
        sid = mujoco.mj_name2id(self.mj_model, mujoco.mjtObj.mjOBJ_SITE, name)
        if sid < 0:
            names = [mujoco.mj_id2name(self.mj_model, mujoco.mjtObj.mjOBJ_SITE, i) for i in range(self.mj_model.nsite)]
            raise KeyError(f"no site named '{name}'; the model's sites: {names}")
        return sid

    def mocap_index(self, body: str) -> int:
        """Column of ``body`` in ``mocap_pos`` / ``mocap_quat`` (a body with ``mocap="true"`` in its MJCF)."""
        index = int(self.mj_model.body_mocapid[self.body_id(body)])
        if index < 0:
            mocap = [n for b, n in enumerate(self.body_names) if self.mj_model.body_mocapid[b] >= 0]
            raise ValueError(f"body '{body}' is not a mocap body; mocap bodies: {mocap}")
        return index

    def body_id(self, name: str) -> int:
        if name not in self.body_names:
            raise KeyError(f"no body named '{name}'; bodies: {self.body_names}")
        return self.body_names.index(name)

    def recapture(self) -> None:
        """Drop captured graphs; call after replacing Model arrays or changing solver options."""
        self._graphs.clear()

    # ------------------------------------------------------------- overflow
    def poll_overflow(self) -> list[str]:
        """Host-side check (syncs): warn once per bit seen since the last poll; returns the YAML keys named."""
        seen = self._overflow_seen | self.overflow
        bits = _or_all(seen)
        self._overflow_seen.zero_()
        keys = []
        for bit, key in _OVERFLOW_KEYS.items():
            if bits & bit and key not in keys:
                keys.append(key)
        if keys:
            # Only the bits that drop data: ITERATIONS/LS_ITERATIONS (solver stopped at its iteration limit) are
            # set by every RL-sized iteration count and would read as a cause here.
            dropped = bits & sum(_OVERFLOW_KEYS)
            warnings.warn(
                "MuJoCo Warp dropped contacts or constraint rows (overflow bits "
                f"{mjw.OverflowType(dropped)!r}); physics in the affected worlds is wrong. "
                f"Raise {', '.join(keys)} in the task YAML.",
                RuntimeWarning,
                stacklevel=2,
            )
        return keys


def _or_all(values: torch.Tensor) -> int:
    out = 0
    for v in np.unique(values.cpu().numpy()):
        out |= int(v)
    return out
