"""Sensors: one interface (``Sensor``) for everything a task senses, each a named torch view ``(num_envs, ...)``
with no host copy (``Simulator.sensor(name)``; a camera has one view per output, ``Simulator.sensor(name,
output="rgb")``).

A sensor is declared before the model is built (``ModelRequest.declared_sensors``, or ``env.sensors`` and
``env.cameras`` in the task YAML; ``ModelRequest.all_sensors()`` lists them all) and adds what it needs to the model
spec there (``Sensor.add_to``); once the model is compiled the simulator's sensor registry (``SensorRegistry``,
sim/sensor_registry.py; ``Simulator.sensors``) binds it to a ``SensorContext`` (``Sensor.bind``: its views) and
refreshes it in the phase of the step its ``refresh`` names:
  * MuJoCo sensors (an asset's MJCF ``<sensor>`` section, ``env.sensors`` entries, the net contact forces of
    ``ContactForces``) are columns of the batched ``sensordata``, which each physics step rewrites; they have nothing
    to do in ``sense()``. MuJoCo computes them from the state at the start of that step (its forward pass runs before
    the integration), so after ``Simulator.simulate()`` a view holds the values of the last physics step's start
    state, like ``xpos`` and ``cvel``; ``Simulator.forward()`` recomputes them from the current state. A world reset
    by ``Simulator.reset_worlds`` reads zeros until its next physics step.
  * Computed sensors (``HeightScan``), ``refresh = "sense"``, are torch work on the device: ``Simulator.sense()``
    refreshes them from the current state. VecTask calls it once per step, after the resets and before the
    observation is computed (inside the captured step on CUDA), and before the observation of ``reset()``.
  * Cameras (``CameraSpec``, sim/cameras.py), ``refresh = "render"``, are refreshed by a render:
    ``Simulator.render_cameras()`` draws every camera of every world at once (one render context, Warp launches
    replayed as one Warp graph). That cannot run in ``sense()``: the sense phase sits inside the torch function that
    VecTask compiles and captures (between the resets and the flat observation, both in ``post_physics_step``), and a
    Warp launch there would break the compiled graph. So VecTask renders them after that function, in the step's
    render phase (tasks/base/step_execution.py), and after the resets of ``reset()``, every ``env.renderInterval``
    steps; the image observation reads them after it.

``env.sensors.<name>: {type: ..., site: ...}`` declares a MuJoCo sensor that the asset does not have. Its type is one
MuJoCo sensor, or ``imu``: an accelerometer and a gyro on one site, MuJoCo sensors ``<name>_accelerometer`` and
``<name>_gyro``, whose view ``<name>`` is their 6 adjacent columns (linear acceleration in m/s², gravity included as
MuJoCo's accelerometer has it, then angular velocity in rad/s, both in the site's frame). The model records each such
group as a custom text element, so a saved ``.mjb`` keeps it. A site sensor may name a ``body`` instead: it then
gets a site ``<name>_site`` of its own at the body's frame (the legged robots' URDFs have no sites).

Frames and signs are MuJoCo's (docs/porting.md, "Sensors"): ``force`` and ``torque`` are the interaction between the
site's body and its parent body, in the site's frame (the force the parent exerts on the child subtree, with the
torque about the site); they are not IsaacGym's asset force sensor, which sums the forces on one body.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar, Mapping, Sequence

import mujoco
import torch

from isaacgymenvs_mw.sim.height_map import HeightMap
from isaacgymenvs_mw.sim.scene import scene_prefixes
from isaacgymenvs_mw.sim.terrain import heightfield_grid
from isaacgymenvs_mw.utils.config import check_entry
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import yaw_from_quat

_S = mujoco.mjtSensor
# env.sensors types -> the MuJoCo sensors each adds, in column order (``imu``: two). All read a site (or a site of
# their own on a body); the frame sensors may read a body itself.
SENSOR_TYPES: dict[str, tuple[mujoco.mjtSensor, ...]] = {
    "imu": (_S.mjSENS_ACCELEROMETER, _S.mjSENS_GYRO),
    "accelerometer": (_S.mjSENS_ACCELEROMETER,),
    "gyro": (_S.mjSENS_GYRO,),
    "velocimeter": (_S.mjSENS_VELOCIMETER,),
    "force": (_S.mjSENS_FORCE,),
    "torque": (_S.mjSENS_TORQUE,),
    "touch": (_S.mjSENS_TOUCH,),
    "framepos": (_S.mjSENS_FRAMEPOS,),
    "framequat": (_S.mjSENS_FRAMEQUAT,),
    "framelinvel": (_S.mjSENS_FRAMELINVEL,),
    "frameangvel": (_S.mjSENS_FRAMEANGVEL,),
}
BODY_TYPES = ("framepos", "framequat", "framelinvel", "frameangvel")
SENSOR_KEYS = ("type", "site", "body")
# Custom text elements naming a sensor group (after this prefix) and its MuJoCo sensors (the text, space separated).
GROUP_TEXT_PREFIX = "sensor_group:"
# The phases of a step that refresh sensors (``Sensor.refresh``), in their order: the sense phase inside the step's
# torch function, then the render after it.
REFRESH_PHASES = ("sense", "render")


@dataclass(frozen=True)
class SensorContext:
    """What a sensor may bind to (``Sensor.bind``): the compiled model, the device state and the torch views of that
    state, not the whole simulator (whose methods step, reset and capture: no sensor's business).

    Args:
        mj_model: the compiled host model.
        model, data: MuJoCo Warp's device Model and Data (``num_worlds`` worlds).
        device: the torch device of the views.
        num_worlds: number of worlds (= numEnvs).
        sensordata: (num_worlds, nsensordata) torch view of ``data.sensordata``.
        columns: {MuJoCo sensor or sensor group name: its columns of ``sensordata``}.
        state: the simulator's torch views of the state by name (``qpos``, ``qvel``, ``xpos``, ``site_xpos``,
            ``dof_pos``, and ``root_pos``, ``root_quat``, ``root_lin_vel``, ``root_ang_vel`` on a floating base; the
            same tensors as ``Simulator``'s attributes of those names), also read as attributes:
            ``context.root_lin_vel``.
        images: {camera name: {output: (num_worlds, C, H, W) image}}, the render context's images.
    """

    mj_model: mujoco.MjModel
    model: object
    data: object
    device: torch.device
    num_worlds: int
    sensordata: torch.Tensor
    columns: Mapping[str, slice]
    state: Mapping[str, torch.Tensor] = field(default_factory=dict)
    images: Mapping[str, Mapping[str, torch.Tensor]] = field(default_factory=dict)

    def __getattr__(self, name: str) -> torch.Tensor:
        state = self.__dict__.get("state", {})
        if name not in state:
            raise AttributeError(f"a sensor's context has no {name!r}; its state views: {list(state)}")
        return state[name]

    def mujoco_sensor(self, name: str, key: str) -> torch.Tensor:
        """The (num_worlds, dim) slice of ``sensordata`` of the MuJoCo sensor (or sensor group) ``name``; ``key``
        names where the user wrote it, for the error."""
        if name not in self.columns:
            raise ConfigError(f"{key}: {name!r} is not a MuJoCo sensor of the model; its sensors: {list(self.columns)}")
        return self.sensordata[:, self.columns[name]]


class Sensor(ABC):
    """One sensor of the simulator, seen by tasks as the view ``Simulator.sensor(name)``, or, for a sensor with
    several outputs (a camera's ``rgb``, ``depth``, ...), one view per output: ``Simulator.sensor(name,
    output=...)``.

    Subclasses set ``name`` (unique among the model's sensors) and implement ``bind``; a MuJoCo sensor or a camera
    also adds itself to the model spec (``add_to``). ``refresh`` says which phase of the step refreshes the views
    (``REFRESH_PHASES``): "sense", device torch work (``sense``, which a computed sensor implements); "render", the
    simulator's one batch render of its cameras (``Simulator.render_cameras``), Warp launches replayed as a graph of
    their own."""

    name: str
    refresh: ClassVar[str] = "sense"
    # The names of its views when it has several (bind returns {output: view}); () when it has one.
    outputs: tuple[str, ...] = ()

    def add_to(self, spec: mujoco.MjSpec) -> None:
        """Add what the sensor needs to the model being built (MuJoCo sensors, sites, cameras). Computed sensors add
        nothing."""

    @abstractmethod
    def bind(self, context: SensorContext) -> torch.Tensor | Mapping[str, torch.Tensor]:
        """Its (num_worlds, ...) view on the context's device ({output: view} for each of ``outputs``), made once
        after the model is compiled. Always the same tensors, refreshed in place: a captured step holds their
        addresses."""

    def sense(self) -> None:
        """Refresh the view from the simulator's current state: device torch work only, no host sync (it runs in
        the captured step on CUDA). MuJoCo sensors have nothing to do: each physics step rewrites ``sensordata``;
        nor have rendered ones: the render rewrites their images."""


@dataclass(frozen=True)
class SensorSpec(Sensor):
    """One ``env.sensors`` entry: a MuJoCo sensor of ``type`` on ``site``, or on ``body`` (the frame sensors read
    the body's frame; the others a site ``<name>_site`` added at it)."""

    name: str
    type: str
    site: str | None = None
    body: str | None = None

    @property
    def key(self) -> str:
        return f"env.sensors.{self.name}"

    def part_names(self) -> list[str]:
        """The MuJoCo sensors it adds: itself, or ``<name>_<part>`` for each part of a group (``imu``)."""
        parts = SENSOR_TYPES[self.type]
        if len(parts) == 1:
            return [self.name]
        return [f"{self.name}_{p.name[len('mjSENS_'):].lower()}" for p in parts]

    def add_to(self, spec: mujoco.MjSpec) -> None:
        """Add its MuJoCo sensors after those the spec has (so their columns come after); a group's parts one after
        the other, so that its columns are adjacent."""
        if self.site is not None:
            field, objname, names = "site", self.site, [s.name for s in spec.sites]
        else:
            field, objname, names = "body", self.body, [b.name for b in spec.bodies][1:]
        if objname not in names:
            raise ConfigError(f"{self.key}.{field}={objname!r} is not a {field} of the model; {field}s: {names}")
        parts = self.part_names()
        groups = {t.name[len(GROUP_TEXT_PREFIX):] for t in spec.texts if t.name.startswith(GROUP_TEXT_PREFIX)}
        clash = sorted(({s.name for s in spec.sensors} | groups) & ({self.name} | set(parts)))
        if clash:
            raise ConfigError(f"{self.key}: the model already has a sensor named {clash}; give another name")
        objtype = mujoco.mjtObj.mjOBJ_SITE if self.site is not None else mujoco.mjtObj.mjOBJ_BODY
        if self.body is not None and self.type not in BODY_TYPES:
            objtype, objname = mujoco.mjtObj.mjOBJ_SITE, f"{self.name}_site"
            if objname in {s.name for s in spec.sites}:
                raise ConfigError(f"{self.key}: the model already has a site named {objname!r}; give another name")
            spec.body(self.body).add_site(name=objname)  # at the body's frame, its axes
        for part, kind in zip(parts, SENSOR_TYPES[self.type]):
            spec.add_sensor(name=part, type=kind, objtype=objtype, objname=objname)
        if len(parts) > 1:
            spec.add_text(name=f"{GROUP_TEXT_PREFIX}{self.name}", data=" ".join(parts))

    def bind(self, context: SensorContext) -> torch.Tensor:
        return context.mujoco_sensor(self.name, self.key)


def sensor_specs(cfg: Mapping | None) -> tuple[SensorSpec, ...]:
    """``env.sensors``: {name: {type, site | body}} as ``SensorSpec``s in YAML order; a bad entry is an error naming
    ``env.sensors.<name>.<key>``. Whether the site or body exists is checked when the model is built."""
    if not cfg:
        return ()
    if not hasattr(cfg, "items"):
        raise ConfigError(f"env.sensors={cfg!r} is invalid: give a mapping {{name: {{type: imu, site: <site>}}}}")
    out = []
    for name, entry in cfg.items():
        key = f"env.sensors.{name}"
        check_entry(entry, key, SENSOR_KEYS)
        kind = entry.get("type")
        if kind not in SENSOR_TYPES:
            raise ConfigError(f"{key}.type={kind!r} is invalid: give one of {list(SENSOR_TYPES)}")
        site, body = entry.get("site"), entry.get("body")
        if (site is None) == (body is None):
            raise ConfigError(f"{key}: give exactly one site or body for a sensor of type {kind} (site={site!r}, "
                              f"body={body!r})")
        out.append(SensorSpec(str(name), str(kind), None if site is None else str(site),
                              None if body is None else str(body)))
    return tuple(out)


class ContactForces(Sensor):
    """The net contact force on each of ``bodies``: MuJoCo ``contact`` sensors ``contact_<body>`` (net force, world
    frame: the force the body exerts on what it touches), viewed as ``contact_forces``, (num_worlds, bodies, 3).
    ``ModelRequest.contact_bodies`` declares it (``env.asset.contactBodies`` and the legged tasks' bodies)."""

    name = "contact_forces"

    def __init__(self, bodies: Sequence[str]) -> None:
        self.bodies = tuple(bodies)

    def add_to(self, spec: mujoco.MjSpec) -> None:
        """One sensor per body, one after the other: their columns are adjacent, so the view is a slice."""
        for body in self.bodies:
            spec.add_sensor(name=f"contact_{body}", type=mujoco.mjtSensor.mjSENS_CONTACT,
                            objtype=mujoco.mjtObj.mjOBJ_BODY, objname=body,
                            intprm=[1 << 1, 3, 1])  # data = force (bit 1), reduce = net force (3), one slot

    def bind(self, context: SensorContext) -> torch.Tensor:
        first = context.columns[f"contact_{self.bodies[0]}"].start
        return context.sensordata[:, first:first + 3 * len(self.bodies)].unflatten(1, (len(self.bodies), 3))


class HeightScan(Sensor):
    """Terrain heights (m, world z) under a grid of ``points_x`` x ``points_y`` points, ``length`` x ``width``
    metres, centred on each world's floating base and turned with its yaw (x forward): ``height_scan``,
    (num_worlds, points_x * points_y), x-major (legged_gym's measured heights). The heights are those of the
    compiled ground (its heightfields and boxes, read back from the model), interpolated as MuJoCo collides with
    them (``height_map``, which also looks up any other point: ``SensorRegistry.get("height_scan").height_map``)."""

    name = "height_scan"

    def __init__(self, length: float, width: float, points_x: int, points_y: int) -> None:
        self.length, self.width = float(length), float(width)
        self.points_x, self.points_y = int(points_x), int(points_y)
        self._height_map: HeightMap | None = None  # made by bind, from the compiled model

    @property
    def height_map(self) -> HeightMap:
        """The ground's height (m, world z) at any points (x, y): ``height_map(x, y)``, torch on the device; what
        the scan samples. Exists once the sensor is bound (the simulator is built)."""
        if self._height_map is None:
            raise RuntimeError("height_scan: the height map exists once the simulator has bound the sensor")
        return self._height_map

    def bind(self, context: SensorContext) -> torch.Tensor:
        if "root_pos" not in context.state:
            raise ConfigError("a height scan follows a floating base, but the model's root is fixed "
                              "(env.asset.fixBaseLink)")
        grid = heightfield_grid(context.mj_model)
        self._height_map = HeightMap(grid["heights"], grid["x0"], grid["y0"], grid["spacing"], context.device)
        xs = torch.linspace(-0.5, 0.5, self.points_x, device=context.device) * self.length
        ys = torch.linspace(-0.5, 0.5, self.points_y, device=context.device) * self.width
        gx, gy = torch.meshgrid(xs, ys, indexing="ij")
        self._px, self._py = gx.flatten(), gy.flatten()  # (P,) each, base yaw frame
        self._root_pos, self._root_quat = context.state["root_pos"], context.state["root_quat"]
        self._heights = torch.zeros(context.num_worlds, self._px.shape[0], device=context.device)
        return self._heights

    def sense(self) -> None:
        yaw = yaw_from_quat(self._root_quat)
        c, s = torch.cos(yaw).unsqueeze(1), torch.sin(yaw).unsqueeze(1)
        px, py, pos = self._px, self._py, self._root_pos
        self._heights[:] = self._height_map(pos[:, 0:1] + c * px - s * py, pos[:, 1:2] + s * px + c * py)


def sensor_columns(m: mujoco.MjModel) -> dict[str, slice]:
    """{name: columns of ``sensordata``} of every named MuJoCo sensor of ``m``, and of every sensor group (an
    ``imu``: its parts' adjacent columns, recorded as a custom text element)."""
    columns = {}
    for s in range(m.nsensor):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_SENSOR, s)
        if name:
            adr = int(m.sensor_adr[s])
            columns[name] = slice(adr, adr + int(m.sensor_dim[s]))
    for group, text in scene_prefixes(m, GROUP_TEXT_PREFIX).items():  # {text name: its text}, any prefix
        parts = [columns[p] for p in text.split()]
        columns[group] = slice(parts[0].start, parts[-1].stop)
    return columns
