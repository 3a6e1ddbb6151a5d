"""How a trained policy moves through the terrain curriculum in one episode: levels up, levels down, falls.

Runs an exported policy (``<run>/exported/policy.pt``, written by test mode) for one episode length on a terrain
task in training mode (curriculum on, envs starting at levels 0..maxInitLevel) and counts the curriculum's moves at
each reset. Comparing task settings with the same policy shows what the settings do to the curriculum without
training anything, e.g. heading commands against random yaw rates:

  python benchmarks/diagnostics/curriculum_moves.py --policy <run>/exported/policy.pt --num_envs 128
  python benchmarks/diagnostics/curriculum_moves.py --policy <run>/exported/policy.pt --num_envs 128 \\
      --override "~task.env.commands.heading"
"""

from __future__ import annotations

import argparse
import json
import time

import torch

import isaacgymenvs_mw


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policy", required=True, help="TorchScript policy exported by test mode (policy.pt)")
    parser.add_argument("--task", default="AnymalTerrain")
    parser.add_argument("--num_envs", type=int, default=128)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--override", action="append", default=[], help="a Hydra override of the task (repeatable)")
    args = parser.parse_args()

    task = isaacgymenvs_mw.make(args.task, num_envs=args.num_envs, sim_device=args.device, rl_device=args.device,
                                headless=True, seed=args.seed, overrides=args.override)
    if getattr(task.ground, "terrain_levels", None) is None:
        raise SystemExit(f"--task {args.task} has no terrain curriculum (env.terrain.type must be heightfield)")
    policy = torch.jit.load(args.policy, map_location=args.device)
    obs = task.reset()["obs"]
    start = task.ground.terrain_levels.clone()
    levels = start.clone()
    ups = downs = falls = 0
    began = time.perf_counter()
    for _ in range(int(task.max_episode_length)):
        with torch.no_grad():
            obs_dict, _, reset, extras = task.step(policy(obs))
        obs = obs_dict["obs"]
        reset = reset.bool()
        now = task.ground.terrain_levels
        ups += int(((now > levels) & reset).sum())
        downs += int(((now < levels) & reset).sum())
        falls += int((reset & ~extras["time_outs"].bool()).sum())
        levels = now.clone()
    print(json.dumps({
        "task": args.task, "num_envs": args.num_envs, "seed": args.seed, "overrides": args.override,
        "mean_level_start": round(float(start.float().mean()), 3),
        "mean_level_end": round(float(levels.float().mean()), 3),
        "moved_up": ups, "moved_down": downs, "falls": falls,
        "seconds": round(time.perf_counter() - began, 1),
    }))
    task.close()


if __name__ == "__main__":
    main()
