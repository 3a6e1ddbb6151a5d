"""Training and evaluation end to end: train.py on the command line, run artefacts, test mode, learning."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
import torch.multiprocessing as mp
from omegaconf import OmegaConf

from conftest import REPO_ROOT
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.utils.config import check_run_config, compose_config
from isaacgymenvs_mw.utils.errors import ConfigError

SUMMARY_KEYS = {"task", "num_envs", "iterations", "env_steps", "wall_time_s", "env_steps_per_s",
                "mean_episode_reward", "mean_episode_length", "device", "versions"}


def only_run_dir(runs: Path, experiment: str = "Cartpole") -> Path:
    dirs = [p for p in (runs / experiment).iterdir() if p.is_dir()]
    assert len(dirs) == 1, dirs
    return dirs[0]


def test_train_py_cli_with_overrides(tmp_path):
    runs = tmp_path / "runs"
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "task=Cartpole", "num_envs=8", "max_iterations=2",
           "headless=True", f"runs_dir={runs}", "sim_device=cpu", "rl_device=cpu"]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"})
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    run_dir = only_run_dir(runs)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["task"] == "Cartpole"
    assert summary["num_envs"] == 8
    assert summary["iterations"] == 2
    steps_per_env = compose_config(["task=Cartpole"]).train.runner.num_steps_per_env
    assert summary["env_steps"] == 2 * steps_per_env * 8
    assert (run_dir / "model_2.pt").is_file()
    saved = OmegaConf.load(run_dir / "config.yaml")
    assert saved.num_envs == 8 and saved.task.env.numEnvs == 8 and saved.train.runner.max_iterations == 2
    # the run wrote only under runs_dir (Hydra's output_subdir is off; cwd was tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]


def test_short_training_writes_artefacts_and_test_mode_evaluates(tmp_path, run_args):
    n, iters = 16, 2
    cfg = compose_config(["task=Cartpole", f"num_envs={n}", f"max_iterations={iters}", *run_args])
    steps_per_env = cfg.train.runner.num_steps_per_env
    summary = run(cfg)

    run_dir = only_run_dir(tmp_path / "runs")
    assert Path(summary["run_dir"]) == run_dir
    on_disk = json.loads((run_dir / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(on_disk)
    assert on_disk["task"] == "Cartpole" and on_disk["num_envs"] == n and on_disk["iterations"] == iters
    assert on_disk["env_steps"] == iters * steps_per_env * n
    assert on_disk["wall_time_s"] > 0 and on_disk["env_steps_per_s"] > 0
    for key in ("mean_episode_reward", "mean_episode_length"):
        assert isinstance(on_disk[key], float) and math.isfinite(on_disk[key])
    assert 1 <= on_disk["mean_episode_length"] <= round(cfg.task.env.episodeLength_s / 0.0166) - 1
    assert on_disk["device"].startswith("cpu")
    assert {"torch", "warp-lang", "mujoco", "mujoco-warp", "rsl-rl-lib"} <= set(on_disk["versions"])
    assert len(on_disk["history"]) == iters

    saved = OmegaConf.load(run_dir / "config.yaml")
    assert saved.task.env.numEnvs == n and saved.train.runner.max_iterations == iters

    ckpt = run_dir / f"model_{iters}.pt"
    assert ckpt.is_file()
    state = torch.load(ckpt, map_location="cpu", weights_only=False)
    assert state["iter"] == iters
    first = [v for k, v in state["actor_state_dict"].items() if k.endswith(".weight")][0]
    assert first.shape == (cfg.train.actor.hidden_dims[0], 4)  # Cartpole's four terms

    eval_cfg = compose_config(["task=Cartpole", f"num_envs={n}", "test=True", f"checkpoint={ckpt}", *run_args])
    result = run(eval_cfg)
    eval_path = run_dir / "eval.json"
    assert eval_path.is_file()
    written = json.loads(eval_path.read_text())
    assert {"mean_episode_reward", "mean_episode_length", "episodes"} <= set(written)
    assert written["episodes"] == n
    assert 1 <= written["mean_episode_length"] <= round(cfg.task.env.episodeLength_s / 0.0166) - 1
    assert math.isfinite(written["mean_episode_reward"])
    assert written["checkpoint"] == str(ckpt.resolve())
    assert result["mean_episode_length"] == written["mean_episode_length"]
    # test mode writes no new run directory
    assert only_run_dir(tmp_path / "runs") == run_dir


def test_a_training_time_budget_ends_the_run_after_the_iteration_that_reaches_it(tmp_path, run_args):
    budget = 0.4  # seconds of training: several Cartpole iterations of 8 envs on the CPU
    cfg = compose_config(["task=Cartpole", "num_envs=8", "max_iterations=10000", f"max_train_time_s={budget}",
                          *run_args])
    summary = run(cfg)
    times = [entry["time_s"] for entry in summary["history"]]
    assert summary["time_budget_reached"] and not summary["interrupted"]
    assert times[-1] >= budget and (len(times) == 1 or times[-2] < budget)  # the first iteration at the budget
    assert summary["iterations"] == len(times) < 10000
    assert (only_run_dir(tmp_path / "runs") / f"model_{len(times)}.pt").is_file()  # the final checkpoint


def test_a_budget_not_reached_leaves_the_run_to_its_iterations(tmp_path, run_args):
    summary = run(compose_config(["task=Cartpole", "num_envs=8", "max_iterations=2", "max_train_time_s=1e6",
                                  *run_args]))
    assert summary["iterations"] == 2 and not summary["time_budget_reached"]


@pytest.mark.parametrize("value", [0, -5, "ten", float("nan"), True])
def test_a_bad_training_time_budget_is_one_line_naming_the_key(value):
    cfg = compose_config(["task=Cartpole"])
    cfg.max_train_time_s = value
    with pytest.raises(ConfigError, match=r"^max_train_time_s=.* is invalid: give a number > 0.0$"):
        check_run_config(cfg)


def test_cpu_training_learns_to_balance(tmp_path, run_args):
    cfg = compose_config(["task=Cartpole", "num_envs=512", "max_iterations=40", "seed=42", *run_args])
    summary = run(cfg)
    untrained = summary["history"][0]["mean_episode_length"]  # episodes of the initial policy
    trained = summary["mean_episode_length"]
    assert trained >= 3 * untrained, (untrained, trained)
    assert trained >= 200, (untrained, trained)
    assert summary["mean_episode_reward"] > summary["history"][0]["mean_episode_reward"] + 100


def _budget_rank(rank: int, world: int, init_file: str, train_times: list[float], budget: float, results) -> None:
    import torch.distributed as dist

    from isaacgymenvs_mw.learning.runner import Runner

    dist.init_process_group("gloo", init_method=f"file://{init_file}", rank=rank, world_size=world)
    try:
        rank_view = SimpleNamespace(train_time=train_times[rank], is_distributed=True, device="cpu")
        results[rank] = Runner._budget_spent(rank_view, budget)
    finally:
        dist.destroy_process_group()


@pytest.mark.parametrize(("train_times", "spent"), [([5.0, 3.0], True), ([3.0, 5.0], True), ([3.0, 3.5], False)])
def test_with_several_gpus_every_rank_stops_when_any_rank_spent_the_budget(tmp_path, train_times, spent):
    """The ranks' clocks differ slightly; if one stopped alone the others would wait for it in their next
    all-reduce forever. gloo on the CPU stands in for NCCL."""
    with mp.Manager() as manager:
        results = manager.dict()
        mp.spawn(_budget_rank, args=(2, str(tmp_path / "rendezvous"), train_times, 4.0, results), nprocs=2)
        assert dict(results) == {0: spent, 1: spent}


def test_save_best_keeps_the_saved_checkpoint_where_the_metric_was_highest(tmp_path, run_args):
    summary = run(compose_config(["task=Cartpole", "num_envs=8", "max_iterations=12", "train.runner.save_interval=2",
                                  "train.runner.num_steps_per_env=16", "task.env.episodeLength_s=0.3",
                                  *run_args]))  # save_best is on by default
    run_dir = only_run_dir(tmp_path / "runs")
    # Reference, computed here from the history: at each saved iteration, the mean episode reward over the last 10
    # iterations that ended episodes; the best is the first highest of these.
    history = summary["history"]
    saved = [entry["iteration"] for entry in history if entry["iteration"] % 2 == 0]
    means = {}
    for iteration in saved:
        values = [e["mean_episode_reward"] for e in history[:iteration] if e.get("mean_episode_reward") is not None]
        if values:
            means[iteration] = sum(values[-10:]) / len(values[-10:])
    best = max(means, key=lambda it: (means[it], -it))
    kept = summary["best_checkpoint"]
    assert kept["iteration"] == best and kept["metric"] == "mean_episode_reward"
    assert kept["chosen_by"] == "episode reward"  # Cartpole declares no success metric
    assert kept["value"] == pytest.approx(means[best])
    assert (run_dir / "model_best.pt").read_bytes() == (run_dir / f"model_{best}.pt").read_bytes()


def test_without_save_best_no_best_checkpoint_is_kept(tmp_path, run_args):
    summary = run(compose_config(["task=Cartpole", "num_envs=8", "max_iterations=2", "save_best=False", *run_args]))
    assert summary["best_checkpoint"] is None
    assert not (only_run_dir(tmp_path / "runs") / "model_best.pt").exists()


@pytest.mark.parametrize("metric, success, key", [("auto", "Episode/success", "Episode/success"),
                                                  ("timeout_fraction", None, "timeout_fraction")])
def test_the_best_checkpoint_follows_the_smoothed_metric_not_the_last(tmp_path, metric, success, key):
    from isaacgymenvs_mw.learning.best_checkpoint import BestCheckpoint

    best = BestCheckpoint(tmp_path, metric, success)
    # 30 iterations: the metric rises to 0.9 at iteration 15, then falls; a checkpoint every 10 iterations
    values = [min(i, 15) * 0.06 - max(0, i - 15) * 0.05 for i in range(1, 31)]
    history = []
    for i, value in enumerate(values, start=1):
        history.append({"iteration": i, key: value, "mean_episode_reward": -value})
        if i % 10 == 0:
            checkpoint = tmp_path / f"model_{i}.pt"
            checkpoint.write_bytes(f"weights of iteration {i}".encode())
            best.consider(history, str(checkpoint))
    # the trailing means of 10 iterations at 10, 20 and 30, written out: the one at 20 is the highest
    means = {10: sum(values[0:10]) / 10, 20: sum(values[10:20]) / 10, 30: sum(values[20:30]) / 10}
    assert max(means, key=means.get) == 20 and values[-1] < values[19]
    assert best.summary()["iteration"] == 20 and best.summary()["metric"] == key
    assert best.summary()["value"] == pytest.approx(means[20])
    assert (tmp_path / "model_best.pt").read_bytes() == b"weights of iteration 20"


@pytest.mark.parametrize("values, line", [([0.5] * 30, True), ([0.9 - 0.01 * i for i in range(30)], True),
                                          ([0.01 * i for i in range(30)], False)])
def test_a_best_checkpoint_that_is_the_first_one_says_so(tmp_path, values, line):
    from isaacgymenvs_mw.learning.best_checkpoint import BestCheckpoint

    best = BestCheckpoint(tmp_path, "auto", "Episode/success")
    history = []
    for i, value in enumerate(values, start=1):
        history.append({"iteration": i, "Episode/success": value})
        if i % 10 == 0:
            (tmp_path / f"model_{i}.pt").write_bytes(b"w")
            best.consider(history, str(tmp_path / f"model_{i}.pt"))
    if line:  # flat or falling: model_best.pt is model_10.pt, and the console line says so and what to do
        assert best.summary()["iteration"] == 10
        assert best.never_moved() == (
            f"[train] model_best.pt is a copy of the first checkpoint, model_10.pt: Episode/success never rose above "
            f"its value there ({best.value:.4g}) in 2 later checkpoints; evaluate model_30.pt, or follow "
            "another metric (sweep_metric)")
    else:
        assert best.summary()["iteration"] == 30 and best.never_moved() is None


def test_the_end_of_training_says_when_the_best_checkpoint_is_the_first(tmp_path, run_args, capsys):
    # Episodes of 100 s never time out in 4 iterations of 16 steps: timeout_fraction stays 0 at every checkpoint.
    run(compose_config(["task=Cartpole", "num_envs=8", "max_iterations=4", "train.runner.save_interval=2",
                        "train.runner.num_steps_per_env=16", "task.env.episodeLength_s=100", "task.env.resetDist=0.01",
                        "sweep_metric=timeout_fraction", *run_args]))
    out = capsys.readouterr().out
    assert ("[train] model_best.pt is a copy of the first checkpoint, model_2.pt: timeout_fraction never rose above "
            "its value there (0) in 1 later checkpoint; evaluate model_4.pt") in out


@pytest.mark.parametrize("std_type", ["scalar", "log"])
def test_the_history_records_the_action_noise_the_checkpoint_holds(tmp_path, run_args, std_type):
    summary = run(compose_config(["task=Cartpole", "num_envs=8", "max_iterations=2",
                                  f"train.actor.distribution_cfg.std_type={std_type}", *run_args]))
    checkpoint = torch.load(only_run_dir(tmp_path / "runs") / "model_2.pt", weights_only=False, map_location="cpu")
    # Reference: the saved actor's std parameter (or its log), within rsl-rl-lib's default range [1e-6, 1e6]
    saved = checkpoint["actor_state_dict"]
    std = (saved["distribution.std_param"] if std_type == "scalar" else saved["distribution.log_std_param"].exp())
    std = std.clamp(1e-6, 1e6)
    last = summary["history"][-1]
    assert last["action_std_min"] == pytest.approx(float(std.min()))
    assert last["action_std_mean"] == pytest.approx(float(std.mean()))
    assert summary["noise_collapse"] is None  # std near its initial 1.0: nothing has collapsed


@pytest.mark.parametrize("std_type, lever", [("scalar", "train.actor.distribution_cfg.std_type=log"),
                                             ("log", "++train.actor.distribution_cfg.std_range=[0.1,10.0]")])
def test_a_collapsed_action_noise_is_reported_once_by_its_actuator_name(tmp_path, run_args, capsys, std_type, lever):
    import mujoco

    # Every action's std starts at 0.005 and the adaptive rate is held at its floor (1e-5): the collapse from the start.
    summary = run(compose_config(["task=Ant", "num_envs=4", "max_iterations=2", "train.runner.save_interval=1",
                                  "train.actor.distribution_cfg.init_std=0.005", "train.algorithm.learning_rate=1e-5",
                                  f"train.actor.distribution_cfg.std_type={std_type}",
                                  "+train.algorithm.learning_rate_max=1e-5", *run_args]))
    out = capsys.readouterr().out
    collapse = summary["noise_collapse"]
    assert collapse is not None and collapse["iteration"] == 1 and collapse["learning_rate"] == pytest.approx(1e-5)
    # Reference: the checkpoint saved after iteration 1 and the actuator names MuJoCo C reads from Ant's model
    saved = torch.load(only_run_dir(tmp_path / "runs", "Ant") / "model_1.pt", weights_only=False, map_location="cpu")
    actor = saved["actor_state_dict"]
    std = actor["distribution.std_param"] if std_type == "scalar" else actor["distribution.log_std_param"].exp()
    model = mujoco.MjModel.from_xml_path(str(REPO_ROOT / "assets/mjcf/ant.xml"))
    index = int(std.argmin())
    assert collapse["action"] == index and collapse["std"] == pytest.approx(float(std.min()))
    assert collapse["actuator"] == mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, index)
    assert summary["history"][0]["action_std_min_index"] == index
    assert out.count("the action noise has collapsed") == 1  # once per run, not every iteration
    assert f"action {index} ({collapse['actuator']}) has a std of" in out
    assert f"levers (e.g. {lever})" in out  # the noise as a log first; for a policy that has it, a floor
