"""benchmarks/learning_curve.py: reward against training time from summary.json histories, written as a PNG."""

from __future__ import annotations

import json
import subprocess
import sys

import imageio.v3 as iio

from conftest import REPO_ROOT

SCRIPT = REPO_ROOT / "benchmarks" / "learning_curve.py"


def summary(rewards: list[float | None]) -> dict:
    history = [{"iteration": i + 1, "time_s": 0.5 * (i + 1), "mean_episode_reward": r,
                "mean_episode_length": None if r is None else 10.0 * (i + 1)} for i, r in enumerate(rewards)]
    for record in history:  # iterations in which no episode ended carry no episode statistics
        if record["mean_episode_reward"] is None:
            del record["mean_episode_reward"], record["mean_episode_length"]
    return {"task": "Ant", "num_envs": 64, "device": "cpu", "wall_time_s": 9.0, "train_time_s": 2.0,
            "history": history}


def test_curve_keeps_iterations_that_finished_episodes():
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        from learning_curve import curve
    finally:
        sys.path.remove(str(SCRIPT.parent))
    assert curve(summary([None, 1.0, None, 3.0]), "mean_episode_reward") == ([1.0, 2.0], [1.0, 3.0])


def test_script_writes_a_png(tmp_path):
    paths = []
    for name, rewards in (("a", [None, 1.0, 2.0, 4.0]), ("b", [0.5, 0.7, 3.0, 3.5])):
        path = tmp_path / name / "summary.json"
        path.parent.mkdir()
        path.write_text(json.dumps(summary(rewards)))
        paths.append(str(path))
    out = tmp_path / "curve.png"
    proc = subprocess.run([sys.executable, str(SCRIPT), *paths, "--out", str(out), "--length"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    image = iio.imread(out)
    assert image.ndim == 3 and image.shape[0] > 300 and image.shape[1] > 600
    assert image.std() > 5.0  # lines and text, not a blank canvas


def test_script_refuses_a_run_without_finished_episodes(tmp_path):
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(summary([None, None])))
    proc = subprocess.run([sys.executable, str(SCRIPT), str(path), "--out", str(tmp_path / "x.png")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0 and "no iteration with a finished episode" in proc.stderr


def test_script_adds_a_panel_per_key_and_names_a_missing_one(tmp_path):
    path = tmp_path / "summary.json"
    data = summary([0.5, 1.0, 2.0])
    for i, record in enumerate(data["history"]):
        record["Episode/terrain_level"] = 2.5 - 0.5 * i
    path.write_text(json.dumps(data))
    one, two = tmp_path / "one.png", tmp_path / "two.png"
    for out, extra in ((one, []), (two, ["--key", "Episode/terrain_level"])):
        proc = subprocess.run([sys.executable, str(SCRIPT), str(path), "--out", str(out), *extra],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr[-2000:]
    # a second panel doubles the figure's height (3.2 inches per panel)
    assert iio.imread(two).shape[0] == 2 * iio.imread(one).shape[0]
    proc = subprocess.run([sys.executable, str(SCRIPT), str(path), "--out", str(tmp_path / "x.png"),
                           "--key", "Episode/terain_level"], capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0
    assert "Episode/terain_level" in proc.stderr and "Episode/terrain_level" in proc.stderr
