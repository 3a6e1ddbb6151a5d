"""Shared fixtures for the isaacgymenvs_mw test suite (CPU only, tiny numEnvs).

Warp compiles (or loads from ~/.cache/warp) its kernels once per process; the first task built in a session
costs a few seconds, later ones about 0.1 s, so tests build fresh tasks freely and stay independent.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import warp

# Asked for by the project. Warp 1.19 has no `quiet` setting any more (the attribute is simply ignored);
# `log_level` is what silences the per-module load messages.
warp.config.quiet = True
if hasattr(warp, "LOG_WARNING"):
    warp.config.log_level = warp.LOG_WARNING

TESTS_DIR = Path(__file__).resolve().parent
REPO_ROOT = TESTS_DIR.parent
if str(TESTS_DIR) not in sys.path:  # helper modules (cartpole_reference, _user_task_module) live next to the tests
    sys.path.insert(0, str(TESTS_DIR))

# Small models on few cores: torch's multi-threaded kernels buy nothing here and, on a shared, loaded machine,
# make a 512-env training iteration ~10x slower (measured 46 s vs 4 s for 10 iterations with 2 cores busy
# elsewhere). One intra-op thread keeps the suite's run time stable; train.py subprocesses get OMP_NUM_THREADS=1.
torch.set_num_threads(1)

CPU_ARGS = ["sim_device=cpu", "rl_device=cpu", "headless=True"]


def signal_at_line(cmd: list[str], cwd, starts_with: str, signum: int, env: dict | None = None,
                   timeout: float = 120) -> tuple[int, str]:
    """Run ``cmd``, send it ``signum`` once a line of its output starts with ``starts_with``, and return its exit
    status and whole output (stdout and stderr together)."""
    import os
    import subprocess

    env = env or {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line)
            if line.startswith(starts_with):
                proc.send_signal(signum)
                break
        out, _ = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc.returncode, "".join(lines) + out


@pytest.fixture(autouse=True)
def _seed_everything():
    torch.manual_seed(0)
    np.random.seed(0)


@pytest.fixture(scope="session")
def make_cartpole():
    """Factory: a fresh Cartpole task on the CPU, built the way ``isaacgymenvs_mw.make`` documents."""
    import isaacgymenvs_mw

    def make(num_envs: int = 8, overrides=()):
        return isaacgymenvs_mw.make(
            "Cartpole", num_envs=num_envs, sim_device="cpu", rl_device="cpu", headless=True,
            overrides=list(overrides),
        )

    return make


@pytest.fixture
def run_args(tmp_path):
    """Run-level overrides for launch.run / train.py that keep everything on the CPU and inside tmp_path."""
    return [*CPU_ARGS, f"runs_dir={tmp_path / 'runs'}"]


def train_one_iteration_then_test(task: str, runs_dir: Path, run_args: list[str], overrides: list[str]) -> None:
    """One training iteration of ``task`` on 2 envs (8 steps each), then test mode from its checkpoint, which must
    finish one episode per env."""
    from isaacgymenvs_mw.learning.launch import run
    from isaacgymenvs_mw.utils.config import compose_config

    cfg = compose_config([f"task={task}", "num_envs=2", "max_iterations=1", "train.runner.num_steps_per_env=8",
                          *overrides, *run_args])
    assert run(cfg)["iterations"] == 1
    (checkpoint,) = (runs_dir / task).glob("*/model_1.pt")
    result = run(compose_config([f"task={task}", "num_envs=2", "test=True", f"checkpoint={checkpoint}", *overrides,
                                 *run_args]))
    assert result["episodes"] == 2


def train_py_two_iterations_then_test(task: str, tmp_path: Path, num_envs: int, test_overrides: tuple[str, ...] = (),
                                      timeout: int = 400) -> tuple[dict, dict]:
    """``python train.py`` for 2 iterations of ``task`` on ``num_envs`` CPU worlds, then test mode from its last
    checkpoint (``test_overrides`` added): the run's summary.json and the evaluation's eval.json."""
    import json
    import subprocess

    runs = tmp_path / "runs"
    base = [sys.executable, str(REPO_ROOT / "train.py"), f"task={task}", f"num_envs={num_envs}", *CPU_ARGS,
            f"runs_dir={runs}"]
    environ = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([*base, "max_iterations=2"], cwd=tmp_path, capture_output=True, text=True, timeout=timeout,
                          check=False, env=environ)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    (run_dir,) = [p for p in (runs / task).iterdir() if p.is_dir()]
    summary = json.loads((run_dir / "summary.json").read_text())
    checkpoint = run_dir / "model_2.pt"
    assert checkpoint.is_file()
    proc = subprocess.run([*base, "test=True", f"checkpoint={checkpoint}", *test_overrides], cwd=tmp_path,
                          capture_output=True, text=True, timeout=timeout, check=False, env=environ)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    (evaluation,) = runs.rglob("eval.json")
    return summary, json.loads(evaluation.read_text())


def tensorboard_scalars(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """Every scalar a run wrote to TensorBoard: {tag: [(step, value), ...]}."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run_dir), size_guidance={"scalars": 0})
    events.Reload()
    return {tag: [(e.step, e.value) for e in events.Scalars(tag)] for tag in events.Tags()["scalars"]}
