"""deterministic=True gives bit-identical training on one device, and `logger: wandb` logs what TensorBoard logs;
a drawn seed (seed=-1) is told and recorded, so that a run can be repeated.

Three short Cartpole trainings on the CPU: two with seed 7 and deterministic=True (the second logging to W&B through
a stand-in `wandb` module that records every call: the real package is not a test dependency), one with seed 8.
The same-seed histories (losses, learning rate, episode statistics per iteration) must be equal to the last bit, the
other seed's must not be (the comparison can fail). The W&B scalars must be the TensorBoard scalars of the first run,
read back from its events file with TensorBoard's own reader.
"""

from __future__ import annotations

import importlib.machinery
import json
import os
import re
import subprocess
import sys
import types
from pathlib import Path

import mujoco_warp
import pytest
import torch
from omegaconf import OmegaConf

from conftest import CPU_ARGS, REPO_ROOT, tensorboard_scalars
from isaacgymenvs_mw.learning import loggers
from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError

TIMING_KEYS = {"time_s", "steps_per_s", "collect_s", "learn_s"}
ITERATIONS = 3


class FakeWandb(types.ModuleType):
    """Records what the W&B writer sends: init kwargs, logged scalars (tag, step, value), saved files, finish."""

    def __init__(self) -> None:
        super().__init__("wandb")
        self.__spec__ = importlib.machinery.ModuleSpec("wandb", None)
        self.inits: list[dict] = []
        self.logged: list[tuple[str, int, float]] = []
        self.saved: list[str] = []
        self.finished = 0

    def init(self, **kwargs):
        self.inits.append(kwargs)
        return types.SimpleNamespace(**kwargs)

    def log(self, data: dict, step: int | None = None) -> None:
        self.logged += [(tag, step, float(value)) for tag, value in data.items()]

    def save(self, path: str, base_path: str | None = None) -> None:
        self.saved.append(Path(path).name)

    def finish(self) -> None:
        self.finished += 1


def train(runs: Path, seed: int, *extra: str) -> dict:
    cfg = compose_config(["task=Cartpole", "num_envs=16", f"max_iterations={ITERATIONS}", f"seed={seed}",
                          "deterministic=True", *CPU_ARGS, f"runs_dir={runs}", *extra])
    return run(cfg)


def comparable(history: list[dict]) -> list[dict]:
    return [{k: v for k, v in record.items() if k not in TIMING_KEYS} for record in history]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("repro")
    fake = FakeWandb()
    mp = pytest.MonkeyPatch()
    try:
        first = train(root / "a", 7)
        deterministic_algorithms = torch.are_deterministic_algorithms_enabled()
        mp.setitem(sys.modules, "wandb", fake)
        mp.setenv("WANDB_MODE", "")  # unset: the writer decides (and the patch restores the environment)
        mp.setattr(loggers, "_reachable", lambda *a, **k: False)  # no network here
        second = train(root / "b", 7, "train.runner.logger=wandb", "+train.runner.wandb_project=repro")
        offline = loggers.os.environ.get("WANDB_MODE")
        mp.undo()
        other = train(root / "c", 8)
    finally:
        mp.undo()
        torch.use_deterministic_algorithms(False)  # the runs switched it on for this process
    return {"first": first, "second": second, "other": other, "fake": fake, "offline": offline,
            "deterministic_algorithms": deterministic_algorithms}


def test_same_seed_gives_identical_losses_and_rewards(runs):
    a, b = comparable(runs["first"]["history"]), comparable(runs["second"]["history"])
    assert len(a) == ITERATIONS
    assert a == b
    for record in a:  # the histories hold what the check is about
        assert {"value", "surrogate"} <= set(record["losses"]) and record["episodes"] > 0
    assert a[0]["losses"] != a[-1]["losses"]
    assert runs["deterministic_algorithms"]  # deterministic=True implies torch_deterministic


def test_another_seed_gives_another_curve(runs):
    a, c = comparable(runs["first"]["history"]), comparable(runs["other"]["history"])
    assert [r["losses"] for r in a] != [r["losses"] for r in c]


def test_deterministic_reaches_mujoco_warp():
    on = build_task(compose_config(["task=Cartpole", "num_envs=2", "deterministic=True", *CPU_ARGS]))
    off = build_task(compose_config(["task=Cartpole", "num_envs=2", *CPU_ARGS]))
    assert on.sim.model.opt.deterministic == int(mujoco_warp.DeterminismType.ALL)
    assert off.sim.model.opt.deterministic == int(mujoco_warp.DeterminismType.NONE)


def test_wandb_logs_the_tensorboard_metrics_offline(runs):
    fake = runs["fake"]
    (init,) = fake.inits
    run_dir = Path(runs["second"]["run_dir"])
    assert init["project"] == "repro" and init["name"] == run_dir.name and init["dir"] == str(run_dir)
    assert init["config"]["task_name"] == "Cartpole" and init["config"]["deterministic"] is True
    assert runs["offline"] == "offline"  # WANDB_MODE was unset and the network unreachable
    assert fake.finished == 1
    assert f"model_{ITERATIONS}.pt" in fake.saved  # checkpoints are uploaded, as rsl-rl-lib does

    expected = tensorboard_scalars(Path(runs["first"]["run_dir"]))  # the TensorBoard path, same seed
    expected = {tag: v for tag, v in expected.items() if not tag.endswith("/time")}  # seconds axis: TB only
    logged: dict[str, list[tuple[int, float]]] = {}
    for tag, step, value in fake.logged:
        logged.setdefault(tag, []).append((step, value))
    assert set(logged) == set(expected)
    assert {"Loss/value", "Loss/learning_rate", "Train/mean_episode_reward", "Perf/total_fps"} <= set(logged)
    for tag, values in expected.items():
        assert [s for s, _ in logged[tag]] == [s for s, _ in values] == list(range(ITERATIONS)), tag
        if not tag.startswith("Perf/"):  # timings differ between runs; everything else is bit-identical
            assert [v for _, v in logged[tag]] == pytest.approx([v for _, v in values], rel=1e-6), tag


def test_unknown_logger_lists_valid_values(tmp_path, run_args):
    with pytest.raises(ValueError, match=r"train\.runner\.logger='neptune'.*\['tensorboard', 'wandb'\]"):
        run(compose_config(["task=Cartpole", "num_envs=2", "train.runner.logger=neptune", *run_args]))
    assert not (tmp_path / "runs").exists()  # failed before a run directory was made


def test_wandb_without_the_package_names_the_key(tmp_path, run_args, monkeypatch):
    monkeypatch.setitem(sys.modules, "wandb", None)  # import wandb fails, as when it is not installed
    with pytest.raises(ConfigError, match=r"train\.runner\.logger=wandb needs the wandb package"):
        run(compose_config(["task=Cartpole", "num_envs=2", "train.runner.logger=wandb", *run_args]))
    assert not (tmp_path / "runs").exists()


def test_a_drawn_seed_is_printed_and_written_to_config_yaml(tmp_path):
    """seed=-1 draws a seed: the console names it, and the run's config.yaml holds it (not -1), equal to the seed the
    run used (summary.json's, which set_seed returned), so that seed=<it> repeats the run."""
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "task=Cartpole", *CPU_ARGS, "num_envs=4", "max_iterations=1",
           "seed=-1", f"runs_dir={tmp_path}"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    drawn = re.findall(r"^\[train\] seed=-1 drew seed (\d+) \(give seed=(\d+) to repeat this run\)$", proc.stdout,
                       re.MULTILINE)
    assert len(drawn) == 1 and drawn[0][0] == drawn[0][1], proc.stdout
    (config,) = tmp_path.glob("Cartpole/*/config.yaml")
    saved = OmegaConf.load(config).seed
    used = json.loads((config.parent / "summary.json").read_text())["seed"]
    assert saved == used == int(drawn[0][0]) and saved >= 0
