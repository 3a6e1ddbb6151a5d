"""Sensors by name: MuJoCo sensors of the model (an asset's MJCF ``<sensor>`` section, or ``env.sensors`` in the task
YAML) as torch views ``(num_envs, dim)`` of the batched ``sensordata``, with no host copy.

MuJoCo computes every sensor inside each physics step, from the state at the start of that step (its forward pass
runs before the integration), so after ``Simulator.simulate()`` a view holds the values of the last physics step's
start state, like ``xpos`` and ``cvel``; ``Simulator.forward()`` recomputes them from the current state. A world
reset by ``Simulator.reset_worlds`` reads zeros until its next physics step.

``env.sensors.<name>: {type: ..., site: ...}`` declares a sensor that the asset does not have; ``build_model`` adds
it to the model spec before compiling (``add_sensors``). Its type is one MuJoCo sensor, or ``imu``: an accelerometer
and a gyro on one site, MuJoCo sensors ``<name>_accelerometer`` and ``<name>_gyro``, whose view ``<name>`` is their
6 adjacent columns (linear acceleration in m/s², gravity included as MuJoCo's accelerometer has it, then angular
velocity in rad/s, both in the site's frame). The model records each such group as a custom text element, so a
saved ``.mjb`` keeps it.

Frames and signs are MuJoCo's (docs/porting.md, "Sensors"): ``force`` and ``torque`` are the interaction between the
site's body and its parent body, in the site's frame (the force the parent exerts on the child subtree, with the
torque about the site); they are not IsaacGym's asset force sensor, which sums the forces on one body.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import mujoco
import torch

from isaacgymenvs_mw.sim.scene import scene_prefixes
from isaacgymenvs_mw.utils.config import check_entry
from isaacgymenvs_mw.utils.errors import ConfigError

_S = mujoco.mjtSensor
# env.sensors types -> the MuJoCo sensors each adds, in column order (``imu``: two). All read a site; the frame
# sensors may read a body instead.
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


@dataclass(frozen=True)
class SensorSpec:
    """One ``env.sensors`` entry: a sensor of ``type`` on ``site`` (or, for the frame sensors, on ``body``)."""

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
        if (site is None) == (body is None) or (body is not None and kind not in BODY_TYPES):
            where = "site or body" if kind in BODY_TYPES else "site"
            raise ConfigError(f"{key}: give exactly one {where} for a sensor of type {kind} (site={site!r}, "
                              f"body={body!r})")
        out.append(SensorSpec(str(name), str(kind), None if site is None else str(site),
                              None if body is None else str(body)))
    return tuple(out)


def add_sensors(spec: mujoco.MjSpec, sensors: Sequence[SensorSpec]) -> None:
    """Add each declared sensor to the model being built, after the asset's own (so their columns come after the
    asset's); a group's parts are added one after the other, so its columns are adjacent."""
    taken = {s.name for s in spec.sensors}
    for sensor in sensors:
        if sensor.site is not None:
            objtype, objname, names = mujoco.mjtObj.mjOBJ_SITE, sensor.site, [s.name for s in spec.sites]
        else:
            objtype, objname, names = mujoco.mjtObj.mjOBJ_BODY, sensor.body, [b.name for b in spec.bodies][1:]
        field = "site" if sensor.site is not None else "body"
        if objname not in names:
            raise ConfigError(f"{sensor.key}.{field}={objname!r} is not a {field} of the model; {field}s: {names}")
        parts = sensor.part_names()
        clash = sorted(taken & ({sensor.name} | set(parts)))
        if clash:
            raise ConfigError(f"{sensor.key}: the model already has a sensor named {clash}; give another name")
        for part, kind in zip(parts, SENSOR_TYPES[sensor.type]):
            spec.add_sensor(name=part, type=kind, objtype=objtype, objname=objname)
        taken |= {sensor.name, *parts}
        if len(parts) > 1:
            spec.add_text(name=f"{GROUP_TEXT_PREFIX}{sensor.name}", data=" ".join(parts))


class SensorViews:
    """Every named sensor of a compiled model as a basic slice of ``sensordata`` ((num_worlds, nsensordata) torch
    view of the Warp array): reading one costs no copy, and the physics refreshes it in place."""

    def __init__(self, m: mujoco.MjModel, sensordata: torch.Tensor) -> None:
        self._data = sensordata
        self.columns: dict[str, slice] = {}
        for s in range(m.nsensor):
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_SENSOR, s)
            if name:
                adr = int(m.sensor_adr[s])
                self.columns[name] = slice(adr, adr + int(m.sensor_dim[s]))
        for group, text in scene_prefixes(m, GROUP_TEXT_PREFIX).items():  # {text name: its text}, any prefix
            parts = [self.columns[p] for p in text.split()]
            self.columns[group] = slice(parts[0].start, parts[-1].stop)

    @property
    def names(self) -> list[str]:
        return list(self.columns)

    def view(self, name: str, key: str) -> torch.Tensor:
        """(num_worlds, dim) view of sensor ``name``; ``key``: where the user named it (the error names it)."""
        if name not in self.columns:
            raise ConfigError(f"{key}: {name!r} is not a sensor of the model; its sensors: {self.names}")
        return self._data[:, self.columns[name]]
