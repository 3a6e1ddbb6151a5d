"""Seconds from process start to the first training iteration, with cold and with warm compile caches.

Runs ``train.py task=<task> max_iterations=<n>`` as a new process, first with empty Warp, TorchInductor and Triton
caches (what a new machine or a changed model pays), then again with the caches that run filled (every later
run). For each it reports, from the moment the process was started:
  - ``task_built_s``: the run's "[train] ..." line (model built, kernels loaded, networks made);
  - ``first_iteration_s``: the first "[it 1/...]" line, i.e. the first training iteration done (rollout with the
    post-physics step compiled, and the PPO update);
  - ``total_s``: the whole run;
  - ``timeline``: every other line the run printed (kernel progress, step compilation, ...) with its time.
--profile_dir DIR also runs each under cProfile (DIR/cold.prof, DIR/warm1.prof, ...) to break the start-up down;
the profiler slows Python-heavy phases, so take the times above from a run without it.
Prints one JSON object. The caches live in a temporary folder unless --cache_dir names one.

  python benchmarks/cold_start.py --task Go1 [--num_envs 4096] [--sim_device cuda:0] [--warm_runs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
FIRST_ITERATION = re.compile(r"^\[it\s+\d+/\d+\]")


def timed_run(args: argparse.Namespace, cache: Path, runs: Path, name: str) -> dict:
    profile = ["-m", "cProfile", "-o", str(Path(args.profile_dir) / f"{name}.prof")] if args.profile_dir else []
    cmd = [sys.executable, *profile, str(REPO_ROOT / "train.py"), f"task={args.task}", f"max_iterations={args.iterations}",
           "headless=True", f"sim_device={args.sim_device}", f"rl_device={args.sim_device}", f"runs_dir={runs}"]
    if args.num_envs:
        cmd.append(f"num_envs={args.num_envs}")
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "WARP_CACHE_PATH": str(cache / "warp"),
           "TORCHINDUCTOR_CACHE_DIR": str(cache / "inductor"), "TRITON_CACHE_DIR": str(cache / "triton")}
    out: dict = {"task_built_s": None, "first_iteration_s": None, "timeline": []}
    lines = []
    start = time.perf_counter()
    with subprocess.Popen(cmd, cwd=REPO_ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True) as proc:
        for line in proc.stdout:
            now = time.perf_counter() - start
            lines.append(line.rstrip())
            if out["task_built_s"] is None and line.startswith("[train] ") and " envs on " in line:
                out["task_built_s"] = now
            if not FIRST_ITERATION.match(line):
                out["timeline"].append(f"{now:7.1f} s  {line.rstrip()[:150]}")
            elif out["first_iteration_s"] is None:
                out["first_iteration_s"] = now
        rc = proc.wait()
    out["total_s"] = time.perf_counter() - start
    out["returncode"] = rc
    out["kernel_lines"] = [ln for ln in lines if ln.startswith("[isaacgymenvs_mw] Warp kernels")][-1:]
    if rc != 0:
        out["output_tail"] = lines[-30:]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="Go1")
    parser.add_argument("--num_envs", type=int, default=0, help="0: the task YAML's numEnvs")
    parser.add_argument("--sim_device", default="auto")
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--warm_runs", type=int, default=1)
    parser.add_argument("--cache_dir", default="", help="where the fresh caches go (default: a temporary folder)")
    parser.add_argument("--profile_dir", default="", help="also profile each run with cProfile, files go here")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="cold_start_") as tmp:
        cache = Path(args.cache_dir) if args.cache_dir else Path(tmp) / "cache"
        if cache.exists() and any(cache.iterdir()):
            sys.exit(f"--cache_dir={cache} is not empty: a cold run needs empty caches")
        runs = Path(tmp) / "runs"
        if args.profile_dir:
            Path(args.profile_dir).mkdir(parents=True, exist_ok=True)
        cold = timed_run(args, cache, runs, "cold")
        warm = [timed_run(args, cache, runs, f"warm{i + 1}") for i in range(args.warm_runs)]
    print(json.dumps({"task": args.task, "num_envs": args.num_envs or "task default", "sim_device": args.sim_device,
                      "cpu_count": os.cpu_count(), "cold": cold, "warm": warm}, indent=2))


if __name__ == "__main__":
    main()
