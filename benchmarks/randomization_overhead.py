"""Step rate with the randomisation layer off, as shipped, and with everything on (benchmarks/randomization_presets.py).

For each preset, in one process: (a) the bare physics rate and (b) VecTask.step's rate, as benchmarks/throughput.py
measures them, and the overhead of (b) against the preset `off`. Prints one JSON object.

  python benchmarks/randomization_overhead.py --task Go1 --num_envs 4096 --presets off shipped full
"""

from __future__ import annotations

import argparse
import itertools
import json
import time

import torch

from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.learning.reporting import device_description, package_versions
from isaacgymenvs_mw.utils.config import compose_config
from randomization_presets import PRESETS, apply
from throughput import _physics_rate, _rate


def measure(task_name: str, num_envs: int, sim_device: str, steps: int, preset: str) -> dict:
    cfg = compose_config([f"task={task_name}", f"num_envs={num_envs}", f"sim_device={sim_device}",
                          f"rl_device={sim_device}", "headless=True"])
    task = build_task(apply(cfg, preset))
    task.reset()
    actions = [2.0 * torch.rand(task.num_envs, task.num_actions, device=task.device) - 1.0 for _ in range(16)]
    count = itertools.count()

    def random_step() -> None:
        task.step(actions[next(count) % len(actions)])

    for _ in range(50):  # compiled, captured, mid-episode
        random_step()
    vectask = _rate(random_step, steps, task.num_envs, task.sim_device)
    physics = _physics_rate(task, random_step, steps)
    out = {"preset": preset, "physics_env_steps_per_s": physics, "vectask_env_steps_per_s": vectask,
           "ratio_vectask_over_physics": vectask / physics, "step_execution": task.step_execution,
           "per_world_fields": sorted(task.randomizer.per_world_fields())}
    task.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="Go1")
    parser.add_argument("--num_envs", type=int, default=4096)
    parser.add_argument("--sim_device", default="cuda:0")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--presets", nargs="+", default=["off", "shipped", "full"], choices=PRESETS)
    args = parser.parse_args()
    rows = [measure(args.task, args.num_envs, args.sim_device, args.steps, p) for p in args.presets]
    base = next((r for r in rows if r["preset"] == "off"), None)
    if base is not None:
        for r in rows:
            r["vectask_overhead_vs_off"] = base["vectask_env_steps_per_s"] / r["vectask_env_steps_per_s"] - 1.0
    print(json.dumps({"task": args.task, "num_envs": args.num_envs, "rows": rows,
                      "device": device_description(args.sim_device), "versions": package_versions(),
                      "date": time.strftime("%Y-%m-%d")}), flush=True)


if __name__ == "__main__":
    main()
