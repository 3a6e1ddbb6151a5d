"""Observations as lists of named terms: size, scale and noise side by side, the total size derived.

A task declares what its policy (and critic) observe as a list of ``ObsTerm``; ``ObsLayout`` turns the list into
the things that used to be hand-kept in step with it: the total size (checked against ``env.numObservations`` /
``env.numStates`` with an error naming the key), each term's columns, the per-column noise amplitude, and the
description an exported policy carries.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Callable, Mapping, Sequence

import torch

from isaacgymenvs_mw.sim.cameras import CHANNELS, CameraSpec
from isaacgymenvs_mw.utils.errors import ConfigError

if TYPE_CHECKING:  # the simulator's sensor registry, which the image terms read
    from isaacgymenvs_mw.sim.sensor_registry import SensorRegistry


@dataclass(frozen=True)
class ObsTerm:
    """One named piece of an observation vector.

    Args:
        name: unique within its layout ("base_lin_vel", "dof_pos", ...).
        size: number of columns.
        scale: factor VecTask multiplies ``compute()``'s value by (also documentation and export).
        noise: half-width of the uniform noise added to the observed (scaled) value; 0 = none.
        compute: what computes the raw (num_envs, size) value: a function or bound method without arguments.
            None only for a task that fills its observation itself (the layout then documents it).
    """

    name: str
    size: int
    scale: float = 1.0
    noise: float = 0.0
    compute: Callable[[], torch.Tensor] | None = field(default=None, compare=False, repr=False)


def sensor_terms(sensor: Callable[..., torch.Tensor], scales: Mapping[str, float]) -> list[ObsTerm]:
    """One term per observed sensor (``env.observeSensors``: {name: scale}): the sensor's view (``sensor``: the
    simulator's ``sim.sensor``), flattened, times the scale; named as the sensor. A name that is no sensor of the
    model fails naming ``env.observeSensors.<name>``."""
    terms = []
    for name, scale in scales.items():
        view = sensor(name, key=f"env.observeSensors.{name}")
        terms.append(ObsTerm(name, int(view[0].numel()), scale, compute=lambda view=view: view.flatten(1)))
    return terms


class ObsLayout:
    """Column layout of an observation vector made of ``terms``, in order."""

    def __init__(self, terms: Sequence[ObsTerm]) -> None:
        names = [t.name for t in terms]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ConfigError(f"observation terms {duplicates} appear more than once; term names must be unique")
        bad = [t.name for t in terms if int(t.size) < 1]
        if bad:
            raise ConfigError(f"observation terms {bad} have size < 1")
        self.terms = tuple(terms)
        self.slices: dict[str, slice] = {}
        start = 0
        for t in self.terms:
            self.slices[t.name] = slice(start, start + int(t.size))
            start += int(t.size)
        self.size = start

    @property
    def names(self) -> list[str]:
        return [t.name for t in self.terms]

    def check(self, declared: int, key: str) -> None:
        """Fail, naming ``key``, when a size given in the YAML is not the sum of the terms."""
        if declared != self.size:
            parts = " + ".join(f"{t.name} {t.size}" for t in self.terms)
            raise ConfigError(f"{key}={declared}, but the task observes {self.size} values ({parts}); "
                             f"remove {key} (the size is derived from the terms) or set {key}: {self.size}")

    def noise_scale(self, device: torch.device | str) -> torch.Tensor:
        """(size,) uniform-noise half-widths, one per column."""
        return torch.cat([torch.full((int(t.size),), float(t.noise)) for t in self.terms]).to(device)

    def columns(self, names: Sequence[str], key: str) -> torch.Tensor:
        """Column indices of the named terms, in the order given; an unknown name fails naming ``key``."""
        unknown = [n for n in names if n not in self.slices]
        if unknown:
            raise ConfigError(f"{key}: unknown observation term(s) {unknown}; terms: {self.names}")
        return torch.cat([torch.arange(self.slices[n].start, self.slices[n].stop) for n in names])

    def describe(self) -> list[dict]:
        """The layout as plain data (name, size, scale, noise, first column), for logs and exported policies."""
        described = [f.name for f in fields(ObsTerm) if f.name != "compute"]
        return [{**{k: getattr(t, k) for k in described}, "start": self.slices[t.name].start} for t in self.terms]


IMAGE_OUTPUTS = ("rgb", "depth")  # camera outputs an image term may observe (their channels: sim/cameras.py)


@dataclass(frozen=True)
class ImageTerm:
    """One camera image in the image observation (the "camera" group), as uint8 channels in [0, 255].

    Args:
        name: unique within the image terms.
        camera: the ``env.cameras`` entry it reads.
        output: "rgb" (3 channels, R, G, B as rendered) or "depth" (1 channel: ``round(255 * depth / depthFar)``,
            so 0 is at the camera and 255 at ``depthFar`` or beyond, nothing hit included).
    """

    name: str
    camera: str
    output: str = "rgb"

    @property
    def channels(self) -> int:
        return CHANNELS[self.output]


def camera_terms(cameras: Mapping[str, CameraSpec] | None) -> list[ImageTerm]:
    """Image terms for every observable output (rgb, depth) of every ``env.cameras`` entry (``cameras``: the
    simulator's ``sim.cameras``), in YAML order: what the YAML declares is what the policy sees, so a camera and its
    outputs are named once. A term is named by its output, prefixed by ``<camera>_`` when there are several cameras."""
    cameras = dict(cameras or {})
    if not cameras:
        raise ConfigError("this task observes its cameras, but env.cameras declares none; declare one: "
                          "env.cameras.<name>: {pos, lookAt, width, height, outputs: [rgb]}")
    prefix = len(cameras) > 1
    return [ImageTerm(f"{name}_{output}" if prefix else output, camera=name, output=output)
            for name, camera in cameras.items() for output in camera.outputs if output in IMAGE_OUTPUTS]


class ImageGroup:
    """The image observation: the terms' images stacked along channels, (num_envs, C, H, W) uint8 on the device.

    uint8 keeps rollout storage at one byte per pixel and channel; the policy's model scales it to [0, 1]
    (``learning/models.py``). Every term must come from a camera of the same width and height.
    """

    def __init__(self, terms: Sequence[ImageTerm], sensors: SensorRegistry) -> None:
        names = [t.name for t in terms]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ConfigError(f"image observation terms {duplicates} appear more than once; names must be unique")
        cameras = sensors.cameras
        self.sources = []  # each term's camera
        self.images = []  # each term's (num_envs, C, H, W) view: the camera sensor's output
        for t in terms:
            if t.output not in IMAGE_OUTPUTS:
                raise ConfigError(f"image observation term '{t.name}': output '{t.output}' is not one of "
                                  f"{list(IMAGE_OUTPUTS)}")
            if t.camera not in cameras:
                raise ConfigError(f"image observation term '{t.name}' reads camera '{t.camera}', which env.cameras "
                                  f"does not declare (cameras: {list(cameras)}); declare env.cameras.{t.camera}")
            view = cameras[t.camera]
            if t.output not in view.outputs:
                raise ConfigError(f"image observation term '{t.name}' reads the {t.output} image of camera "
                                  f"'{t.camera}', but env.cameras.{t.camera}.outputs={list(view.outputs)} does not "
                                  f"render it; add {t.output} to env.cameras.{t.camera}.outputs")
            self.sources.append(view)
            self.images.append(sensors.view(t.camera, f"image observation term '{t.name}'", t.output))
        sizes = {(v.height, v.width) for v in self.sources}
        if len(sizes) != 1:
            listing = {t.camera: f"{v.width}x{v.height}" for t, v in zip(terms, self.sources)}
            raise ConfigError(f"image observation terms read cameras of different sizes {listing}; give their "
                              "env.cameras entries one width and height")
        (height, width), = sizes
        self.terms = tuple(terms)
        self.shape = (sum(t.channels for t in terms), height, width)
        # The flat view of a frame, term by term: what env.history.camera stacks (its terms select blocks).
        self.layout = ObsLayout([ObsTerm(t.name, t.channels * height * width) for t in terms])

    def compute(self, out: torch.Tensor) -> torch.Tensor:
        """Write the cameras' current images into ``out`` ((num_envs, C, H, W) uint8, e.g. the newest slot of a
        frame stack; device work only); returns it."""
        start = 0
        for term, camera, image in zip(self.terms, self.sources, self.images):
            part = out[:, start:start + term.channels]
            if term.output == "rgb":
                part.copy_(image)
            else:
                part.copy_(torch.round(image * (255.0 / camera.depth_far)).clamp_(0.0, 255.0))
            start += term.channels
        return out

    def picture(self, frame: torch.Tensor, world: int = 0) -> torch.Tensor:
        """World ``world``'s image in ``frame`` (num_envs, C, H, W) as one (H, W * terms, 3) uint8 RGB picture,
        terms side by side (depth as grey), for people: videos of what the policy sees."""
        tiles, start = [], 0
        for term in self.terms:
            part = frame[world, start:start + term.channels]
            tiles.append(part.expand(3, -1, -1) if term.channels == 1 else part)
            start += term.channels
        return torch.cat(tiles, dim=2).permute(1, 2, 0)

    def describe(self) -> list[dict]:
        """The terms as plain data (name, camera, output, channels, first channel), for exported policies."""
        out, start = [], 0
        for term, view in zip(self.terms, self.sources):
            out.append({"name": term.name, "camera": term.camera, "output": term.output, "channels": term.channels,
                        "start_channel": start, **({"depth_far": view.depth_far} if term.output == "depth" else {})})
            start += term.channels
        return out
