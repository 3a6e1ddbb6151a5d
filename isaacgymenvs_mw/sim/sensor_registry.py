"""The sensor registry: the owner of a simulator's sensors (sim/sensors.py), cameras included (sim/cameras.py).

The simulator hands the registry a ``SensorContext`` (the compiled model, the device state, the views sensors read)
and the sensors the model was built with; the registry checks their names and phases, makes the render context of
the cameras, binds every sensor to the context, and keeps the lists each phase of the step refreshes: the computed
sensors (``sense``) and the cameras (``render``). Tasks and observation terms look every sensor up here by name
(``Simulator.sensor(name[, output])`` asks the registry): a MuJoCo sensor of the model (an MJCF ``<sensor>``, an
``env.sensors`` entry), a bound ``Sensor``'s view, or one output of a camera.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Mapping, Sequence

import torch
import warp as wp

from isaacgymenvs_mw.sim.cameras import Cameras, CameraSpec
from isaacgymenvs_mw.sim.sensors import REFRESH_PHASES, Sensor, SensorContext
from isaacgymenvs_mw.utils.errors import ConfigError


class SensorRegistry:
    """The sensors of one simulator, bound to ``context`` and looked up by name (sim/sensors.py says which state
    each view describes and when it is refreshed).

    Args:
        context: what the sensors bind to (its ``images`` are filled here, from the render context).
        sensors: the sensors the model was built with (``ModelRequest.all_sensors()``, ``env.cameras`` included).
        wp_device: the Warp device of the render context.
    """

    def __init__(self, context: SensorContext, sensors: Sequence[Sensor], wp_device: wp.context.Device) -> None:
        names = [s.name for s in sensors]
        for sensor in sensors:
            if names.count(sensor.name) > 1:
                raise ConfigError(f"two sensors of the model are named {sensor.name!r} (sensors and cameras share one "
                                  "namespace); give one another name")
            if sensor.refresh not in REFRESH_PHASES:
                raise ValueError(f"sensor {sensor.name!r}: refresh={sensor.refresh!r}; give one of {REFRESH_PHASES}")
        # The render phase: one render context draws every rendered sensor (a camera of the model) at once.
        rendered = [s for s in sensors if s.refresh == "render"]
        self.render_context: Cameras | None = None
        if rendered:
            self.render_context = Cameras(context.mj_model, context.model, context.data, rendered,
                                          context.num_worlds, wp_device)
            context = replace(context, images=self.render_context.images())
        self.context = context
        self.renders = 0  # renders so far
        self._sensors = {s.name: s for s in sensors}
        self._bound: dict[str, torch.Tensor | dict[str, torch.Tensor]] = {}
        for sensor in sensors:
            self._add(sensor, sensor.bind(context))
        # The sense phase: the sensors that compute their views (MuJoCo's are rewritten by the physics step).
        self.computed = [s for s in sensors if s.refresh == "sense" and type(s).sense is not Sensor.sense]
        # The cameras by name, in the render context's order (the model's: env.cameras in YAML order).
        views = self.render_context.views if self.render_context is not None else {}
        self.cameras: dict[str, CameraSpec] = {name: self._sensors[name] for name in views}

    def _add(self, sensor: Sensor, views: torch.Tensor | Mapping[str, torch.Tensor]) -> None:
        if sensor.outputs and (not isinstance(views, Mapping) or tuple(views) != tuple(sensor.outputs)):
            raise TypeError(f"{type(sensor).__name__}.bind must return {{output: view}} for {list(sensor.outputs)}")
        self._bound[sensor.name] = dict(views) if sensor.outputs else views

    @property
    def names(self) -> list[str]:
        """Every sensor name: the model's MuJoCo sensors and groups, then the bound sensors."""
        return list(dict.fromkeys([*self.context.columns, *self._bound]))

    @property
    def columns(self) -> Mapping[str, slice]:
        """{MuJoCo sensor or group: its columns of ``sensordata``}."""
        return self.context.columns

    def get(self, name: str) -> Sensor:
        """The bound sensor object ``name`` (a ``HeightScan``, a ``CameraSpec``, ...); MuJoCo sensors of the model's
        own have views only."""
        if name not in self._sensors:
            raise KeyError(f"no bound sensor named {name!r}; bound sensors: {list(self._sensors)}")
        return self._sensors[name]

    def outputs(self, name: str) -> tuple[str, ...]:
        """The outputs of sensor ``name`` (a camera's ``rgb``, ``depth``, ``segmentation``); () for one view."""
        views = self._bound.get(name)
        return tuple(views) if isinstance(views, dict) else ()

    def view(self, name: str, key: str = "sensor", output: str | None = None) -> torch.Tensor:
        """(num_worlds, ...) view of sensor ``name`` (of its ``output``, for a sensor of several); ``key``: where the
        user named it (the error names it)."""
        views = self._bound.get(name)
        if views is None:
            if name not in self.context.columns:
                raise ConfigError(f"{key}: {name!r} is not a sensor of the model; its sensors: {self.names}")
            views = self.context.mujoco_sensor(name, key)
        outputs = list(views) if isinstance(views, dict) else []
        if outputs and output not in outputs:
            raise ConfigError(f"{key}: sensor {name!r} has the outputs {outputs}; give one (output={output!r})")
        if not outputs and output is not None:
            raise ConfigError(f"{key}: sensor {name!r} has one view, no output {output!r}")
        return views[output] if outputs else views

    def sense(self) -> None:
        """The sense phase: refresh every computed sensor from the current state (device torch work, capturable)."""
        for sensor in self.computed:
            sensor.sense()

    def render(self, run: Callable[[str, Callable[[], None]], None]) -> None:
        """The render phase: ``run`` (the simulator's graph engine) replays the render context's launches as the
        graph "render"; nothing without cameras."""
        if self.render_context is not None:
            run("render", self.render_context.launch)
            self.renders += 1
