"""Cameras are sensors (sim/sensors.py): an ``env.cameras`` entry is a ``Sensor`` refreshed by the render, listed
with the model's other sensors, and its views through ``Simulator.sensor(name, output=...)`` are the very tensors
the render writes and the image observation reads."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from conftest import TESTS_DIR

import isaacgymenvs_mw
from isaacgymenvs_mw.sim import Sensor, Simulator, build_model, request_from_config
from isaacgymenvs_mw.sim.cameras import CameraSpec
from isaacgymenvs_mw.utils.errors import ConfigError

SMALL = ["task.env.cameras.front.width=32", "task.env.cameras.front.height=16"]  # a cheap image for the CPU


def test_a_camera_is_a_sensor_whose_views_are_the_images_the_observation_reads():
    task = isaacgymenvs_mw.make("CartpoleCamera", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True,
                                overrides=[*SMALL, "task.env.cameras.front.outputs=[rgb,depth]",
                                           "task.env.history.camera.length=1"])
    sim, images = task.sim, task.observations.images
    (camera,) = [s for s in task.model_request().all_sensors() if s.name == "front"]
    assert isinstance(camera, CameraSpec) and isinstance(camera, Sensor) and camera.refresh == "render"
    assert "front" in sim.sensors.names and sim.sensors.outputs("front") == ("rgb", "depth")
    assert [t.output for t in images.terms] == ["rgb", "depth"]
    for term, read in zip(images.terms, images.images):  # what ImageGroup.compute copies into the observation
        view = sim.sensor("front", output=term.output)
        assert view is read and view.data_ptr() == read.data_ptr()
    # The observation after a step is built from those views, as the render left them.
    obs, *_ = task.step(torch.zeros(2, 1))
    assert torch.equal(obs["camera"][:, 0:3], sim.sensor("front", output="rgb"))
    expected = torch.round(sim.sensor("front", output="depth") * 255 / camera.depth_far).to(torch.uint8)
    assert torch.equal(obs["camera"][:, 3:4], expected)
    with pytest.raises(ConfigError, match=r"^sensor: sensor 'front' has the outputs \['rgb', 'depth'\]; give one "
                                          r"\(output=None\)$"):
        sim.sensor("front")


def test_cameras_given_as_sensors_are_rendered_in_one_render_and_not_sensed():
    env = {"asset": {"assetRoot": str(TESTS_DIR / "assets"), "assetFileName": "camera_scene.xml"},
           "cameras": {"a": {"pos": [0.3, -4.0, 1.2], "lookAt": [0, 0, 0.5], "width": 8, "height": 6,
                             "outputs": ["depth"]},
                       "b": {"body": "carrier", "pos": [-1.2, -0.8, 0.6], "lookAt": [0.1, 0, 0.4], "width": 4,
                             "height": 4, "outputs": ["segmentation", "rgb"]}}}
    request = request_from_config(env, {"dt": 0.01}, None, Path("assets"))
    assert [s.name for s in request.all_sensors()] == ["a", "b"]
    sim = Simulator(build_model(request), 2, "cpu", declared_sensors=request.all_sensors())
    assert sim.sensors.outputs("a") == ("depth",) and sim.sensors.outputs("b") == ("rgb", "segmentation")
    assert sim.sensors.computed == []  # nothing of theirs in the sense phase
    sim.sense()
    assert sim.sensors.renders == 0 and (sim.sensor("a", output="depth") == 0).all()
    sim.render_cameras()
    assert sim.sensors.renders == 1
    assert (sim.sensor("a", output="depth") > 0).all() and sim.sensor("b", output="segmentation").max() >= 0
    assert list(sim.cameras) == ["a", "b"] and sim.cameras["b"].outputs == ("rgb", "segmentation")
    with pytest.raises(ConfigError, match=r"^two sensors of the model are named 'a'"):
        Simulator(build_model(request), 1, "cpu", declared_sensors=(*request.all_sensors(), request.cameras[0]))
