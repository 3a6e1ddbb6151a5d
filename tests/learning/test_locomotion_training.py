"""Ant trains on a 2-core CPU (the CI smoke test the issue asks for: num_envs=64, a few iterations), and test mode
evaluates it, reports the forward speed and films env 0 with the camera following the torso."""

from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np

from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.utils.config import compose_config


def test_ant_trains_with_64_envs_then_test_mode_reports_speed_and_films(tmp_path, run_args):
    iterations = 3
    cfg = compose_config(["task=Ant", "num_envs=64", f"max_iterations={iterations}", *run_args])
    summary = run(cfg)
    assert summary["iterations"] == iterations
    assert summary["env_steps"] == iterations * cfg.train.runner.num_steps_per_env * 64
    assert len(summary["history"]) == iterations
    run_dir = [p for p in (tmp_path / "runs" / "Ant").iterdir() if p.is_dir()][0]
    ckpt = run_dir / f"model_{iterations}.pt"
    assert ckpt.is_file()

    episode = 30  # a short episode keeps the CPU evaluation quick
    eval_cfg = compose_config(["task=Ant", "num_envs=8", "test=True", f"checkpoint={ckpt}",
                               f"task.env.episodeLength_s={episode * 2 * 0.00833}", "capture_video=True", "capture_video_len=6",
                               *run_args])
    result = run(eval_cfg)
    written = json.loads((run_dir / "eval.json").read_text())
    assert written["episodes"] == 8
    assert np.isfinite(written["forward_speed"]) and abs(written["forward_speed"]) < 20.0
    assert 0.0 <= written["timeout_fraction"] <= 1.0
    assert result["forward_speed"] == written["forward_speed"]
    videos = sorted((run_dir / "videos_eval").glob("*.mp4"))
    assert videos, "test mode with capture_video=True wrote no clip"
    frames = iio.imread(videos[0], plugin="FFMPEG")
    assert frames.shape[0] == 6 and frames.std() > 1.0  # six frames, and not a flat image
