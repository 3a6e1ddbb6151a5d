"""What a run prints: one line for Warp's kernels (Warp's own lines only with verbose=True), no CUDA-driver warning on
CPU runs, no rsl_rl network printout, a plain word while no episode has ended (another for a quiet iteration after
that); kernels ready before the first step, so that stepping compiles or loads nothing more; and, should a native
library crash, every thread's Python stack in the log."""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys

import pytest
from conftest import CPU_ARGS, REPO_ROOT

ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}


def train(tmp_path, *extra: str) -> str:
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "task=Cartpole", "num_envs=4", "max_iterations=1",
           "train.runner.num_steps_per_env=2", *CPU_ARGS, f"runs_dir={tmp_path / 'runs'}", *extra]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env=ENV)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    return out


def test_default_output_is_compact(tmp_path):
    out = train(tmp_path)
    kernel_lines = [ln for ln in out.splitlines() if ln.startswith("[isaacgymenvs_mw] Warp kernels on cpu:")]
    assert len(kernel_lines) >= 1 and re.search(r"\d+ modules ready in [\d.]+ s", kernel_lines[-1]), out
    assert " load on device " not in out and "Warp 1." not in out  # Warp's per-module lines and banner
    assert "Could not find or load the NVIDIA CUDA driver" not in out
    assert "MLP(" not in out and "Resolved observation sets" not in out
    # 2 steps per iteration: no Cartpole episode can have ended, and the line says how far the longest got
    (it_line,) = [ln for ln in out.splitlines() if ln.startswith("[it ")]
    assert "no episode ended yet (longest 2/" in it_line and "ep_rew" not in it_line, it_line
    assert it_line.endswith("| ETA 0s"), it_line  # the last iteration: nothing left
    # The first line comes before the imports of torch and MuJoCo Warp and says what follows (its time is a
    # benchmark's to judge: benchmarks/startup_phases.py)
    first = proc_lines(out)[0]
    assert re.fullmatch(r"\[train\] Cartpole: training; loading torch, MuJoCo Warp and the learner, then building "
                        r"the worlds \((\d+\.\d) s after start\)", first), first


def proc_lines(out: str) -> list[str]:
    return [ln for ln in out.splitlines() if ln.strip()]


def test_a_quiet_iteration_after_episodes_have_ended_is_not_called_yet(tmp_path):
    # Cartpole episodes of at most 4 steps (episodeLength_s / dt = 0.066 / 0.0166) time out after 3 steps, all envs
    # together, and an iteration is 2 steps: steps 1-2 end nothing, 3 and 6 end every episode, 7-8 end nothing.
    out = train(tmp_path, "max_iterations=4", "task.env.episodeLength_s=0.066")
    lines = [ln for ln in out.splitlines() if ln.startswith("[it ")]
    assert len(lines) == 4, out[-2000:]
    assert "no episode ended yet (longest 2/4" in lines[0], lines[0]
    assert "ep_len     3.0" in lines[1] and "ep_len     3.0" in lines[2], lines
    assert "no episode ended this iteration (longest 2/4" in lines[3], lines[3]


# A real segfault in native code, on the main thread in the middle of training: train.py run as a script, with the
# runner's per-iteration log patched to read address 0 through ctypes (a crash in library code).
NATIVE_CRASH = """
import ctypes, runpy, sys
from isaacgymenvs_mw.learning.runner import Runner
Runner._log_iteration = lambda *args, **kwargs: ctypes.string_at(0)
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


def test_a_native_crash_leaves_the_python_stack_in_the_log(tmp_path):
    # The crash is the main thread's own, with the GIL held, so every other thread's frames stand still while
    # faulthandler prints them. (A SIGSEGV sent from outside went to any thread, and the thread then holding the GIL
    # could change its frames under the dump and end it early: 1 run in 12 on a loaded 2-core machine.)
    cmd = [sys.executable, "-c", NATIVE_CRASH, str(REPO_ROOT / "train.py"), "task=Cartpole", "num_envs=4",
           "max_iterations=3", "train.runner.num_steps_per_env=2", *CPU_ARGS, f"runs_dir={tmp_path / 'runs'}"]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env=ENV)
    out = proc.stdout + proc.stderr
    assert proc.returncode == -signal.SIGSEGV, out[-2000:]
    assert "Fatal Python error: Segmentation fault" in out, out[-2000:]
    # the crashing thread's frames, newest first: ctypes' read, then up through the training loop
    crashed_in_learn = (r"Current thread 0x[0-9a-f]+.*\n"
                        r"  File .*ctypes.*\n(  File .*\n)*  File .*training_run\.py\", line \d+ in learn")
    assert re.search(crashed_in_learn, out), out[-2000:]


def test_eta_formats_the_time_left():
    from isaacgymenvs_mw.learning.reporting import duration

    assert [duration(s) for s in (0.4, 42, 185, 3725, float("nan"))] == ["0s", "42s", "3m05s", "1h02m", "--"]


def test_eta_leaves_out_the_compiling_first_iteration():
    # Go1Terrain's first iteration (compiling) took minutes and its ETA read 8h10m; steady ones are what is left.
    from isaacgymenvs_mw.learning.reporting import steady_iteration_s

    history = [{"collect_s": 90.0, "learn_s": 10.0}, {"collect_s": 0.3, "learn_s": 0.1},
               {"collect_s": 0.5, "learn_s": 0.1}]
    assert steady_iteration_s(history) == pytest.approx((0.4 + 0.6) / 2)
    assert math.isnan(steady_iteration_s(history[:1]))  # only the first: not known yet


def test_a_slow_first_collect_reports_progress(monkeypatch, capsys):
    from isaacgymenvs_mw.learning import reporting

    clock = iter([100.0, 104.0, 120.0, 150.0])  # seconds at steps 1, 2, 3, 4 (the last: no line, the update follows)
    monkeypatch.setattr(reporting.time, "perf_counter", lambda: next(clock))
    progress = reporting.FirstCollectProgress(iteration=1, steps=4, started=95.0, every_s=15.0)
    for step in range(1, 5):
        progress.step_done(step)
    lines = capsys.readouterr().out.splitlines()
    # 104 s is 9 s after the start (quiet); 120 s is 25 s: a line; 150 s is 30 s after it, but the last step
    assert lines == ["[it     1] collecting: env step 3/4 after 25s, about 8s more before the update"]


def test_verbose_shows_warp_and_rsl_rl_detail(tmp_path):
    out = train(tmp_path, "verbose=True")
    assert " load on device 'cpu'" in out and "MLP(" in out


STEP_AFTER_BUILD = """
import isaacgymenvs_mw, warp
task = isaacgymenvs_mw.make("Go1", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True)
warp.config.log_level = warp.LOG_INFO  # from here on Warp reports every module it loads
print("BUILT", flush=True)
task.reset()
for _ in range(3):
    task.step(task.zero_actions())
task.sim.forward()
print("STEPPED", flush=True)
"""


def test_kernels_are_ready_before_the_first_step(tmp_path):
    proc = subprocess.run([sys.executable, "-c", STEP_AFTER_BUILD], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300, env={**ENV, "PYTHONPATH": str(REPO_ROOT)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    before, after = proc.stdout.split("BUILT", 1)
    assert "STEPPED" in after
    assert re.search(r"Warp kernels on cpu: \d+ modules ready", before)
    assert " load on device " not in after, after  # reset, steps and forward found every module loaded


def test_block_size_queries_are_recorded_not_compiled():
    # MuJoCo Warp asks Warp for an occupancy-based block size, which on CUDA compiles the module on the spot; the dry
    # run must record that module (at the default block size, the variant the query loads) and compile nothing.
    import types

    import warp as wp

    from isaacgymenvs_mw.sim import kernels

    @wp.kernel(module="unique")
    def double(x: wp.array(dtype=float)):
        i = wp.tid()
        x[i] = 2.0 * x[i]

    real_query = wp.get_suggested_block_size
    gpu = types.SimpleNamespace(is_cuda=True, sm_count=132)  # stands for a CUDA device; nothing runs on it
    answers = []

    def entry_point():
        answers.append(wp.get_suggested_block_size(double, gpu))
        answers.append(wp.get_suggested_block_size(double, "cpu"))
        wp.launch(double, dim=4, inputs=[wp.zeros(4, dtype=float, device="cpu")], block_dim=64, device="cpu")

    recorded = kernels._record_launches([entry_point])
    assert recorded == [(double.module, None), (double.module, 64)]
    assert answers[0][0] > 0 and answers[0][1] == 132
    assert answers[1] == real_query(double, "cpu") == (1, 1)
    assert not double.module.execs  # neither the query nor the launch compiled it
    assert wp.get_suggested_block_size is real_query
