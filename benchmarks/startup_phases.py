"""Where the seconds before the first training iteration go: one ``train.py`` run, timed phase by phase in-process.

``cold_start.py`` reads the lines a run prints; this script looks inside one run instead. It imports the packages a
training run needs one at a time (timing each), then runs ``train.py`` in this process with the start-up functions
wrapped by a timer: Hydra's composition, the device set-up, the model build (MjSpec compile and the stability probe
inside it), ``put_model``/``make_data``, the recording of Warp's kernel launches, the randomiser's binding, the wait
for Warp's kernels (the step's compilation runs inside it), the runner's construction and the training. Times are
seconds from the process's start (the interpreter's own start-up included, on Linux), so ``train_line_s`` and
``first_iteration_s`` compare with ``cold_start.py``'s ``task_built_s`` and ``first_iteration_s``. The imports are
listed in the order they ran; in a plain ``train.py`` the learning stack's imports come after Hydra's composition,
which moves the phases after them but not their lengths. Caches are whatever the environment points at (run
``cold_start.py`` for empty ones).

  python benchmarks/startup_phases.py task=Go1 num_envs=4096 sim_device=cuda:0 rl_device=cuda:0 max_iterations=1

Every argument goes to ``train.py`` (``headless=True`` is added). Prints one JSON object at the end.
"""

from __future__ import annotations

import functools
import importlib
import json
import os
import runpy
import sys
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def _process_start() -> float:
    """``time.perf_counter()``'s reading at the moment this process started (Linux: /proc; elsewhere: now)."""
    try:
        with open("/proc/self/stat") as f:
            started_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return time.perf_counter() - (uptime - started_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return time.perf_counter()


T0 = _process_start()
# The packages a training run imports, heaviest first, in the order train.py meets them; the last one brings the rest
# of the framework. Each is timed on top of those before it.
IMPORTS = ("hydra", "isaacgymenvs_mw.utils.config", "torch", "warp", "mujoco", "mujoco_warp", "tensordict",
           "rsl_rl.runners", "isaacgymenvs_mw.learning.launch")
# (module, attribute, label): the start-up functions timed, each wherever the framework holds it.
PHASES = (
    ("hydra._internal.hydra", "Hydra.compose_config", "Hydra composition"),
    ("isaacgymenvs_mw.learning.train_config", "check_before_start", "run keys checked"),
    ("isaacgymenvs_mw.tasks.build", "build_task", "build_task (all of the task's construction)"),
    ("torch.cuda", "set_device", "torch.cuda.set_device (CUDA context)"),
    ("isaacgymenvs_mw.sim.kernels", "init_warp", "Warp init"),
    ("isaacgymenvs_mw.sim.builder", "build_model", "model build (MjSpec edits, compile, stability probe)"),
    ("mujoco", "MjSpec.compile", "MjSpec.compile"),
    ("isaacgymenvs_mw.sim.stability", "probe_divergence", "stability probe (MuJoCo C steps)"),
    ("isaacgymenvs_mw.sim.memory", "check_worlds_fit", "memory check"),
    ("mujoco_warp", "put_model", "put_model"),
    ("mujoco_warp", "make_data", "make_data"),
    ("isaacgymenvs_mw.sim.kernels", "_record_launches", "Warp launches recorded (kernel objects made)"),
    ("isaacgymenvs_mw.tasks.base.randomization", "Randomizer.bind", "randomiser bound"),
    ("isaacgymenvs_mw.sim.graph_engine", "GraphEngine.load_kernels", "wait for Warp's kernels (+ step compile)"),
    ("isaacgymenvs_mw.learning.runner", "Runner.__init__", "rsl-rl runner made"),
    ("isaacgymenvs_mw.learning.runner", "Runner.learn", "training (Runner.learn)"),
)

events: list[dict] = []
lines: dict[str, float] = {}


def now() -> float:
    return round(time.perf_counter() - T0, 3)


def timed_imports() -> list[dict]:
    out = []
    for name in IMPORTS:
        began = time.perf_counter()
        importlib.import_module(name)
        out.append({"import": name, "s": round(time.perf_counter() - began, 3), "done_at": now()})
    return out


def wrap(module: str, attribute: str, label: str) -> None:
    """Time every call of ``module.attribute``, in that module, on its class, and where other modules imported it."""
    try:
        owner = importlib.import_module(module)
    except ImportError:
        return
    *classes, name = attribute.split(".")
    for cls in classes:
        owner = getattr(owner, cls)
    original = getattr(owner, name, None)
    if original is None:
        return

    @functools.wraps(original)
    def timer(*args, **kwargs):
        began = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            events.append({"phase": label, "s": round(time.perf_counter() - began, 3), "ended_at": now()})

    setattr(owner, name, timer)
    if classes:
        return
    for mod in list(sys.modules.values()):  # `from x import f` bindings elsewhere
        if getattr(mod, "__name__", "").startswith("isaacgymenvs_mw") and getattr(mod, name, None) is original:
            setattr(mod, name, timer)


class _LineClock:
    """stdout that notes when the run's "[train] <task>: ..." and first "[it ...]" lines were written."""

    def __init__(self, stream) -> None:
        self.stream = stream

    def write(self, text: str) -> int:
        if text.startswith("[train] ") and " envs on " in text:
            lines.setdefault("train_line_s", now())
        elif text.startswith("[it "):
            lines.setdefault("first_iteration_s", now())
        return self.stream.write(text)

    def __getattr__(self, name: str):
        return getattr(self.stream, name)


def main() -> None:
    sys.path.insert(0, str(REPO_ROOT))
    os.chdir(REPO_ROOT)
    script_started = now()
    imports = timed_imports()
    for module, attribute, label in PHASES:
        wrap(module, attribute, label)
    sys.argv = [str(REPO_ROOT / "train.py"), "headless=True", *sys.argv[1:]]
    sys.stdout = _LineClock(sys.stdout)
    status = 0
    try:
        runpy.run_path(sys.argv[0], run_name="__main__")
    except SystemExit as end:
        status = end.code if isinstance(end.code, int) else (0 if end.code is None else 1)
    finally:
        sys.stdout = sys.stdout.stream
    totals: dict[str, dict] = {}
    for e in events:
        row = totals.setdefault(e["phase"], {"calls": 0, "s": 0.0})
        row["calls"] += 1
        row["s"] = round(row["s"] + e["s"], 3)
    result = {"argv": sys.argv[1:], "exit_status": status, "cpu_count": os.cpu_count(),
              "interpreter_start_s": script_started, "imports": imports,
              "imports_s": round(sum(i["s"] for i in imports), 3), **lines, "end_s": now(),
              "phase_totals": totals, "phases": events}
    print(json.dumps(result, indent=2), flush=True)


if __name__ == "__main__":
    main()
