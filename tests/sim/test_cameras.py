"""Cameras in the sim layer (sim/cameras.py) against MuJoCo C.

The scene (tests/assets/camera_scene.xml) has a floor, a wall and a carrier body that slides and turns, carrying a
box and a ball. For every pixel of every world, MuJoCo C's ``mj_ray`` is cast from the camera pose ``mj_forward``
computes for that world's ``qpos``, through the pixel's centre: the rendered depth must equal the distance it
returns times the cosine of the ray's angle to the optical axis (planar depth; ``depthFar`` where nothing is hit
within it), and the segmentation must name the geom it hits.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from conftest import TESTS_DIR

from isaacgymenvs_mw.sim import Simulator, build_model, request_from_config
from isaacgymenvs_mw.sim.cameras import camera_specs, image_bytes
from isaacgymenvs_mw.utils.errors import ConfigError

QPOS = torch.tensor([[0.0, 0.0], [0.7, 0.5], [-0.9, -1.2]])  # (slide m, turn rad) per world


def scene_env(**cameras) -> dict:
    side = {"pos": [0.3, -4.0, 1.2], "lookAt": [0.0, 0.0, 0.5], "fovy": 50, "width": 40, "height": 30,
            "outputs": ["rgb", "depth", "segmentation"], "depthFar": 30.0}
    # On the carrier, behind and to the right of it, looking at its ball (a point in the carrier's frame).
    onboard = {"body": "carrier", "pos": [-1.2, -0.8, 0.6], "lookAt": [0.1, 0.0, 0.4], "width": 32, "height": 24,
               "outputs": ["depth", "segmentation"], "depthFar": 3.0}
    return {"asset": {"assetRoot": str(TESTS_DIR / "assets"), "assetFileName": "camera_scene.xml"},
            "cameras": cameras or {"side": side, "onboard": onboard}}


def make_sim(env: dict, num_worlds: int = 3, **kwargs) -> tuple[Simulator, mujoco.MjModel]:
    request = request_from_config(env, {"dt": 0.01}, None, Path("assets"))
    model = build_model(request)
    return Simulator(model, num_worlds, "cpu", declared_sensors=request.all_sensors(), **kwargs), model


class Images:
    """Camera ``name`` of ``sim`` as these tests read it: its declared size and depth range (``sim.cameras``), and
    each output it renders as the sensor view ``sim.sensor(name, output=...)``."""

    def __init__(self, sim: Simulator, name: str) -> None:
        spec = sim.cameras[name]
        self.width, self.height, self.depth_far, self.outputs = spec.width, spec.height, spec.depth_far, spec.outputs
        self.images = {out: sim.sensor(name, output=out) for out in spec.outputs}
        self.rgb, self.depth, self.segmentation = (self.images.get(out) for out in ("rgb", "depth", "segmentation"))


@pytest.fixture(scope="module")
def rendered() -> Simulator:
    sim, _ = make_sim(scene_env())
    sim.qpos.copy_(QPOS)  # written without a pose refresh: the render computes poses from qpos itself
    sim.render_cameras()
    return sim


def ray_cast(m: mujoco.MjModel, qpos: np.ndarray, camera: str, width: int, height: int) -> tuple[np.ndarray, ...]:
    """Planar depth (inf: no hit) and geom id (-1: none) through each pixel centre, from MuJoCo C."""
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    cid = m.camera(camera).id
    rot, origin = d.cam_xmat[cid].reshape(3, 3), d.cam_xpos[cid]
    half = math.tan(math.radians(float(m.cam_fovy[cid])) / 2)
    depth, geom = np.full((height, width), np.inf), np.full((height, width), -1)
    hit = np.zeros(1, np.int32)
    for r in range(height):
        for c in range(width):
            # Camera frame: x right, y up, looking along -z; row 0 at the top.
            ray = np.array([(2 * (c + 0.5) / width - 1) * half * width / height, (1 - 2 * (r + 0.5) / height) * half,
                            -1.0])
            length = np.linalg.norm(ray)
            dist = mujoco.mj_ray(m, d, origin, rot @ (ray / length), None, 1, -1, hit)
            if dist >= 0:
                depth[r, c], geom[r, c] = dist / length, hit[0]  # cos(angle to the axis) = 1 / length
    return depth, geom


@pytest.mark.parametrize("camera", ["side", "onboard"])
def test_depth_and_segmentation_equal_mj_ray_through_the_same_pixels(rendered, camera):
    sim, view = rendered, Images(rendered, camera)
    assert view.depth.shape == (3, 1, view.height, view.width) and view.depth.dtype == torch.float32
    assert view.segmentation.shape == (3, 1, view.height, view.width) and view.segmentation.dtype == torch.int32
    for world in range(3):
        depth, geom = ray_cast(sim.mj_model, QPOS[world].numpy(), camera, view.width, view.height)
        expected = np.where(depth > view.depth_far, view.depth_far, depth)
        np.testing.assert_allclose(view.depth[world, 0].numpy(), expected, atol=1e-4, rtol=0)
        np.testing.assert_array_equal(view.segmentation[world, 0].numpy(), geom)
        assert (depth > view.depth_far).any() and np.isfinite(depth).any()  # both cases occur


def test_a_camera_on_a_moving_body_follows_it(rendered):
    """The onboard camera moves and turns with the carrier: the carrier's own box and ball fill the same pixels
    at the same depths in every world, while the world-fixed camera sees them elsewhere."""
    m = rendered.mj_model
    carried = [m.geom("box").id, m.geom("ball").id]
    seg = rendered.sensor("onboard", output="segmentation")[:, 0]
    depth = rendered.sensor("onboard", output="depth")[:, 0]
    on_carrier = torch.isin(seg, torch.tensor(carried))
    assert on_carrier[0].float().mean() > 0.05
    for world in (1, 2):
        assert torch.equal(on_carrier[world], on_carrier[0])
        torch.testing.assert_close(depth[world][on_carrier[0]], depth[0][on_carrier[0]], atol=1e-4, rtol=0)
    side = torch.isin(rendered.sensor("side", output="segmentation")[:, 0], torch.tensor(carried))
    assert not torch.equal(side[1], side[0]) and not torch.equal(side[2], side[0])


def test_segmentation_ids_name_the_geoms_and_rgb_has_their_colours(rendered):
    """Each geom id covers pixels of that geom's colour (R, G, B channel order); the background is -1."""
    m, view = rendered.mj_model, Images(rendered, "side")
    assert view.rgb.shape == (3, 3, view.height, view.width) and view.rgb.dtype == torch.uint8
    seg, rgb = view.segmentation[:, 0], view.rgb.permute(0, 2, 3, 1).float()
    for name, channel in (("box", 0), ("ball", 1), ("wall", 2)):  # red box, green ball, blue wall
        pixels = rgb[seg == m.geom(name).id]
        assert len(pixels) > 10, name
        others = [c for c in range(3) if c != channel]
        assert (pixels[:, channel] > pixels[:, others].max(dim=1).values).float().mean() > 0.95, name
    assert (seg == -1).any() and (rgb[seg == -1] == 0).all()  # nothing hit: the black background


def test_render_follows_writes_and_resets(rendered):
    """A state written from torch (as a task's reset does) shows in the next render, in that world only."""
    sim, _ = make_sim(scene_env(), num_worlds=2)
    sim.qpos.copy_(QPOS[:2])
    sim.render_cameras()
    before = sim.sensor("side", output="depth").clone()
    sim.reset_worlds(torch.tensor([False, True]))  # world 1 back to qpos0 = QPOS[0]
    sim.render_cameras()
    after = sim.sensor("side", output="depth")
    torch.testing.assert_close(after[0], before[0])
    torch.testing.assert_close(after[1], before[0])  # as world 0, which sits at qpos0


def test_captured_render_equals_eager():
    eager, _ = make_sim(scene_env(), num_worlds=2)
    captured, _ = make_sim(scene_env(), num_worlds=2, use_graphs=True)
    for step in range(3):
        for sim in (eager, captured):
            sim.qpos.copy_(QPOS[:2] * (1 + step))
            sim.render_cameras()
        for name in ("side", "onboard"):
            for out in eager.sensors.outputs(name):
                assert torch.equal(captured.sensor(name, output=out), eager.sensor(name, output=out)), (step, name, out)
    assert "render" in captured._graphs


@pytest.mark.parametrize("change, message", [
    ({"body": "nope"}, "env.cameras.cam.body: 'nope' matches no body (a pattern must match the whole name); "
                       "bodies: ['carrier']"),
    ({"width": 0}, "env.cameras.cam.width=0 is invalid: give a whole number >= 1"),
    ({"height": 2.5}, "env.cameras.cam.height=2.5 is invalid: give a whole number >= 1"),
    ({"outputs": ["rgb", "normals"]}, "env.cameras.cam.outputs=['rgb', 'normals'] is invalid: give a non-empty list "
                                      "of distinct names from ['rgb', 'depth', 'segmentation']"),
    ({"fovy": 180}, "env.cameras.cam.fovy=180 is invalid: give a number > 0.0 and <= 179.0"),
    ({"lookAt": [0, 0, 0], "rot": [1, 0, 0, 0]}, "env.cameras.cam: give rot or lookAt, not both"),
    ({"zoom": 2}, "env.cameras.cam: unknown key(s) ['zoom']; valid keys: ['body', 'pos', 'rot', 'lookAt', 'fovy', "
                  "'width', 'height', 'outputs', 'depthFar']"),
])
def test_bad_camera_entries_are_one_line_errors_naming_the_key(change, message):
    with pytest.raises(ConfigError) as err:
        make_sim(scene_env(cam={"pos": [0, -3, 1], **change}), num_worlds=1)
    assert str(err.value) == message


def test_a_resolution_that_does_not_fit_in_memory_is_refused():
    cam = {"pos": [0, -3, 1], "width": 100000, "height": 100000}
    with pytest.raises(ConfigError, match=r"^env\.cameras\.cam\.width=100000, env\.cameras\.cam\.height=100000: "
                                          r"the images of 4 worlds would take 260\.8 GiB, more than 50% of the memory "
                                          r"free on cpu; lower the resolution or numEnvs$"):
        make_sim(scene_env(cam=cam), num_worlds=4)


def test_image_bytes_per_world():
    (spec,) = camera_specs({"c": {"width": 64, "height": 64, "outputs": ["rgb", "depth"]}})
    assert image_bytes([spec], 1000) == 1000 * 64 * 64 * (7 + 8)
