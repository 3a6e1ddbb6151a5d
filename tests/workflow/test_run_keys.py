"""Run-level and train keys are checked before anything is built, with messages naming key, value and what is valid;
and a run stopped by Ctrl-C or SIGTERM keeps its checkpoint and summary and exits with the signal's status."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from conftest import CPU_ARGS, REPO_ROOT, signal_at_line
from isaacgymenvs_mw import make
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.learning.runner import Runner
from isaacgymenvs_mw.utils.stop import StopRequested
from isaacgymenvs_mw.utils.stop import StopProtocol
from isaacgymenvs_mw.learning.checkpoints import check_runs_dir
from isaacgymenvs_mw.utils.config import compose_config


@pytest.fixture
def no_simulator(monkeypatch):
    """Fail the test if a Simulator (kernels, device memory) is built."""
    from isaacgymenvs_mw.sim import simulator

    def forbidden(self, *args, **kwargs):
        raise AssertionError("Simulator was constructed before the bad key was reported")

    monkeypatch.setattr(simulator.Simulator, "__init__", forbidden)


@pytest.mark.parametrize("override,named,valid", [
    ("seed=abc", "seed='abc'", "whole number >= -1"),
    ("seed=1.5", "seed=1.5", "whole number >= -1"),
    ("headless=yes", "headless='yes'", "True or False"),
    ("test=1", "test=1", "True or False"),
    ("capture_video=maybe", "capture_video='maybe'", "True or False"),
    ("torch_deterministic=0", "torch_deterministic=0", "True or False"),
    ("verbose=2", "verbose=2", "True or False"),
    ("deterministic=on", "deterministic='on'", "True or False"),
    ("capture_video_freq=0", "capture_video_freq=0", "whole number >= 1"),
    ("capture_video_len=abc", "capture_video_len='abc'", "whole number >= 1"),
    ("graphics_device_id=x", "graphics_device_id='x'", "whole number >= -1"),
    ("runs_dir=''", "runs_dir=''", "non-empty string"),
    ("train.algorithm.learning_rate=abc", "train.algorithm.learning_rate='abc'", "number > 0"),
    ("train.algorithm.learning_rate=-1e-3", "train.algorithm.learning_rate=-0.001", "number > 0"),
    ("train.algorithm.gamma=1.5", "train.algorithm.gamma=1.5", "number >= 0.0 and <= 1.0"),
    ("train.algorithm.num_mini_batches=0", "train.algorithm.num_mini_batches=0", "whole number >= 1"),
    ("train.algorithm.schedule=sometimes", "train.algorithm.schedule='sometimes'", "['adaptive', 'fixed']"),
    ("train.algorithm.use_clipped_value_loss=sure", "train.algorithm.use_clipped_value_loss='sure'",
     "True or False"),
    ("train.runner.num_steps_per_env=0", "train.runner.num_steps_per_env=0", "whole number >= 1"),
    ("train.runner.init_at_random_ep_len=1", "train.runner.init_at_random_ep_len=1", "True or False"),
    ("train.actor.hidden_dims=[32,0]", "train.actor.hidden_dims=0", "whole number >= 1"),
    ("train.actor.distribution_cfg.init_std=0", "train.actor.distribution_cfg.init_std=0", "number > 0"),
])
def test_bad_key_is_named_with_what_is_valid_before_anything_is_built(tmp_path, no_simulator, override, named,
                                                                      valid):
    runs = tmp_path / "runs"
    with pytest.raises(ValueError) as err:
        run(compose_config(["task=Cartpole", "num_envs=2", *CPU_ARGS, f"runs_dir={runs}", override]))
    msg = str(err.value)
    assert named in msg and valid in msg, msg
    assert not runs.exists()


@pytest.mark.parametrize("runs_dir", ["/proc/nope", "/proc/nope/deeper"])
def test_runs_dir_that_cannot_be_created_is_named(no_simulator, runs_dir):
    with pytest.raises(ValueError) as err:
        run(compose_config(["task=Cartpole", "num_envs=2", *CPU_ARGS, f"runs_dir={runs_dir}"]))
    msg = str(err.value)
    assert f"runs_dir='{runs_dir}'" in msg and "cannot be written" in msg and "create and write" in msg


def test_runs_dir_under_a_file_is_named_and_a_good_one_is_left_untouched(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    with pytest.raises(ValueError, match="runs_dir="):
        check_runs_dir(str(blocker / "runs"))
    # a folder that can be made passes, and the check leaves nothing behind: the run makes it when it writes
    check_runs_dir(str(tmp_path / "new" / "deeper" / "runs"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_runs_dir_a_run_beside_creates_during_the_check_passes_and_stays(tmp_path, monkeypatch):
    # another run made the folder after this check looked: the check passes and leaves that run's folder alone
    beside = tmp_path / "shared_runs"
    beside.mkdir()
    real_exists = Path.exists
    monkeypatch.setattr(Path, "exists", lambda self: False if self == beside else real_exists(self))
    check_runs_dir(str(beside / "mine"))
    assert beside.is_dir() and list(beside.iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shared_runs"]


def test_runs_dir_checked_by_runs_side_by_side_passes_in_each(tmp_path):
    # eight runs started at once on one new folder tree (a round of seeds, one per GPU) all pass their check
    import multiprocessing
    for round_ in range(5):
        target = str(tmp_path / f"r{round_}" / "runs" / "seed")
        with multiprocessing.get_context("fork").Pool(8) as pool:
            errors = pool.map(_check_or_error, [target] * 8)
        assert errors == [None] * 8


def _check_or_error(runs_dir: str) -> str | None:
    try:
        check_runs_dir(runs_dir)
    except ValueError as err:
        return str(err)
    return None


@pytest.mark.parametrize("signum, sigint_at_start, repeats", [(signal.SIGTERM, signal.SIG_DFL, 1),
                                                              (signal.SIGINT, signal.SIG_DFL, 1),
                                                              (signal.SIGINT, signal.SIG_IGN, 1),
                                                              (signal.SIGTERM, signal.SIG_DFL, 2),
                                                              (signal.SIGINT, signal.SIG_DFL, 2)],
                         ids=["SIGTERM", "SIGINT", "SIGINT-ignored-at-start", "SIGTERM-twice", "SIGINT-twice"])
def test_signal_saves_checkpoint_marks_summary_and_exits_nonzero(tmp_path, signum, sigint_at_start, repeats):
    runs = tmp_path / "runs"
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "task=Cartpole", "num_envs=4", "max_iterations=100000",
           "train.runner.save_interval=100000", *CPU_ARGS, f"runs_dir={runs}"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
    # SIG_DFL: as from a terminal. SIG_IGN: as a background job of a non-interactive shell starts it (a script's
    # `python train.py ... &`); the run must still stop cleanly on `kill -INT`.
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, sigint_at_start))
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line)
            if line.startswith("[it "):
                for _ in range(repeats):  # `timeout` signals the process, then its whole process group
                    proc.send_signal(signum)
                break
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    lines.append(out)
    text = "".join(lines)
    assert proc.returncode == 128 + signum, text[-3000:]  # 143 for SIGTERM, 130 for SIGINT
    assert "Fatal Python error" not in text

    (run_dir,) = (runs / "Cartpole").iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["signal"] == signal.Signals(signum).name
    last = summary["final_iteration"]
    assert last >= 1 and len(summary["history"]) == last
    checkpoints = sorted(p.name for p in run_dir.glob("model_[0-9]*.pt"))  # model_best.pt (save_best) aside
    assert checkpoints == [f"model_{last}_interrupted.pt"]  # what it learned, and no 'finished' checkpoint
    assert f"stopped by {signal.Signals(signum).name}" in text
    assert text.count("stopped by") == 1, text[-3000:]  # once, from the run; train.py only sets the status


def _deliver(signum):
    os.kill(os.getpid(), signum)
    for _ in range(1000):  # Python runs signal handlers between bytecodes
        pass


def test_a_signal_only_asks_the_runner_to_stop_and_a_later_sigint_insists():
    # The handler must not raise where the signal lands (inside a compiled step, a CUDA graph, TensorBoard's queue):
    # it records the signal, and Runner.learn raises StopRequested between env steps.
    runner = SimpleNamespace(stop_signal=None)
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    with StopProtocol(repeat_window_s=0.0).training(runner):  # every repeat comes "later"
        _deliver(signal.SIGTERM)
        assert runner.stop_signal == signal.SIGTERM
        _deliver(signal.SIGTERM)  # `timeout` sends two: ignored
        with pytest.raises(KeyboardInterrupt):
            _deliver(signal.SIGINT)
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before

    with pytest.raises(StopRequested) as info:
        Runner._stop_if_requested(runner)
    assert info.value.signum == signal.SIGTERM and isinstance(info.value, KeyboardInterrupt)


def test_sigint_pair_from_timeout_is_one_request():
    # `timeout -s INT` signals the process and then its group: the second SIGINT, even after the handler has run,
    # must not raise where it lands.
    runner = SimpleNamespace(stop_signal=None)
    with StopProtocol(repeat_window_s=3600.0).training(runner):
        _deliver(signal.SIGINT)
        assert runner.stop_signal == signal.SIGINT
        _deliver(signal.SIGINT)  # would raise KeyboardInterrupt here if it counted as insisting
        assert runner.stop_signal == signal.SIGINT


def test_a_stop_before_the_first_iteration_says_no_checkpoint_exists(tmp_path):
    # A first iteration of 100000 env steps cannot end before the signal: nothing may be saved, and the user is told.
    runs = tmp_path / "runs"
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "task=Cartpole", "num_envs=4", "max_iterations=5",
           "train.runner.num_steps_per_env=100000", *CPU_ARGS, f"runs_dir={runs}"]
    status, text = signal_at_line(cmd, tmp_path, "[train] Cartpole: 4 envs", signal.SIGINT)  # training starts after it
    assert status == 130, text[-3000:]
    assert "no checkpoint exists yet" in text and text.count("stopped by SIGINT") == 1, text[-3000:]
    (run_dir,) = (runs / "Cartpole").iterdir()
    assert not list(run_dir.glob("model_*.pt"))
    assert json.loads((run_dir / "summary.json").read_text())["iterations"] == 0


def test_cpu_threads_sets_torchs_thread_count():
    from isaacgymenvs_mw.utils.config import cpu_threads

    assert cpu_threads("auto") == os.cpu_count() and cpu_threads(3) == 3 and cpu_threads("2") == 2
    for bad in (0, -1, 1.5, "many", True):
        with pytest.raises(ValueError, match=r"cpu_threads=.* is invalid: give a whole number >= 1 or auto"):
            cpu_threads(bad)
    before = torch.get_num_threads()
    try:
        task = make("Cartpole", num_envs=2, sim_device="cpu", rl_device="cpu", overrides=["cpu_threads=2"])
        assert torch.get_num_threads() == 2
        task.close()
    finally:
        torch.set_num_threads(before)
