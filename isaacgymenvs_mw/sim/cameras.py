"""Cameras: declared in the task YAML (``env.cameras``), added to the model, drawn for every world at once by MuJoCo
Warp's batch renderer, and seen from torch as (num_worlds, C, H, W) tensors that are views of device memory.

One render context draws every camera of every world (MuJoCo Warp 4.0 has no per-world rendering). A render is,
all on the device and capturable as one CUDA graph: body and camera poses from the current ``qpos``
(``kinematics`` + ``camlight``: after a physics step MuJoCo Warp's poses describe the state before it, and a reset
writes ``qpos`` only), the scene BVH refitted to those poses (``render`` does not, and a stale BVH drops pixels),
the ray-traced render, and a small kernel per camera and output that unpacks the renderer's packed buffers into
channel-first images:

  * ``rgb``           (N, 3, H, W) uint8, channels R, G, B.
  * ``depth``         (N, 1, H, W) float32, metres along the camera's optical axis (planar depth: a point's distance
                      times the cosine of its ray's angle to the axis); nothing hit within ``depthFar`` reads
                      ``depthFar``.
  * ``segmentation``  (N, 1, H, W) int32, the MuJoCo geom id seen through each pixel, -1 where none is.

Row 0 of an image is its top; column 0 its left. A MuJoCo camera looks along its frame's -z axis with +y up.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import ClassVar, Mapping, Sequence

import mujoco
import numpy as np
import torch
import warp as wp

import mujoco_warp as mjw
from isaacgymenvs_mw.sim.names import one_body
from isaacgymenvs_mw.sim.sensors import Sensor, SensorContext
from isaacgymenvs_mw.utils.config import check_entry, real_number, whole_number
from isaacgymenvs_mw.utils.errors import ConfigError

OUTPUTS = ("rgb", "depth", "segmentation")
# The channels of each output's image: the one table of them (the image observation reads it too).
CHANNELS = {"rgb": 3, "depth": 1, "segmentation": 1}
CAMERA_KEYS = ("body", "pos", "rot", "lookAt", "fovy", "width", "height", "outputs", "depthFar")
WORLD = "world"  # env.cameras.<name>.body of a camera fixed in the world

# Device bytes per pixel and world of each output: the renderer's packed buffer plus our channel-first image.
_BYTES_PER_PIXEL = {"rgb": 4 + 3, "depth": 4 + 4, "segmentation": 8 + 4}
_OBJ_GEOM = wp.constant(int(mujoco.mjtObj.mjOBJ_GEOM))

# Of the memory free on the device, the share image buffers may take: physics, rollout storage and the networks
# need the rest.
MEMORY_SHARE = 0.5


@dataclass(frozen=True)
class CameraSpec(Sensor):
    """One ``env.cameras.<name>`` entry, checked: a ``Sensor`` with one view per output, refreshed by the simulator's
    render (``refresh``; the module docstring says what a render does).

    ``body``: the body the camera is attached to (a pattern that must select exactly one body of the scene; checked
    when the model is built), None for a camera fixed in the world. ``pos`` and ``quat`` (w, x, y, z) place it in
    that body's frame (the world frame when fixed). ``fovy``: vertical field of view in degrees.
    """

    refresh: ClassVar[str] = "render"

    name: str
    body: str | None
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    fovy: float
    width: int
    height: int
    outputs: tuple[str, ...] = field()  # required: field() hides the default of Sensor.outputs
    depth_far: float

    @property
    def key(self) -> str:
        return f"env.cameras.{self.name}"

    def add_to(self, spec: mujoco.MjSpec) -> None:
        """Add the camera on its body (the one body its pattern selects in the composed scene) or the world body."""
        parent = spec.worldbody if self.body is None else spec.body(one_body(spec, self.body, f"{self.key}.body"))
        parent.add_camera(name=self.name, pos=list(self.pos), quat=list(self.quat), fovy=float(self.fovy),
                          resolution=[self.width, self.height])

    def bind(self, context: SensorContext) -> dict[str, torch.Tensor]:
        """{output: (N, C, H, W) image}: the views the render context writes (``sim.sensor(name, output=...)``)."""
        images = context.images[self.name]
        return {output: images[output] for output in self.outputs}


def camera_specs(cfg: Mapping | None) -> tuple[CameraSpec, ...]:
    """``env.cameras``: {name: {body, pos, rot | lookAt, fovy, width, height, outputs, depthFar}} in YAML order;
    a bad value is an error naming ``env.cameras.<name>.<key>``."""
    if not cfg:
        return ()
    if not hasattr(cfg, "items"):
        raise ConfigError(f"env.cameras={cfg!r} is invalid: give a mapping {{name: {{pos: [x, y, z], lookAt: "
                          "[x, y, z], width: 64, height: 64, outputs: [rgb]}}}}")
    return tuple(_camera_spec(str(name), entry) for name, entry in cfg.items())


def _camera_spec(name: str, entry: Mapping) -> CameraSpec:
    key = f"env.cameras.{name}"
    check_entry(entry, key, CAMERA_KEYS)
    body = str(entry.get("body", WORLD))
    pos = _numbers(entry.get("pos", (0.0, 0.0, 0.0)), 3, f"{key}.pos")
    if entry.get("rot") is not None and entry.get("lookAt") is not None:
        raise ConfigError(f"{key}: give rot or lookAt, not both")
    if entry.get("lookAt") is not None:
        quat = look_at_quat(pos, _numbers(entry["lookAt"], 3, f"{key}.lookAt"), f"{key}.lookAt")
    else:
        quat = _numbers(entry.get("rot", (1.0, 0.0, 0.0, 0.0)), 4, f"{key}.rot")
        if not math.isclose(sum(v * v for v in quat), 1.0, rel_tol=1e-3):
            raise ConfigError(f"{key}.rot={list(quat)} is not a unit quaternion (w, x, y, z)")
    fovy = real_number(entry.get("fovy", 45.0), f"{key}.fovy", 0.0, 179.0, low_open=True)  # degrees
    size = {dim: whole_number(entry.get(dim, 64), f"{key}.{dim}", 1) for dim in ("width", "height")}  # pixels
    outputs = entry.get("outputs", ["rgb"])
    outputs = [outputs] if isinstance(outputs, str) else list(outputs or [])
    if not outputs or any(o not in OUTPUTS for o in outputs) or len(set(outputs)) != len(outputs):
        raise ConfigError(f"{key}.outputs={outputs!r} is invalid: give a non-empty list of distinct names from "
                          f"{list(OUTPUTS)}")
    far = real_number(entry.get("depthFar", 10.0), f"{key}.depthFar", 0.0, low_open=True)  # metres
    return CameraSpec(name, None if body == WORLD else body, pos, quat, fovy, size["width"], size["height"],
                      tuple(o for o in OUTPUTS if o in outputs), far)


def _numbers(value: object, size: int, key: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        out = ()
    if len(out) != size:
        raise ConfigError(f"{key}={value!r} is invalid: give {size} numbers")
    return out


def look_at_quat(pos: Sequence[float], target: Sequence[float], key: str = "lookAt") -> tuple[float, ...]:
    """The orientation (w, x, y, z) of a camera at ``pos`` that looks at ``target`` with the frame's +z up in the
    image (+y when it looks straight up or down)."""
    back = np.asarray(pos, dtype=float) - np.asarray(target, dtype=float)  # the camera's +z: it looks along -z
    if np.linalg.norm(back) < 1e-9:
        raise ConfigError(f"{key}={list(target)} is the camera's own position: give a point it looks at")
    z = back / np.linalg.norm(back)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.999 else np.array([0.0, 1.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.stack([x, y, z], axis=1).ravel())
    return tuple(float(v) for v in quat)


@wp.kernel
def _unpack_rgb(packed: wp.array2d(dtype=wp.uint32), adr: int, width: int, out: wp.array4d(dtype=wp.uint8)):
    world, pixel = wp.tid()
    value = packed[world, adr + pixel]  # 0xAARRGGBB
    row, col = pixel // width, pixel % width
    out[world, 0, row, col] = wp.uint8((value >> wp.uint32(16)) & wp.uint32(255))
    out[world, 1, row, col] = wp.uint8((value >> wp.uint32(8)) & wp.uint32(255))
    out[world, 2, row, col] = wp.uint8(value & wp.uint32(255))


@wp.kernel
def _unpack_depth(packed: wp.array2d(dtype=float), adr: int, width: int, far: float,
                  out: wp.array4d(dtype=float)):
    world, pixel = wp.tid()
    value = packed[world, adr + pixel]  # planar depth, 0 where nothing is hit
    if value <= 0.0 or value > far:
        value = far
    out[world, 0, pixel // width, pixel % width] = value


@wp.kernel
def _unpack_segmentation(packed: wp.array2d(dtype=wp.vec2i), adr: int, width: int, out: wp.array4d(dtype=int)):
    world, pixel = wp.tid()
    value = packed[world, adr + pixel]  # (object id, object type), (-1, -1) for the background
    geom = -1
    if value[1] == _OBJ_GEOM:
        geom = value[0]
    out[world, 0, pixel // width, pixel % width] = geom


class CameraView:
    """The images of one camera for every world: ``rgb``, ``depth``, ``segmentation`` (None where the camera does
    not render that output), torch views of device memory that each render rewrites in place."""

    def __init__(self, spec: CameraSpec, index: int, arrays: dict[str, wp.array]) -> None:
        self.spec = spec
        self.name = spec.name
        self.index = index  # among the render context's cameras
        self.width, self.height = spec.width, spec.height
        self.outputs = spec.outputs
        self.depth_far = spec.depth_far
        self.arrays = arrays
        views = {out: wp.to_torch(a) for out, a in arrays.items()}
        self.rgb: torch.Tensor | None = views.get("rgb")
        self.depth: torch.Tensor | None = views.get("depth")
        self.segmentation: torch.Tensor | None = views.get("segmentation")

    def image(self, output: str) -> torch.Tensor:
        """The (N, C, H, W) view of ``output``."""
        view = getattr(self, output, None)
        if view is None:
            raise ConfigError(f"{self.spec.key}.outputs={list(self.outputs)} does not render {output}; add it there")
        return view


class Cameras:
    """The render context of a model's YAML cameras and their images (see the module docstring)."""

    def __init__(self, mj_model: mujoco.MjModel, model, data, specs: Sequence[CameraSpec], num_worlds: int,
                 wp_device: wp.context.Device) -> None:
        self.model, self.data = model, data
        self.num_worlds = int(num_worlds)
        check_image_memory(specs, self.num_worlds, wp_device)
        ids = []
        for cam in specs:
            cid = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_CAMERA, cam.name)
            if cid < 0:
                raise ConfigError(f"{cam.key}: the model has no camera named '{cam.name}'")
            ids.append(cid)
        # The context lists its cameras in model order; cam_active as a mask keeps that order.
        order = sorted(range(len(specs)), key=lambda i: ids[i])
        self.specs = [specs[i] for i in order]
        active = [False] * mj_model.ncam
        for i in order:
            active[ids[i]] = True
        with wp.ScopedDevice(wp_device):
            self.context = mjw.create_render_context(
                mj_model, nworld=self.num_worlds,
                cam_res=[(c.width, c.height) for c in self.specs],
                render_rgb=["rgb" in c.outputs for c in self.specs],
                render_depth=["depth" in c.outputs for c in self.specs],
                render_seg=["segmentation" in c.outputs for c in self.specs],
                cam_active=active,
            )
            self.views: dict[str, CameraView] = {}
            for index, cam in enumerate(self.specs):
                arrays = {}
                for out in cam.outputs:
                    dtype = {"rgb": wp.uint8, "depth": float, "segmentation": int}[out]
                    arrays[out] = wp.zeros((self.num_worlds, CHANNELS[out], cam.height, cam.width), dtype=dtype)
                self.views[cam.name] = CameraView(cam, index, arrays)
        rc = self.context
        self._adr = {"rgb": rc.rgb_adr.numpy(), "depth": rc.depth_adr.numpy(), "segmentation": rc.seg_adr.numpy()}

    def images(self) -> dict[str, dict[str, torch.Tensor]]:
        """{camera: {output: (N, C, H, W) image}}: the views each render rewrites, what the cameras bind to."""
        return {name: {out: view.image(out) for out in view.outputs} for name, view in self.views.items()}

    def launch(self) -> None:
        """Poses from the current state, BVH refit, render, unpack: Warp launches only (capturable)."""
        m, d, rc = self.model, self.data, self.context
        mjw.kinematics(m, d)
        mjw.camlight(m, d)
        mjw.refit_bvh(m, d, rc)
        mjw.render(m, d, rc)
        packed = {"rgb": rc.rgb_data, "depth": rc.depth_data, "segmentation": rc.seg_data}
        for view in self.views.values():
            dim = (self.num_worlds, view.width * view.height)
            for out, array in view.arrays.items():
                adr = int(self._adr[out][view.index])
                if out == "rgb":
                    wp.launch(_unpack_rgb, dim=dim, inputs=[packed[out], adr, view.width, array])
                elif out == "depth":
                    wp.launch(_unpack_depth, dim=dim, inputs=[packed[out], adr, view.width, view.depth_far, array])
                else:
                    wp.launch(_unpack_segmentation, dim=dim, inputs=[packed[out], adr, view.width, array])


def image_bytes(specs: Sequence[CameraSpec], num_worlds: int) -> int:
    """Device bytes the image buffers of ``specs`` take for ``num_worlds`` worlds."""
    per_world = sum(c.width * c.height * _BYTES_PER_PIXEL[o] for c in specs for o in c.outputs)
    return per_world * int(num_worlds)


def check_image_memory(specs: Sequence[CameraSpec], num_worlds: int, wp_device: wp.context.Device) -> None:
    """Refuse resolutions whose image buffers would take more than ``MEMORY_SHARE`` of the device's free memory,
    naming the camera's width and height keys."""
    free = _free_bytes(wp_device)
    budget = MEMORY_SHARE * free
    for cam in specs:
        need = image_bytes([cam], num_worlds)
        if need > budget:
            raise ConfigError(
                f"{cam.key}.width={cam.width}, {cam.key}.height={cam.height}: the images of {num_worlds} worlds "
                f"would take {need / 2**30:.1f} GiB, more than {MEMORY_SHARE:.0%} of the memory free on "
                f"{wp_device.alias}; lower the resolution or numEnvs"
            )


def _free_bytes(wp_device: wp.context.Device) -> int:
    if wp_device.is_cuda:
        return int(wp_device.free_memory)
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 2**40  # unknown: do not refuse
