"""``python train.py -m ...``: a sweep's jobs (Hydra's expansion), their table against a plain calculation from each
run's history, the files it writes (and the ones it must not), bad input before any job runs, and a signal."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
import torch

from conftest import CPU_ARGS, REPO_ROOT, signal_at_line
from isaacgymenvs_mw.learning.sweep import (SMOOTHING, evaluation_outputs, expand, last_checkpoint, markdown_table,
                                            metric_key, summarise, visible_gpus)
from isaacgymenvs_mw.utils.errors import ConfigError

ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}


def test_expansion_is_hydras_cartesian_product_in_order():
    jobs, labels = expand(["task=Cartpole", "seed=1,2", "task.env.maxEffort=range(3,5)", "+x=choice(a,b)"])
    assert len(jobs) == 8
    assert jobs[0] == ["task=Cartpole", "seed=1", "task.env.maxEffort=3", "+x=a"]
    assert jobs[1] == ["task=Cartpole", "seed=1", "task.env.maxEffort=3", "+x=b"]
    assert jobs[-1] == ["task=Cartpole", "seed=2", "task.env.maxEffort=4", "+x=b"]
    assert labels[-1] == ["seed=2", "task.env.maxEffort=4", "+x=b"]  # only what varies
    with pytest.raises(ConfigError, match=r"seed=interval\(0,1\): an interval sweep"):
        expand(["seed=interval(0,1)"])


def reference_row(values: list[float]) -> tuple[float, float]:
    """Final and best of trailing means over SMOOTHING values, by numpy (fewer values at the start)."""
    means = [float(np.mean(values[max(0, i + 1 - SMOOTHING):i + 1])) for i in range(len(values))]
    return means[-1], max(means)


@pytest.mark.parametrize("parent, count, jobs", [
    (None, 4, ["0", "1", "2", "3"]),          # no restriction: the indexes
    ("2,3", 2, ["2", "3"]),                   # the host's GPUs 2 and 3, not its 0 and 1
    (" 3, 1 ", 2, ["3", "1"]),                # the parent's order, spaces dropped
    ("GPU-aa,GPU-bb", 2, ["GPU-aa", "GPU-bb"]),  # UUIDs pass through
    ("1,7", 1, ["1"]),                        # CUDA stops at the first GPU that does not exist
])
def test_a_sweep_hands_each_job_one_of_the_gpus_its_parent_was_given(parent, count, jobs):
    assert visible_gpus(parent, count) == jobs


def test_test_mode_names_its_outputs_after_the_checkpoint_unless_it_is_the_runs_last(tmp_path):
    run_dir = tmp_path / "Cartpole" / "stamp"
    run_dir.mkdir(parents=True)
    for name in ("model_9.pt", "model_10.pt", "model_12_interrupted.pt", "model_best.pt"):
        torch.save({"iter": 0}, run_dir / name)  # whole files: only their names matter here
    (run_dir / "model_13.pt").touch()  # empty, as a full disk left one before writes were atomic: never the latest

    def names(checkpoint: str) -> list[str]:
        return [p.name for p in evaluation_outputs(run_dir / checkpoint)]

    assert names("model_12_interrupted.pt") == ["eval.json", "exported", "videos_eval"]
    # by iteration number, not by text: model_9 comes before model_10
    assert names("model_10.pt") == ["eval_model_10.json", "exported_model_10", "videos_eval_model_10"]
    assert names("model_9.pt") == ["eval_model_9.json", "exported_model_9", "videos_eval_model_9"]
    assert names("model_best.pt") == ["eval_best.json", "exported_best", "videos_eval_best"]
    assert last_checkpoint(tmp_path) == run_dir / "model_12_interrupted.pt"  # what a sweep evaluates: eval.json
    (run_dir / "model_12_interrupted.pt").unlink()
    assert names("model_10.pt") == ["eval.json", "exported", "videos_eval"]


def test_final_and_best_are_trailing_means_of_the_iterations_that_reported_the_metric():
    rng = np.random.default_rng(0)
    values = list(rng.uniform(0.0, 1.0, 37))
    history = [{"time_s": float(i), "Episode/success": v} for i, v in enumerate(values)]
    history.insert(5, {"time_s": 4.5})  # an iteration where no episode ended: no value, skipped
    row = summarise({"history": history, "final_iteration": 38}, "Episode/success")
    final, best = reference_row(values)
    assert row["final"] == pytest.approx(final, rel=1e-12) and row["best"] == pytest.approx(best, rel=1e-12)
    assert row["final_over_best"] == pytest.approx(final / best, rel=1e-12)
    assert metric_key(history, "auto", "Episode/success") == "Episode/success"  # the task's declared success
    assert metric_key([{"mean_episode_reward": 1.0}], "auto", None) == "mean_episode_reward"  # none declared
    assert metric_key(history, "success", "Episode/success") == "Episode/success"
    plain = [{"time_s": 1.0, "timeout_fraction": 0.5, "mean_episode_length": 10.0}]
    assert metric_key(plain, "timeout_fraction", "Episode/success") == "timeout_fraction"  # a history key as it is
    assert metric_key(plain, "success", None) == "Episode/success"  # a declared metric's short name, even when absent


def test_the_table_says_where_a_lanes_action_noise_collapsed():
    collapsed = {"iteration": 1417, "action": 1, "actuator": "A_WRJ1", "std": 0.0034, "mean_std": 4.2,
                 "learning_rate": 1e-5}
    unnamed = dict(collapsed, actuator=None)
    rows = [dict(summarise({"history": [], "noise_collapse": c}, "mean_episode_reward"), label=label)
            for label, c in (("a", collapsed), ("b", unnamed), ("c", None))]
    lines = markdown_table(rows, "mean_episode_reward").splitlines()
    assert lines[0].endswith("| noise collapsed |") and lines[1].count("|---") == lines[0].count(" | ") + 1
    assert [line.rsplit("|", 2)[1].strip() for line in lines[2:]] == ["it 1417, A_WRJ1", "it 1417, action 1", "-"]


def test_a_cartpole_sweep_writes_its_jobs_table_and_curves_under_runs_dir_only(tmp_path):
    runs = tmp_path / "runs"
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "-m", "task=Cartpole", "seed=1,2", "num_envs=4",
           "max_iterations=3", "sweep_eval=True", *CPU_ARGS, f"runs_dir={runs}"]
    out = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, env=ENV, timeout=600)
    assert out.returncode == 0, (out.stdout + out.stderr)[-3000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]  # no multirun/ or outputs/ beside it
    (sweep_dir,) = (runs / "sweeps").iterdir()
    assert sweep_dir.name.startswith("Cartpole_")
    table = json.loads((sweep_dir / "sweep.json").read_text())
    assert table["metric"] == "mean_episode_reward"  # Cartpole declares no metric of its own
    assert table["chosen_by"] == "episode reward"
    assert [row["label"] for row in table["jobs"]] == ["seed=1", "seed=2"]
    for k, row in enumerate(table["jobs"]):
        (summary_path,) = (sweep_dir / f"job{k}").glob("Cartpole/*/summary.json")
        summary = json.loads(summary_path.read_text())
        assert summary["seed"] == k + 1 and summary["final_iteration"] == 3
        values = [r["mean_episode_reward"] for r in summary["history"] if r.get("mean_episode_reward") is not None]
        final, best = reference_row(values)
        assert row["final"] == pytest.approx(final) and row["best"] == pytest.approx(best)
        assert row["status"] == 0 and (sweep_dir / f"job{k}.log").read_text().count("[it ") == 3
        # sweep_eval: test mode ran on the final checkpoint, and the table holds its episode reward
        evaluation = json.loads((summary_path.parent / "eval.json").read_text())
        assert evaluation["checkpoint"] == str(summary_path.parent / "model_3.pt")
        assert row["test"] == pytest.approx(evaluation["mean_episode_reward"])
        # then the best checkpoint (save_best, on by default), into its own file beside the last one's
        best = json.loads((summary_path.parent / "eval_best.json").read_text())
        assert best["checkpoint"] == str(summary_path.parent / "model_best.pt")
        assert row["test_best"] == pytest.approx(best["mean_episode_reward"])
        assert (summary_path.parent / "exported_best" / "policy.onnx").is_file()
    assert (sweep_dir / "sweep.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    markdown = (sweep_dir / "sweep.md").read_text()
    assert markdown.count("| seed=") == 2 and markdown in out.stdout


@pytest.mark.parametrize("args, message", [
    (["seed=1,2", "num_envs=4,0"], "num_envs=0 is invalid"),
    (["seed=1,2", "multi_gpu=True"], "multi_gpu=True: a sweep runs its jobs one per GPU"),
    (["seed=interval(1,3)"], "an interval sweep needs a sweeper"),
    (["seed=1,2", "sweep_eval=maybe"], "sweep_eval='maybe' is invalid"),
    (["train.algorithm.gamma=0.99,2"], "train.algorithm.gamma=2 is invalid"),  # the train YAML, in its last job
    (["seed=1,2", "checkpoint=missing.pt"], "checkpoint='missing.pt': no such file"),
    (["test=False,True"], "test=True: a sweep trains"),  # in its last job, and named before the missing checkpoint
])
def test_bad_input_in_any_job_is_one_line_before_any_job_runs(tmp_path, args, message):
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "-m", "task=Cartpole", *args, *CPU_ARGS,
           f"runs_dir={tmp_path / 'runs'}"]
    out = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, env=ENV, timeout=300)
    assert out.returncode == 2, out.stdout + out.stderr
    assert message in out.stderr and "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "runs").exists()  # nothing ran


def test_sigterm_to_the_sweep_stops_the_running_job_with_its_work_and_starts_no_other(tmp_path):
    runs = tmp_path / "runs"
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "-m", "task=Cartpole", "seed=1,2", "num_envs=4",
           "max_iterations=100000", "train.runner.save_interval=100000", *CPU_ARGS, f"runs_dir={runs}"]
    # job 0 is training once "[it " shows (jobs one after another echo their output); the sweep process alone is
    # signalled, as `kill` does
    status, text = signal_at_line(cmd, tmp_path, "[it ", signal.SIGTERM, ENV)
    assert status == 143, text[-3000:]
    (sweep_dir,) = (runs / "sweeps").iterdir()
    (run_dir,) = (sweep_dir / "job0" / "Cartpole").iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["signal"] == "SIGTERM"
    assert (run_dir / f"model_{summary['final_iteration']}_interrupted.pt").is_file()
    assert not (sweep_dir / "job1").exists()  # no new job after the stop
    rows = json.loads((sweep_dir / "sweep.json").read_text())["jobs"]
    assert rows[0]["interrupted"] is True and rows[1]["final"] is None
