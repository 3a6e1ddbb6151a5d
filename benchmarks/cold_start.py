"""Seconds from process start to the first training iteration, with cold and with warm compile caches.

Runs ``train.py task=<task> max_iterations=<n>`` as a new process, first with empty Warp, TorchInductor and Triton
caches (what a new machine or a changed model pays), then again with the caches that run filled (every later
run). For each it reports, from the moment the process was started:
  - ``task_built_s``: the run's "[train] ..." line (model built, kernels loaded, networks made);
  - ``first_iteration_s``: the first "[it 1/...]" line, i.e. the first training iteration done (rollout with the
    post-physics step compiled, and the PPO update);
  - ``total_s``: the whole run;
  - ``phases``: the start-up phases as the run's own lines give them: ``warp_kernels_s`` (Warp's kernel modules,
    compiled in parallel), ``step_compile_s`` (torch.compile of the post-physics step) and ``step_compiled`` (where
    it ran: "alongside Warp's kernels", i.e. overlapped with them, or "first step"; None: not compiled), then
    ``iterations`` (each iteration's collect and learn seconds and steps/s, the first one included);
  - ``timeline``: every other line the run printed (kernel progress, step compilation, ...) with its time.
--compile_step_off measures the same again with ``+task.sim.compileStep=False`` (its own empty caches, then warm):
an uncompiled step starts sooner and steps slower, and over ``--iterations`` the totals say which wins.
--after_warmup also measures a start after ``python -m isaacgymenvs_mw.warmup`` (the same task, num_envs and device)
filled an empty cache folder of its own: the warm-up's seconds (``warmup_s``), then the folder is moved to another
place and one run starts on it, whose ``first_iteration_s`` is what a shipped cache gives a fresh machine.
Every process gets its caches through ISAACGYMENVS_MW_CACHE (utils/compile_cache.py): Warp's, Inductor's, Triton's
and the CUDA driver's, so that a cold run finds none of the machine's own.
--profile_dir DIR also runs each under cProfile (DIR/cold.prof, DIR/warm1.prof, ...) to break the start-up down;
the profiler slows Python-heavy phases, so take the times above from a run without it.
Prints one JSON object: ``summary`` (the headline seconds of every run), then each run in full. The caches live in
a temporary folder unless --cache_dir names one.

  python benchmarks/cold_start.py --task Go1 [--num_envs 4096] [--sim_device cuda:0] [--warm_runs 2]
                                  [--compile_step_off] [--after_warmup]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from isaacgymenvs_mw.utils.compile_cache import SUBFOLDERS

REPO_ROOT = Path(__file__).resolve().parents[1]
FIRST_ITERATION = re.compile(r"^\[it\s+\d+/\d+\]")
# The start-up lines of sim/kernels.py and tasks/base/step_execution.py, and the progress line of each iteration.
WARP_KERNELS = re.compile(r"Warp kernels on \S+: (\d+) modules ready in ([\d.]+) s")
STEP_COMPILED = re.compile(r"compiled \S+ post-physics step \(sim\.compileStep\) (?:at the first step )?in ([\d.]+) s"
                           r"(, alongside Warp's kernels)?")
ITERATION = re.compile(r"([\d,]+) steps/s .* collect\s+([\d.]+)s learn\s+([\d.]+)s")
COMPILE_STEP_OFF = "+task.sim.compileStep=False"


def phases(lines: list[str]) -> dict:
    """The start-up phases and the iterations, from the lines the run printed."""
    out: dict = {"warp_kernels_s": None, "warp_modules": None, "step_compile_s": None, "step_compiled": None,
                 "iterations": []}
    for line in lines:
        if (kernels := WARP_KERNELS.search(line)) and out["warp_kernels_s"] is None:
            out["warp_modules"], out["warp_kernels_s"] = int(kernels.group(1)), float(kernels.group(2))
        elif step := STEP_COMPILED.search(line):  # a recompilation at the first step counts on top
            out["step_compile_s"] = (out["step_compile_s"] or 0.0) + float(step.group(1))
            out["step_compiled"] = "alongside Warp's kernels" if step.group(2) else "first step"
        elif FIRST_ITERATION.match(line) and (it := ITERATION.search(line)):
            out["iterations"].append({"steps_per_s": float(it.group(1).replace(",", "")),
                                      "collect_s": float(it.group(2)), "learn_s": float(it.group(3))})
    return out


def cache_env(cache: Path) -> dict[str, str]:
    """The environment of a measured process: every compile cache (Warp's, Inductor's, Triton's and the CUDA
    driver's) in a folder under ``cache`` (ISAACGYMENVS_MW_CACHE), none of the machine's own."""
    env = {k: v for k, v in os.environ.items() if k not in SUBFOLDERS}
    return {**env, "PYTHONUNBUFFERED": "1", "ISAACGYMENVS_MW_CACHE": str(cache)}


def timed_warmup(args: argparse.Namespace, cache: Path) -> dict:
    """``python -m isaacgymenvs_mw.warmup`` for the measured task, on the caches under ``cache``: its seconds and
    its lines (the Warp kernel line and the warm-up's own, which names what each cache gained)."""
    cmd = [sys.executable, "-m", "isaacgymenvs_mw.warmup", f"task={args.task}", f"sim_device={args.sim_device}",
           f"rl_device={args.sim_device}"]
    if args.num_envs:
        cmd.append(f"num_envs={args.num_envs}")
    start = time.perf_counter()
    proc = subprocess.run(cmd, cwd=REPO_ROOT, env=cache_env(cache), capture_output=True, text=True)
    lines = (proc.stdout + proc.stderr).splitlines()
    out = {"warmup_s": time.perf_counter() - start, "returncode": proc.returncode,
           "lines": [ln for ln in lines if ln.startswith(("[warmup]", "[isaacgymenvs_mw]"))]}
    if proc.returncode != 0:
        out["output_tail"] = lines[-30:]
    return out


def after_warmup(args: argparse.Namespace, cache: Path, runs: Path) -> dict:
    """A warm-up on an empty cache folder of its own, the folder then moved elsewhere (as if shipped to another
    machine: nothing left where it was made), then one run on the moved folder."""
    built, shipped = cache / "built", cache / "shipped"
    if cache.exists() and any(cache.iterdir()):
        sys.exit(f"{cache} is not empty: the warm-up needs empty caches (--cache_dir)")
    warmup = timed_warmup(args, built)
    shutil.copytree(built, shipped)
    shutil.rmtree(built)
    return {"warmup": warmup, "run": timed_run(args, shipped, runs, "after_warmup")}


def timed_run(args: argparse.Namespace, cache: Path, runs: Path, name: str, overrides: tuple[str, ...] = ()) -> dict:
    profile = ["-m", "cProfile", "-o", str(Path(args.profile_dir) / f"{name}.prof")] if args.profile_dir else []
    cmd = [sys.executable, *profile, str(REPO_ROOT / "train.py"), f"task={args.task}", f"max_iterations={args.iterations}",
           "headless=True", f"sim_device={args.sim_device}", f"rl_device={args.sim_device}", f"runs_dir={runs}",
           *overrides]
    if args.num_envs:
        cmd.append(f"num_envs={args.num_envs}")
    out: dict = {"task_built_s": None, "first_iteration_s": None, "timeline": []}
    lines = []
    start = time.perf_counter()
    with subprocess.Popen(cmd, cwd=REPO_ROOT, env=cache_env(cache), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
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
    out["phases"] = phases(lines)
    if rc != 0:
        out["output_tail"] = lines[-30:]
    return out


def cold_then_warm(args: argparse.Namespace, cache: Path, runs: Path, name: str,
                   overrides: tuple[str, ...] = ()) -> dict:
    """One cold run on the empty caches under ``cache``, then ``--warm_runs`` on what it left there."""
    if cache.exists() and any(cache.iterdir()):
        sys.exit(f"{cache} is not empty: a cold run needs empty caches (--cache_dir)")
    prefix = f"{name}_" if name else ""
    cold = timed_run(args, cache, runs, f"{prefix}cold", overrides)
    warm = [timed_run(args, cache, runs, f"{prefix}warm{i + 1}", overrides) for i in range(args.warm_runs)]
    return {"cold": cold, "warm": warm}


def headline(measured: dict) -> dict:
    """Seconds to the first iteration and of the whole run, per run, and where the step was compiled."""
    rows = {"cold": measured["cold"], **{f"warm{i + 1}": run for i, run in enumerate(measured["warm"])}}
    return {name: headline_row(run) for name, run in rows.items()}


def headline_row(run: dict) -> dict:
    keys = ("first_iteration_s", "total_s")
    return {**{k: None if run[k] is None else round(run[k], 1) for k in keys},
            "warp_kernels_s": run["phases"]["warp_kernels_s"], "step_compile_s": run["phases"]["step_compile_s"],
            "step_compiled": run["phases"]["step_compiled"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="Go1")
    parser.add_argument("--num_envs", type=int, default=0, help="0: the task YAML's numEnvs")
    parser.add_argument("--sim_device", default="auto")
    parser.add_argument("--iterations", type=int, default=2)
    parser.add_argument("--warm_runs", type=int, default=1)
    parser.add_argument("--compile_step_off", action="store_true",
                        help=f"also measure the run with {COMPILE_STEP_OFF} (cold on its own empty caches, then warm)")
    parser.add_argument("--after_warmup", action="store_true",
                        help="also measure a run after python -m isaacgymenvs_mw.warmup filled empty caches of its own")
    parser.add_argument("--cache_dir", default="", help="where the fresh caches go (default: a temporary folder)")
    parser.add_argument("--profile_dir", default="", help="also profile each run with cProfile, files go here")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="cold_start_") as tmp:
        cache = Path(args.cache_dir) if args.cache_dir else Path(tmp) / "cache"
        runs = Path(tmp) / "runs"
        if args.profile_dir:
            Path(args.profile_dir).mkdir(parents=True, exist_ok=True)
        default = cold_then_warm(args, cache, runs, "")
        # Its own caches: Warp's modules would otherwise be warm for the cold run without the compiled step.
        off = cold_then_warm(args, cache / "compile_step_off", runs, "compile_step_off", (COMPILE_STEP_OFF,)) \
            if args.compile_step_off else None
        warmed = after_warmup(args, cache / "after_warmup", runs) if args.after_warmup else None
    summary = {"default": headline(default)}
    if off is not None:
        summary["compileStep=False"] = headline(off)
    if warmed is not None:
        summary["after_warmup"] = {"warmup_s": round(warmed["warmup"]["warmup_s"], 1),
                                   **headline_row(warmed["run"])}
    result = {"task": args.task, "num_envs": args.num_envs or "task default", "sim_device": args.sim_device,
              "cpu_count": os.cpu_count(), "iterations": args.iterations, "summary": summary, **default}
    if off is not None:
        result["compile_step_off"] = off
    if warmed is not None:
        result["after_warmup"] = warmed
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
