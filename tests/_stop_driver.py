"""Runs train.py in this process with a hook after the first training iteration (used by tests/workflow/test_stop.py).

Usage: python tests/_stop_driver.py PATH [train.py overrides...]; PATH is "ahead", "first_call" or "eager" (how the
post-physics step gets compiled). After the first iteration it prints whether SIGTERM's handler, as Python and as
the kernel see it, is still the one train.py installed, then sends itself SIGTERM.
"""

import os
import runpy
import signal
import sys
from pathlib import Path

import torch

from isaacgymenvs_mw.learning import launch
from isaacgymenvs_mw.learning.runner import Runner
from isaacgymenvs_mw.utils.stop import PROCESS_STOP, native_handler

path, overrides = sys.argv[1], sys.argv[2:]
if path == "eager":  # torch runs the step uncompiled: the fallback where compiling is off or impossible
    torch.compiler.set_stance("force_eager")
if path == "first_call":  # as a step with a graph break: compiled by its first call, inside the first iteration
    build = launch.build_task

    def build_compiled_at_first_call(cfg):
        task = build(cfg)
        task.execution.compile_ahead = False
        return task

    launch.build_task = build_compiled_at_first_call

log_iteration = Runner._log_iteration


def log_then_signal(self, writer, it, *args, **kwargs):
    log_iteration(self, writer, it, *args, **kwargs)
    if it == 0:
        ours = signal.getsignal(signal.SIGTERM) is PROCESS_STOP._handler
        native = native_handler(signal.SIGTERM) == PROCESS_STOP._native[signal.SIGTERM]
        print(f"[driver] compiled_at={self.env.task.execution.compiled_at} python_handler={ours} "
              f"native_handler={native}", flush=True)
        os.kill(os.getpid(), signal.SIGTERM)


Runner._log_iteration = log_then_signal
sys.argv = ["train.py", *overrides]
runpy.run_path(str(Path(__file__).resolve().parents[1] / "train.py"), run_name="__main__")
