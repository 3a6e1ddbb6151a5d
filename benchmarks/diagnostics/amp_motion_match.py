"""How close does a trained AMP policy's motion come to its motion library's, feature group by group? Runs the exported
policy (test mode writes ``exported/policy.pt`` beside the checkpoint) on an AMP task, collects the current-step part
of its AMP observations after a short settling time, draws as many from the motion library, and prints one JSON
object: per group of the AMP observation (root height, root rotation, velocities, joint positions, joint speeds, key
body positions), the mean over its features of |policy mean - motion mean| / motion std, and the median of policy std
/ motion std. A policy that moves as the motions do scores near 0 and 1.

  python benchmarks/diagnostics/amp_motion_match.py --policy RUN/exported/policy.pt --num_envs 64 sim_device=cpu
"""

from __future__ import annotations

import argparse
import json

import torch


def feature_match(policy: torch.Tensor, motion: torch.Tensor, groups: list[tuple[str, int]]) -> dict[str, dict]:
    """Per named group of consecutive columns of (samples, features) ``policy`` and ``motion``: the mean standardised
    gap of the means and the median ratio of the standard deviations."""
    out, start = {}, 0
    for name, size in groups:
        p, m = policy[:, start:start + size], motion[:, start:start + size]
        spread = m.std(dim=0).clamp(min=1e-6)
        out[name] = {"features": size,
                     "mean_gap_in_motion_std": float(((p.mean(dim=0) - m.mean(dim=0)).abs() / spread).mean()),
                     "median_std_ratio": float((p.std(dim=0) / spread).median())}
        start += size
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policy", required=True, help="an exported TorchScript policy (exported/policy.pt)")
    parser.add_argument("--task", default="HumanoidAMP")
    parser.add_argument("--num_envs", type=int, default=64)
    parser.add_argument("--steps", type=int, default=300, help="policy steps to run")
    parser.add_argument("--settle", type=int, default=10, help="first steps left out (the reset's transient)")
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("overrides", nargs="*", help="sim_device=..., rl_device=..., task.env.* overrides")
    args = parser.parse_args()

    import isaacgymenvs_mw
    from isaacgymenvs_mw.tasks.amp.observations import dof_obs_size

    devices = dict(o.split("=", 1) for o in args.overrides if o.split("=", 1)[0] in ("sim_device", "rl_device"))
    rest = [o for o in args.overrides if o.split("=", 1)[0] not in devices]
    task = isaacgymenvs_mw.make(task=args.task, num_envs=args.num_envs, seed=args.seed, headless=True,
                                overrides=rest, **devices)
    policy = torch.jit.load(args.policy, map_location=task.rl_device)
    per_step = task.num_amp_obs_per_step
    obs = task.reset()["obs"]
    rows = []
    with torch.no_grad():
        for step in range(args.steps):
            obs = task.step(policy(obs).clamp(-1.0, 1.0))[0]["obs"]
            if step >= args.settle:
                rows.append(task.amp_obs[:, :per_step].clone())
    policy_obs = torch.cat(rows).cpu()
    motion_obs = task.fetch_amp_obs_demo(policy_obs.shape[0])[:, :per_step].cpu()
    groups = [("root_height", 1), ("root_rot", 6), ("root_vel", 3), ("root_ang_vel", 3),
              ("dof_obs", dof_obs_size(task.group_sizes)), ("dof_vel", task.sim.num_dof),
              ("key_body_pos", 3 * len(task.key_bodies))]
    print(json.dumps({"task": args.task, "samples": policy_obs.shape[0],
                      "groups": feature_match(policy_obs, motion_obs, groups)}, indent=1))


if __name__ == "__main__":
    main()
