"""The stop protocol from the first line of train.py to the last (isaacgymenvs_mw/utils/stop.py).

A SIGTERM (``timeout``, a scheduler) or SIGINT must end a run with one line and the signal's exit status, keeping the
checkpoint and summary once training has begun, whenever it comes: during start-up (a cold kernel cache compiles for
a long while), after the post-physics step has compiled by any of its three paths, and after a library replaced the
handler behind Python's back.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import CPU_ARGS, REPO_ROOT

ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}


def test_sigterm_during_start_up_with_a_cold_kernel_cache_ends_with_one_line_and_status_143(tmp_path):
    # With an empty kernel cache, Warp compiles Cartpole's kernels for well over 5 s on a 2-core machine: the
    # signal lands in the start-up, where no handler used to exist and the run ended with no word.
    env = {**ENV, "WARP_CACHE_PATH": str(tmp_path / "warp_cache")}
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "task=Cartpole", "num_envs=4", *CPU_ARGS,
           f"runs_dir={tmp_path / 'runs'}"]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    time.sleep(5.0)
    proc.send_signal(signal.SIGTERM)
    signalled = time.monotonic()
    try:
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    took = time.monotonic() - signalled
    assert "[it " not in out, out  # it was still starting: the test's premise
    assert proc.returncode == 143, out
    assert out.strip().splitlines()[-1] == ("[train] stopped by SIGTERM before the first training iteration ended: "
                                            "no checkpoint exists yet"), out
    assert "Traceback" not in out
    # It ends at once: it does not first wait for the kernel modules still queued on the compile threads.
    assert took < 10.0, took


@pytest.mark.parametrize("path, compiled_at", [("ahead", "alongside Warp's kernels"), ("first_call", "first step"),
                                               ("eager", "None")])
def test_after_the_step_compiled_by_each_path_sigterm_still_reaches_our_handler_and_saves(tmp_path, path,
                                                                                          compiled_at):
    runs = tmp_path / "runs"
    cmd = [sys.executable, str(REPO_ROOT / "tests" / "_stop_driver.py"), path, "task=Cartpole", "num_envs=4",
           "max_iterations=1000", "train.runner.save_interval=1000", "+task.sim.compileStep=True", *CPU_ARGS,
           f"runs_dir={runs}"]
    out = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, env=ENV, timeout=600)
    text = out.stdout + out.stderr
    assert f"[driver] compiled_at={compiled_at} python_handler=True native_handler=True" in text, text[-3000:]
    assert out.returncode == 143, text[-3000:]
    (run_dir,) = (runs / "Cartpole").iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["signal"] == "SIGTERM"
    checkpoint = run_dir / f"model_{summary['final_iteration']}_interrupted.pt"
    assert checkpoint.is_file() and summary["interrupted_checkpoint"] == str(checkpoint)
    assert f"what it learned is in {checkpoint}" in text  # the stop names the checkpoint it wrote


REPLACED = """
import ctypes, os, signal, sys, time
from types import SimpleNamespace
from isaacgymenvs_mw.utils.stop import StopProtocol, StopRequested, native_handler
stop = StopProtocol()
stop.install()
print("clean", stop.reassert())
if sys.argv[1] == "native":  # as a C library calling signal(): Python's view still shows the old handler
    libc = ctypes.CDLL(None)
    libc.signal.restype = ctypes.c_void_p
    libc.signal.argtypes = [ctypes.c_int, ctypes.c_void_p]
    libc.signal(signal.SIGTERM, 0)  # SIG_DFL
    print("python_view_unchanged", signal.getsignal(signal.SIGTERM) is stop._handler, native_handler(signal.SIGTERM))
    time.sleep(0.5)  # the watchdog writes ours back, with no call from this thread
    print("watchdog_restored", native_handler(signal.SIGTERM) == stop._native[signal.SIGTERM])
    try:  # the default action would end the process here; ours raises where the signal lands (start-up phase)
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(1000):
            pass
    except StopRequested as stop_request:
        print("ours_raised", stop_request.signum == signal.SIGTERM)
    stop.signum = None  # a fresh protocol for the part below
else:
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
print("message", stop.reassert())
runner = SimpleNamespace(stop_signal=None)
with stop.training(runner):
    os.kill(os.getpid(), signal.SIGTERM)  # the default action would end the process here, silently
    for _ in range(1000):
        pass
print("alive", runner.stop_signal == signal.SIGTERM)
"""


@pytest.mark.parametrize("how, names", [("native", "SIGTERM by native code (sigaction: the default action"),
                                        ("python", "SIGTERM by the default action (the process dies) (through Python)")])
def test_a_replaced_handler_is_found_put_back_and_named(how, names):
    out = subprocess.run([sys.executable, "-c", REPLACED, how], capture_output=True, text=True, env=ENV, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    lines = dict(line.split(" ", 1) for line in out.stdout.strip().splitlines())
    assert lines["clean"] == "None"  # nothing to say while nothing replaced it
    if how == "native":
        assert lines["python_view_unchanged"] == "True 0"  # Python cannot see it: the kernel's view is read
        assert lines["watchdog_restored"] == "True" and lines["ours_raised"] == "True"
    assert names in lines["message"] and "it is back" in lines["message"]
    assert lines["alive"] == "True"


IN_A_FINALISER = """
import gc, os, signal, time
from isaacgymenvs_mw.utils.stop import StopProtocol, StopRequested
stop = StopProtocol()
stop.install()

class Buffer:  # as a Warp array: its finaliser frees memory when the garbage collector reaches it
    def __del__(self):
        os.kill(os.getpid(), signal.SIGTERM)  # the signal lands here, where Python discards what is raised
        for _ in range(1000):
            pass

started = time.monotonic()
try:
    Buffer()
    gc.collect()
    while time.monotonic() - started < 20.0:  # start-up carrying on
        sum(range(1000))
    print("kept going")
except StopRequested as stop_request:
    print("stopped", stop_request.signum == signal.SIGTERM, time.monotonic() - started < 1.0)
"""


def test_a_signal_that_lands_in_a_finaliser_still_stops_the_start_up_at_once():
    # CI, 2026-11-29: SIGTERM landed in a Warp array's __del__ during start-up; the StopRequested raised there was
    # printed as "Exception ignored" and the start-up went on for 12 s more.
    out = subprocess.run([sys.executable, "-c", IN_A_FINALISER], capture_output=True, text=True, env=ENV, timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.strip() == "stopped True True", out.stdout + out.stderr  # within a second, not 20 s later
    assert "Exception ignored" not in out.stderr and "Traceback" not in out.stderr, out.stderr


STUCK = """
import os, signal, time
from types import SimpleNamespace
from isaacgymenvs_mw.utils.stop import StopProtocol
stop = StopProtocol(stop_grace_s=1.0)
stop.install()
runner = SimpleNamespace(stop_signal=None)
with stop.training(runner):
    os.kill(os.getpid(), signal.SIGTERM)
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:  # a run that never reaches its next env step (a compile waiting forever)
        time.sleep(0.05)
print("never stopped")
"""


def test_a_stop_that_is_stuck_ends_with_every_threads_stack_and_the_signals_status():
    started = time.monotonic()
    out = subprocess.run([sys.executable, "-c", STUCK], capture_output=True, text=True, env=ENV, timeout=60)
    assert out.returncode == 143, out.stdout + out.stderr
    assert time.monotonic() - started < 20.0  # well before the 30 s the main thread would wait
    assert "never stopped" not in out.stdout
    assert "still running 1 s after SIGTERM: the stop is stuck" in out.stderr
    assert "Current thread" in out.stderr or "Thread 0x" in out.stderr  # faulthandler's dump of the threads
