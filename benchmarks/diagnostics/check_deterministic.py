"""Are two trainings with the same seed bit-identical? Runs ``train.py`` twice (fresh processes, as a user reruns)
and compares the per-iteration histories of their summary.json: losses, learning rate, episode statistics.
Timings are left out. Prints one JSON object: identical (bool), the first differing iteration and keys, and the
largest relative difference of the losses.

  python benchmarks/diagnostics/check_deterministic.py --task Go1 --iterations 20                  # deterministic=True
  python benchmarks/diagnostics/check_deterministic.py --task Go1 --iterations 20 --off            # the same, mode off
  python benchmarks/diagnostics/check_deterministic.py --task Cartpole --num_envs 64 --iterations 20 sim_device=cpu rl_device=cpu
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
TIMING_KEYS = {"time_s", "steps_per_s", "collect_s", "learn_s"}


def train(runs: Path, args, extra: list[str]) -> dict:
    cmd = [sys.executable, str(REPO / "train.py"), f"task={args.task}", f"max_iterations={args.iterations}",
           f"seed={args.seed}", f"deterministic={not args.off}", "headless=True", f"runs_dir={runs}", *extra]
    if args.num_envs:
        cmd.append(f"num_envs={args.num_envs}")
    started = time.perf_counter()
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    if proc.returncode != 0:
        raise SystemExit(f"train.py failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    (summary,) = runs.rglob("summary.json")
    data = json.loads(summary.read_text())
    data["process_s"] = time.perf_counter() - started
    return data


def flatten(record: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in record.items():
        if key in TIMING_KEYS:
            continue
        if isinstance(value, dict):
            out.update(flatten(value, f"{prefix}{key}/"))
        else:
            out[f"{prefix}{key}"] = value
    return out


def compare(a: list[dict], b: list[dict]) -> dict:
    first, keys, worst = None, [], 0.0
    for ra, rb in zip(a, b):
        fa, fb = flatten(ra), flatten(rb)
        differing = sorted(k for k in fa.keys() | fb.keys() if fa.get(k) != fb.get(k))
        if differing and first is None:
            first, keys = ra["iteration"], differing
        for k in fa:
            if k.startswith("losses/") and isinstance(fa[k], float) and isinstance(fb.get(k), float):
                worst = max(worst, abs(fa[k] - fb[k]) / max(abs(fa[k]), 1e-12))
    return {"identical": first is None and len(a) == len(b), "first_differing_iteration": first,
            "differing_keys": keys, "max_rel_loss_difference": worst}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="Go1")
    parser.add_argument("--num_envs", type=int, default=0, help="0: the task YAML's numEnvs")
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--off", action="store_true", help="deterministic=False (what differs without it)")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides for both runs")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        first = train(Path(tmp) / "a", args, args.overrides)
        second = train(Path(tmp) / "b", args, args.overrides)
    result = {"task": args.task, "deterministic": not args.off, "iterations": args.iterations,
              "num_envs": first["num_envs"], "device": first["device"],
              **compare(first["history"], second["history"]),
              "env_steps_per_s": [first["env_steps_per_s"], second["env_steps_per_s"]],
              "final_mean_episode_reward": [first["mean_episode_reward"], second["mean_episode_reward"]],
              "versions": first["versions"]}
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
