"""capture_video: MuJoCo's offscreen renderer (OSMesa on CPU) films env 0 into mp4 clips, in real time."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

import isaacgymenvs_mw
from isaacgymenvs_mw.sim.video import VideoRecorder
from isaacgymenvs_mw.utils.config import compose_config

REPO_ROOT = Path(__file__).resolve().parents[2]
W, H = 192, 144  # small, even (H.264 in yuv420p needs even sizes); the 8 m Cartpole rail is framed whole


def make(task: str, num_envs: int = 2):
    return isaacgymenvs_mw.make(task, num_envs=num_envs, sim_device="cpu", rl_device="cpu", headless=True)


def read_video(path: Path) -> tuple[np.ndarray, float]:
    frames = iio.imread(path, plugin="FFMPEG")  # (n, h, w, 3)
    fps = float(iio.immeta(path, plugin="FFMPEG")["fps"])
    return frames, fps


def drawn(frame: np.ndarray) -> bool:
    """The scene is really drawn: not one flat colour, and the model's (warm) body colour in some pixels."""
    colours = np.unique(frame.reshape(-1, 3), axis=0)
    r, b = frame[..., 0].astype(int), frame[..., 2].astype(int)
    warm = (r > 120) & (r > b + 40)
    return len(colours) > 5 and warm.sum() >= 8


def test_mujoco_gl_choice(monkeypatch):
    from isaacgymenvs_mw.sim import video

    monkeypatch.setattr(video.sys, "platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setenv("MUJOCO_GL", "glfw")
    video.choose_gl_backend()
    assert os.environ["MUJOCO_GL"] == "glfw"  # the user's choice is kept

    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setenv("DISPLAY", ":0")
    video.choose_gl_backend()
    assert "MUJOCO_GL" not in os.environ  # a display: MuJoCo's default (GLFW) is right

    monkeypatch.delenv("DISPLAY")
    monkeypatch.setattr(video.os.path, "exists", lambda p: p == "/dev/nvidia0")
    monkeypatch.setattr("ctypes.util.find_library", lambda name: f"lib{name}.so.1")
    video.choose_gl_backend()
    assert os.environ["MUJOCO_GL"] == "egl"

    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setattr(video.os.path, "exists", lambda p: False)
    video.choose_gl_backend()
    assert os.environ["MUJOCO_GL"] == "osmesa"

    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setattr("ctypes.util.find_library", lambda name: None)
    video.choose_gl_backend()
    assert "MUJOCO_GL" not in os.environ  # no library: left alone (the probe then says what to install)


def test_cartpole_clips_frames_and_rate(tmp_path):
    task = make("Cartpole")
    task.reset()
    rec = VideoRecorder(task.sim, tmp_path / "videos", fps=1.0 / task.control_dt, width=W, height=H,
                        every=10, length=5)
    syncs = []
    real_sync = rec._sync
    rec._sync = lambda: (syncs.append(task.control_steps), real_sync())[1]
    task.display.record(rec)

    actions = torch.ones(task.num_envs, task.num_actions)
    for _ in range(23):
        task.step(actions)
    # device state is read only while a clip records: steps 1-5, 11-15, 21-23
    assert syncs == [1, 2, 3, 4, 5, 11, 12, 13, 14, 15, 21, 22, 23]
    assert sorted(p.name for p in (tmp_path / "videos").glob("*.mp4")) == ["video_1.mp4", "video_11.mp4"]
    task.close()  # flushes the clip in progress
    assert task.display.video_recorder is None
    names = sorted(p.name for p in (tmp_path / "videos").iterdir())  # and no partial file is left
    assert names == ["video_1.mp4", "video_11.mp4", "video_21.mp4"]

    for name, count in (("video_1.mp4", 5), ("video_11.mp4", 5), ("video_21.mp4", 3)):
        frames, fps = read_video(tmp_path / "videos" / name)
        assert frames.shape == (count, H, W, 3), name
        assert fps == pytest.approx(1.0 / task.control_dt, rel=1e-3)  # real time: one frame per control step
        assert all(drawn(f) for f in frames), name
    # the cart is pushed along the rail all clip long: the picture changes
    frames, _ = read_video(tmp_path / "videos" / "video_11.mp4")
    assert np.abs(frames[-1].astype(int) - frames[0].astype(int)).mean() > 0.05


def robot_pixels(rec: VideoRecorder, ground: int | list[int]) -> tuple[int, np.ndarray | None]:
    seg = rec.render(segmentation=True)
    mask = (seg >= 0) & ~np.isin(seg, ground)
    if mask.sum() == 0:
        return 0, None
    ys, xs = np.nonzero(mask)
    return int(mask.sum()), np.array([xs.mean(), ys.mean()])


def place_root(task, x: float) -> None:
    n = task.num_envs
    pos = torch.tensor([[x, 0.0, 0.34]]).repeat(n, 1)
    quat = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1)
    task.sim.write_state(torch.ones(n, dtype=torch.bool), root_pos=pos, root_quat=quat,
                         root_lin_vel=torch.zeros(n, 3), root_ang_vel=torch.zeros(n, 3))


def test_legged_camera_follows_the_root(tmp_path):
    task = make("Go1")
    task.reset()
    ground = task.sim.geom_id("ground")
    tracking = VideoRecorder(task.sim, tmp_path / "a", fps=50, width=160, height=120)
    fixed = VideoRecorder(task.sim, tmp_path / "b", fps=50, width=160, height=120, track_body=None)
    centre = np.array([160 / 2, 120 / 2])

    place_root(task, 0.0)
    rgb = tracking.render()
    assert rgb.shape == (120, 160, 3) and drawn(rgb)
    n0, c0 = robot_pixels(tracking, ground)
    f0, fc0 = robot_pixels(fixed, ground)
    place_root(task, 1.0)
    n1, c1 = robot_pixels(tracking, ground)
    f1, fc1 = robot_pixels(fixed, ground)

    # the tracking camera keeps the robot, the same size, near the middle of the picture
    assert n0 > 200 and n1 > 200
    assert 0.8 < n1 / n0 < 1.25
    assert np.linalg.norm(c0 - centre) < 0.2 * 160 and np.linalg.norm(c1 - centre) < 0.2 * 160
    assert np.linalg.norm(c1 - c0) < 3.0
    # control: a fixed camera sees the same 1 m move as a large shift (or loses the robot)
    assert f0 > 200
    assert fc1 is None or np.linalg.norm(fc1 - fc0) > 20.0

    # and a clip written while the robot moves keeps it centred too
    tracking.every, tracking.length = 1, 2
    tracking.capture(1)
    place_root(task, 2.0)
    tracking.capture(2)
    frames, fps = read_video(tmp_path / "a" / "video_1.mp4")
    assert frames.shape == (2, 120, 160, 3) and fps == pytest.approx(50.0)
    assert np.abs(frames[1].astype(int) - frames[0].astype(int)).mean() < 8.0
    tracking.close()
    fixed.close()
    task.close()


def test_terrain_camera_frames_the_robot_not_the_ground(tmp_path):
    """The terrain is 200 heightfields and four border boxes on the world body; the camera's distance must come from
    the robot alone, as on flat ground, and the border must not take the robot's colour."""
    flat, rough = make("Anymal"), make("AnymalTerrain")
    cams = []
    for task, folder in ((flat, "flat"), (rough, "rough")):
        task.reset()
        rec = VideoRecorder(task.sim, tmp_path / folder, fps=50, width=160, height=120)
        cams.append(rec.camera.distance)
        rec.close()
    assert cams[1] == pytest.approx(cams[0], rel=1e-6)

    # The robot is drawn whole on terrain too: in the default pose, upright, it covers as many pixels as on flat
    # ground (the terrain's size once put the near clip plane at the camera's distance and cut the robot away).
    seen = []
    for task in (flat, rough):
        n, m = task.num_envs, task.sim.mj_model
        task.sim.write_state(torch.ones(n, dtype=torch.bool), dof_pos=task.default_dof_pos.repeat(n, 1),
                             root_pos=task.sim.root_pos.clone(), root_quat=torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
                             root_lin_vel=torch.zeros(n, 3), root_ang_vel=torch.zeros(n, 3))
        ground = [g for g in range(m.ngeom) if (m.geom(g).name or "").startswith("ground")]
        rec = VideoRecorder(task.sim, tmp_path / f"seen{len(seen)}", fps=50, width=160, height=120)
        seen.append(robot_pixels(rec, ground)[0])
        rec.close()
    assert seen[0] > 200 and 0.8 < seen[1] / seen[0] < 1.25, seen

    border = rough.sim.geom_id("ground/border_0")
    rec = VideoRecorder(rough.sim, tmp_path / "colours", fps=50, width=160, height=120)
    assert np.allclose(rec.model.geom_rgba[border], rec.model.geom_rgba[rough.sim.geom_id("ground/cell_0_0")])
    assert drawn(rec.render())
    rec.close()
    flat.close()
    rough.close()


def test_train_and_test_mode_capture_video(tmp_path):
    runs = tmp_path / "runs"
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "task=Cartpole", "capture_video=True",
           "capture_video_freq=16", "capture_video_len=8", "max_iterations=2", "num_envs=4", "headless=True",
           "train.runner.save_interval=1",  # model_1.pt too: an earlier checkpoint for test mode below
           "sim_device=cpu", "rl_device=cpu", f"runs_dir={runs}"]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"})
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    (run_dir,) = [p for p in (runs / "Cartpole").iterdir() if p.is_dir()]
    videos = sorted((run_dir / "videos").glob("*.mp4"))
    cfg = compose_config(["task=Cartpole"])
    control_dt = float(cfg.task.sim.dt) * int(cfg.task.env.controlFrequencyInv)
    # Cartpole collects 16 steps per iteration: 32 env steps, clips start at steps 1 and 17
    assert [p.name for p in videos] == ["video_1.mp4", "video_17.mp4"]
    for path in videos:
        frames, fps = read_video(path)
        assert frames.shape == (8, 480, 640, 3)
        assert fps == pytest.approx(1.0 / control_dt, rel=1e-3)
        assert drawn(frames[0])

    # test mode films the evaluation next to the checkpoint's eval.json
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "task=Cartpole", "test=True",
           f"checkpoint={run_dir / 'model_2.pt'}", "capture_video=True", "capture_video_freq=1000",
           "capture_video_len=4", "num_envs=2", "headless=True", "sim_device=cpu", "rl_device=cpu",
           f"runs_dir={runs}"]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"})
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert (run_dir / "eval.json").is_file()
    assert sorted(p.name for p in (run_dir / "videos_eval").iterdir()) == ["video_1.mp4"]
    frames, _ = read_video(run_dir / "videos_eval" / "video_1.mp4")
    assert frames.shape == (4, 480, 640, 3) and drawn(frames[-1])

    # an earlier checkpoint films into its own folder: the last checkpoint's video stays as it was (issue 59)
    last_video = (run_dir / "videos_eval" / "video_1.mp4").read_bytes()
    cmd[cmd.index(f"checkpoint={run_dir / 'model_2.pt'}")] = f"checkpoint={run_dir / 'model_1.pt'}"
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"})
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert sorted(p.name for p in (run_dir / "videos_eval_model_1").iterdir()) == ["video_1.mp4"]
    assert (run_dir / "videos_eval" / "video_1.mp4").read_bytes() == last_video
    assert sorted(p.name for p in (run_dir / "videos_eval").iterdir()) == ["video_1.mp4"]


GL_ATTEMPTS = """
import isaacgymenvs_mw
from isaacgymenvs_mw.sim.video import VideoRecorder

task = isaacgymenvs_mw.make("Cartpole", num_envs=1, sim_device="cpu", rl_device="cpu", headless=True)
messages = []
for attempt in range(2):
    try:
        VideoRecorder(task.sim, "videos", fps=50.0, width=64, height=48)
    except RuntimeError as err:
        messages.append(str(err))
assert len(messages) == 2, messages
assert messages[0] == messages[1], messages
print("GL-ERROR:", messages[0])
"""


def test_unusable_gl_backend_gives_the_same_clear_error_twice_and_no_abort(tmp_path):
    # GLFW without a display cannot start; MuJoCo aborts the whole process when asked a second time
    # ("Fatal Python error: Aborted"). The recorder must say so twice, in the same words, and the process go on.
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.update(MUJOCO_GL="glfw", PYTHONPATH=str(REPO_ROOT), OMP_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-c", GL_ATTEMPTS], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300, env=env)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert "Fatal Python error" not in out and "Aborted" not in out
    (line,) = [ln for ln in proc.stdout.splitlines() if ln.startswith("GL-ERROR:")]
    assert "MUJOCO_GL='glfw'" in line and "libosmesa6" in line and "MUJOCO_GL=egl" in line
    assert not (tmp_path / "videos").exists()


def test_training_goes_on_without_video_when_no_gl_backend_starts(tmp_path):
    # capture_video=True where no backend can start (GLFW without a display): one [video] line, then the run trains
    # and writes its checkpoint and summary as without video, and exits 0.
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.update(MUJOCO_GL="glfw", OMP_NUM_THREADS="1")
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "task=Cartpole", "num_envs=4", "max_iterations=1",
           "sim_device=cpu", "rl_device=cpu", "headless=True", "capture_video=True", f"runs_dir={tmp_path}"]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert "Traceback" not in out
    (line,) = [ln for ln in out.splitlines() if ln.startswith("[video]")]
    assert "MUJOCO_GL='glfw'" in line and line.endswith("the run goes on without it")
    (run_dir,) = (tmp_path / "Cartpole").iterdir()
    assert (run_dir / "model_1.pt").is_file() and (run_dir / "summary.json").is_file()
    assert not (run_dir / "videos").exists()


def test_mocap_goal_marker_is_filmed_where_the_task_puts_it(tmp_path):
    """AllegroHand's goal marker is a mocap body the task moves: the film shows it at the task's pose (and frames
    the scene with it there), not at the pose its file gives."""
    task = make("AllegroHand", num_envs=1)
    task.reset()
    recorder = VideoRecorder(task.sim, tmp_path, fps=30, width=W, height=H)
    goal = task.sim.body_id("goal/cube")
    task.goal_quat[0] = torch.tensor([0.0, 0.0, 0.0, 1.0])  # half a turn about z
    task.sim.mocap_quat[0, task.goal_marker] = task.goal_quat[0]
    seg = recorder.render(segmentation=True)
    np.testing.assert_allclose(recorder.data.xpos[goal], task.sim.mocap_pos[0, task.goal_marker].numpy(), atol=1e-6)
    np.testing.assert_allclose(recorder.data.xquat[goal], [0.0, 0.0, 0.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(recorder.data.xpos[goal], [-0.2, -0.26, 0.64], atol=1e-6)
    goal_geoms = [g for g in range(recorder.model.ngeom) if recorder.model.geom_bodyid[g] == goal]
    assert np.isin(seg, goal_geoms).sum() > 20  # in the picture
    recorder.close()
    task.close()


def test_a_task_camera_stands_at_its_eye_and_looks_at_its_lookat(tmp_path):
    """env.videoCamera {eye, lookat}: MuJoCo's scene puts the rendering camera at eye, facing lookat (its own
    mjv_updateScene, not this project's arithmetic, is the reference); Trifinger's shipped view sees into the arena,
    where the side view the framing picks sees the wall and not the cube."""
    from isaacgymenvs_mw.sim.video import camera_view

    task = make("Trifinger")
    task.reset()
    for eye, lookat in [([0.3, -0.4, 0.5], [0.0, 0.05, 0.1]), ([-1.0, 2.0, -0.5], [0.2, 0.0, 0.3])]:
        rec = VideoRecorder(task.sim, tmp_path, fps=50, width=64, height=48,
                            view=camera_view({"eye": eye, "lookat": lookat}))
        rec.renderer.update_scene(rec.data, camera=rec.camera)
        left, right = rec.renderer.scene.camera[0], rec.renderer.scene.camera[1]  # the stereo pair around the head
        direction = (np.array(lookat) - np.array(eye)) / np.linalg.norm(np.array(lookat) - np.array(eye))
        np.testing.assert_allclose((np.array(left.pos) + np.array(right.pos)) / 2, eye, atol=1e-5)
        np.testing.assert_allclose(left.forward, direction, atol=1e-5)
        rec.close()

    cube = task.sim.body_id("object/cube")
    pixels = {}
    for name, view in [("shipped", camera_view(task.cfg["env"]["videoCamera"])), ("framed", None)]:
        rec = VideoRecorder(task.sim, tmp_path, fps=50, width=160, height=120, view=view)
        seg = rec.renderer
        seg.enable_segmentation_rendering()
        rec._sync()
        seg.update_scene(rec.data, camera=rec.camera)
        ids = seg.render()[..., 0]  # geom ids
        cube_geoms = np.flatnonzero(rec.model.geom_bodyid == cube)
        pixels[name] = int(np.isin(ids, cube_geoms).sum())
        seg.disable_segmentation_rendering()
        rec.close()
    assert pixels["shipped"] > 100 and pixels["framed"] < pixels["shipped"] / 4, pixels
    task.close()


@pytest.mark.parametrize(("value", "message"), [
    ({"eye": [0, 0]}, r"task.env.videoCamera.eye=\[0, 0\] is invalid: give a point \[x, y, z\] in metres"),
    ({"eye": [0, 0, 1], "lookat": [0, 0, "up"]}, r"task.env.videoCamera.lookat='up' is invalid"),
    ({"eye": [0, 0, 1], "lookat": [0, 0, 1]}, r"eye and lookat are the same point"),
    ({"eye": [0, 0, 1], "target": [0, 0, 0]}, r"task.env.videoCamera: unknown key\(s\) \['target'\]"),
])
def test_bad_task_camera_is_one_line_naming_the_key(value, message):
    from isaacgymenvs_mw.sim.video import camera_view
    from isaacgymenvs_mw.utils.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        camera_view(value)
