"""Training throughput on the CPU against torch's thread count, alone and beside one busy process.

    python benchmarks/cpu_threads.py [--tasks Cartpole Anymal] [--threads 1 auto] [--iterations 8]

Each case runs ``train.py`` in a subprocess with ``cpu_threads=<n>`` and reads summary.json; the rate is the mean
over the iterations after the first (which compiles). "busy" starts a pure-Python spinning process first, the
kind of neighbour a shared workstation or CI runner has. Prints one JSON line per case.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# Per task: envs and rollout length small enough for a 2-core CPU, large enough that stepping dominates.
TASK_ARGS = {
    "Cartpole": ["num_envs=512"],
    "Anymal": ["num_envs=256", "train.runner.num_steps_per_env=8"],
}


def steady_rate(summary: dict) -> float:
    rows = summary["history"][1:]
    steps = sum(r["env_steps"] - p["env_steps"] for p, r in zip(summary["history"], rows))
    return steps / sum(r["collect_s"] + r["learn_s"] for r in rows)


def run_case(task: str, threads: str, busy: bool, iterations: int) -> dict:
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy else None
    try:
        with tempfile.TemporaryDirectory() as runs:
            cmd = [sys.executable, str(REPO / "train.py"), f"task={task}", "headless=True", "sim_device=cpu",
                   "rl_device=cpu", f"max_iterations={iterations}", f"cpu_threads={threads}", f"runs_dir={runs}",
                   *TASK_ARGS.get(task, [])]
            env = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"}  # the key alone decides
            subprocess.run(cmd, cwd=REPO, check=True, capture_output=True, text=True, env=env)
            (summary_path,) = Path(runs).glob("*/*/summary.json")
            summary = json.loads(summary_path.read_text())
    finally:
        if spinner is not None:
            spinner.kill()
            spinner.wait()
    return {"task": task, "cpu_threads": threads, "busy_neighbour": busy, "cores": os.cpu_count(),
            "steady_env_steps_per_s": round(steady_rate(summary)), "iterations": iterations}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(TASK_ARGS))
    parser.add_argument("--threads", nargs="+", default=["1", "auto"])
    parser.add_argument("--iterations", type=int, default=8)
    args = parser.parse_args()
    for task in args.tasks:
        for busy in (False, True):
            for threads in args.threads:
                print(json.dumps(run_case(task, threads, busy, args.iterations)), flush=True)


if __name__ == "__main__":
    main()
