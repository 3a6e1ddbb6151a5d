"""Image observations: image terms from cameras, frame stacking (env.history.camera), the "camera" group handed to
rsl_rl, the uint8 -> [0, 1] model, and CartpoleCamera training and evaluating from pixels on the CPU."""

from __future__ import annotations

import json

import numpy as np

import pytest
import torch
from rsl_rl.models import CNNModel
from tensordict import TensorDict

import isaacgymenvs_mw
from isaacgymenvs_mw.learning.export import read_metadata
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.learning.models import ImageCNNModel
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.tasks.base.observation_terms import ImageTerm
from isaacgymenvs_mw.tasks.cartpole_camera import CartpoleCamera
from isaacgymenvs_mw.utils.config import compose_config, to_dict
from isaacgymenvs_mw.utils.errors import ConfigError

SMALL = ["task.env.cameras.front.width=32", "task.env.cameras.front.height=16"]  # a cheap image for the CPU


def make(task: str = "CartpoleCamera", num_envs: int = 4, overrides: tuple[str, ...] = ()) -> CartpoleCamera:
    return isaacgymenvs_mw.make(task, num_envs=num_envs, sim_device="cpu", rl_device="cpu", headless=True,
                                overrides=[*SMALL, *overrides])


def test_the_camera_group_is_the_rendered_image_with_past_frames_that_shift_and_reset():
    task = make()
    first = task.reset()["camera"]
    assert first.shape == (4, 9, 16, 32) and first.dtype == torch.uint8
    view = task.sim.sensor("front", output="rgb")
    # After a reset every past frame is the first one.
    assert torch.equal(first[:, 0:3], view) and torch.equal(first[:, 3:6], view) and torch.equal(first[:, 6:9], view)
    previous = first
    resets_seen = 0
    for _ in range(40):
        obs, _, reset, _ = task.step(torch.ones(4, 1))  # full push: episodes end within the loop
        current = obs["camera"]
        assert torch.equal(current[:, 0:3], task.sim.sensor("front", output="rgb"))  # this step's render
        new = reset.bool()
        resets_seen += int(new.sum())
        # Envs that go on: frames move back by one. Envs that restarted: all frames are the new episode's first.
        assert torch.equal(current[~new][:, 3:9], previous[~new][:, 0:6])
        assert torch.equal(current[new][:, 3:6], current[new][:, 0:3])
        assert torch.equal(current[new][:, 6:9], current[new][:, 0:3])
        previous = current
    assert resets_seen > 0
    assert (previous[:, 0:3] != previous[:, 3:6]).any()  # the images do change from step to step


def test_stacking_selected_terms_keeps_only_their_channels_of_past_frames():
    """env.history.camera.terms: the current frame keeps every term; past frames keep the named terms' channels, and
    a step's observation is still intact after the next step (the learner stores it then)."""
    task = make(overrides=("task.env.cameras.front.outputs=[rgb,depth]", "task.env.cameras.front.depthFar=6.0",
                           "+task.env.history.camera.terms=[depth]"))
    first = task.reset()["camera"]
    assert first.shape == (4, 4 + 2 * 1, 16, 32)
    depth = lambda: torch.round(task.sim.sensor("front", output="depth") * 255 / 6.0).to(torch.uint8)  # noqa: E731
    assert torch.equal(first[:, 4:5], depth()) and torch.equal(first[:, 5:6], depth())
    previous = first
    for _ in range(30):
        kept = previous.clone()
        obs, _, reset, _ = task.step(torch.ones(4, 1))
        current, new = obs["camera"], reset.bool()
        assert torch.equal(previous, kept)  # the step did not overwrite the observation it followed
        assert torch.equal(current[:, 0:3], task.sim.sensor("front", output="rgb"))
        assert torch.equal(current[:, 3:4], depth())
        assert torch.equal(current[~new][:, 4:5], previous[~new][:, 3:4])  # last step's depth, one slot back
        assert torch.equal(current[~new][:, 5:6], previous[~new][:, 4:5])
        assert torch.equal(current[new][:, 4:6], current[new][:, 3:4].expand(-1, 2, -1, -1))
        previous = current
    assert (previous[:, 3:4] != previous[:, 4:5]).any()


def test_depth_terms_are_depth_over_depth_far_in_bytes():
    task = make("CartpoleCameraDepth", overrides=("task.env.history.camera.length=1",))
    obs = task.reset()["camera"]
    depth, depth_far = task.sim.sensor("front", output="depth"), task.sim.cameras["front"].depth_far
    assert obs.shape == (4, 1, 16, 32)
    expected = torch.round(depth * 255 / depth_far).to(torch.uint8)
    assert torch.equal(obs, expected)
    assert (obs == 255).any() and (obs < 255).any()  # background at depthFar, the cart-pole nearer


def test_render_interval_keeps_the_last_images_between_renders():
    task = make(overrides=("task.env.renderInterval=3", "task.env.history.camera.length=1"))
    task.reset()
    renders = task.sim.sensors.renders
    for _ in range(6):
        task.step(torch.zeros(4, 1))
    assert task.sim.sensors.renders - renders == 2


class _BackCamera(CartpoleCamera):
    def image_terms(self) -> list[ImageTerm]:
        return [ImageTerm("pixels", camera="back")]


class _FrontDepth(CartpoleCamera):
    def image_terms(self) -> list[ImageTerm]:
        return [ImageTerm("far", camera="front", output="depth")]


def test_image_terms_without_their_camera_or_output_are_one_line_errors():
    task_cfg = to_dict(compose_config(["task=CartpoleCamera", "num_envs=2", *SMALL]).task)
    with pytest.raises(ConfigError, match=r"^image observation term 'pixels' reads camera 'back', which env\.cameras "
                                          r"does not declare \(cameras: \['front'\]\); declare env\.cameras\.back$"):
        _BackCamera(task_cfg, "cpu", "cpu", 0, True)
    with pytest.raises(ConfigError, match=r"^image observation term 'far' reads the depth image of camera 'front', but "
                                          r"env\.cameras\.front\.outputs=\['rgb'\] does not render it; add depth to "
                                          r"env\.cameras\.front\.outputs$"):
        _FrontDepth(task_cfg, "cpu", "cpu", 0, True)
    with pytest.raises(ConfigError, match=r"^task\.env\.history\.camera needs image observation terms"):
        isaacgymenvs_mw.make("Cartpole", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True,
                             overrides=["+task.env.history.camera.length=2"])


def test_a_camera_is_declared_once_in_the_yaml():
    """The policy observes what each camera of env.cameras renders (rgb and depth; not segmentation), named by the
    output, with the camera's name in front when there are several; the removed env.imageOutputs is refused."""
    task = make(overrides=("task.env.cameras.front.outputs=[rgb,depth,segmentation]",
                           "task.env.history.camera.length=1"))
    assert [t.name for t in task.observations.images.terms] == ["rgb", "depth"]
    assert task.reset()["camera"].shape == (4, 4, 16, 32)
    two = make(overrides=("task.env.history.camera.length=1", "+task.env.cameras.side={width: 32, height: 16}"))
    assert [(t.name, t.camera) for t in two.observations.images.terms] == [("front_rgb", "front"), ("side_rgb", "side")]
    with pytest.raises(ConfigError, match=r"^task\.env\.imageOutputs=\['rgb'\] is no longer read: the policy observes "
                                          r"the outputs its cameras render: set task\.env\.cameras\.<name>\.outputs$"):
        make(overrides=("+task.env.imageOutputs=[rgb]",))


def test_the_image_model_scales_bytes_to_unit_range():
    torch.manual_seed(0)
    images = torch.randint(0, 256, (5, 3, 16, 16), dtype=torch.uint8)
    obs = TensorDict({"camera": images, "policy": torch.randn(5, 4)}, batch_size=[5])
    groups = {"actor": ["camera", "policy"]}
    cnn = {"output_channels": [4, 8], "kernel_size": [5, 3], "stride": [2, 2]}
    model = ImageCNNModel(obs, groups, "actor", 1, hidden_dims=[8], cnn_cfg=cnn)
    reference = CNNModel(obs, groups, "actor", 1, hidden_dims=[8], cnn_cfg=cnn)
    reference.cnns["camera"].load_state_dict(model.cnns["camera"].cnn.state_dict())
    reference.mlp.load_state_dict(model.mlp.state_dict())
    floats = TensorDict({"camera": images.float() / 255, "policy": obs["policy"]}, batch_size=[5])
    torch.testing.assert_close(model(obs), reference(floats))


def test_vecenv_sends_the_camera_group():
    env = RslRlVecEnv(make())
    obs = env.get_observations()
    assert set(obs.keys()) == {"policy", "critic", "camera"}
    assert obs["camera"].shape == (4, 9, 16, 32) and obs["camera"].dtype == torch.uint8
    assert obs["policy"].shape == (4, 4)


@pytest.mark.parametrize("task", ["CartpoleCamera", "CartpoleCameraDepth"])
def test_cartpole_camera_trains_and_evaluates_from_pixels_on_the_cpu(tmp_path, run_args, task):
    cfg = compose_config([f"task={task}", "num_envs=4", "max_iterations=1", *SMALL, *run_args])
    summary = run(cfg)
    run_dir = tmp_path / "runs" / task
    (checkpoint,) = run_dir.glob("*/model_1.pt")
    assert summary["iterations"] == 1 and summary["env_steps"] == 4 * cfg.train.runner.num_steps_per_env
    evaluation = run(compose_config([f"task={task}", "num_envs=4", "test=True", f"checkpoint={checkpoint}", *SMALL,
                                     *run_args]))
    assert evaluation["episodes"] >= 4
    exported = checkpoint.parent / "exported"
    metadata = read_metadata(exported / "policy.onnx")
    channels = 3 * (3 if task == "CartpoleCamera" else 1)
    assert metadata["camera"]["shape"] == [channels, 16, 32] and metadata["camera"]["dtype"] == "uint8"
    import onnx

    assert [i.name for i in onnx.load(str(exported / "policy.onnx")).graph.input] == ["obs", "camera"]
    assert json.loads((checkpoint.parent / "eval.json").read_text())["task"] == task


def test_videos_show_what_the_policy_sees_beside_the_view(tmp_path):
    """capture_video on a task with image terms: each frame is the usual view, then env 0's latest image, scaled
    up by a whole factor to the frame's height."""
    from omegaconf import OmegaConf
    from test_video import read_video

    from isaacgymenvs_mw.learning.launch import _attach_video_recorder

    task = make(overrides=("task.env.history.camera.length=1",))
    task.reset()
    _attach_video_recorder(OmegaConf.create({"capture_video_freq": 100, "capture_video_len": 3}), task,
                           tmp_path / "videos")
    seen = []
    for _ in range(3):
        task.step(torch.ones(4, 1))
        seen.append(task.observations.camera_picture(task.control_steps, 0).numpy())
    task.close()
    frames, _ = read_video(tmp_path / "videos" / "video_1.mp4")
    scale = 480 // 16
    assert frames.shape == (3, 480, 640 + 32 * scale, 3)
    for frame, image in zip(frames, seen):
        expected = np.repeat(np.repeat(image, scale, axis=0), scale, axis=1).astype(int)
        assert np.abs(frame[:, 640:].astype(int) - expected).mean() < 3  # H.264 is lossy
    assert np.abs(frames[-1, :, 640:].astype(int) - frames[0, :, 640:].astype(int)).mean() > 0.05
