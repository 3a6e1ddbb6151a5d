"""A blown-up world during training, replayed on any device with the step as training runs it (compiled and
captured on CUDA), and where its NaN/inf went.

Between env steps (outside the captured graphs, as a real blow-up appears between two physics calls) world 0's arm
joint speeds are set to inf at env step ``--inf_at`` and to 1e20 at ``--huge_at``. For the next ``--watch`` steps the
script reads, in that world, which of these hold non-finite values: the simulator state (qpos, qvel), the body
poses the tasks read (xpos), the observation and privileged state the task computed before VecTask's guard
(obs_buf, states_buf), the reward (rew_buf), and what the learner receives. The run's summary then says what each
defence caught: worlds reset for a blow-up, observations/rewards replaced, optimiser steps skipped, learner states
restored, and whether every value loss and weight stayed finite.

  python benchmarks/diagnostics/nan_injection.py --sim_device cuda:0 --num_envs 4096 --iterations 60
  python benchmarks/diagnostics/nan_injection.py --sim_device cpu --num_envs 64 --iterations 6          (the CPU reference)

Prints one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
from pathlib import Path

import torch

from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.utils.config import compose_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="FrankaCubeLift")
    parser.add_argument("--sim_device", default="cuda:0")
    parser.add_argument("--num_envs", type=int, default=4096)
    parser.add_argument("--iterations", type=int, default=60)
    parser.add_argument("--inf_at", type=int, default=40)
    parser.add_argument("--huge_at", type=int, default=80)
    parser.add_argument("--watch", type=int, default=3, help="env steps after each injection to inspect")
    parser.add_argument("--joints", type=int, default=7, help="the first N dofs of world 0 are blown up")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. seed=2")
    args = parser.parse_args()

    seen: list[dict] = []
    step = VecTask.step

    def inspected_step(self: VecTask, actions: torch.Tensor):
        n = self.control_steps
        if n == args.inf_at:
            self.sim.qvel[0, :args.joints] = float("inf")
        elif n == args.huge_at:
            self.sim.qvel[0, :args.joints] = 1.0e20
        out = step(self, actions)
        if any(0 <= n - at < args.watch for at in (args.inf_at, args.huge_at)):
            obs_dict, rew, _, extras = out
            bad = {name: not bool(torch.isfinite(t[0]).all()) for name, t in (
                ("qpos", self.sim.qpos), ("qvel", self.sim.qvel), ("xpos", self.sim.xpos),
                ("obs_buf", self.obs_buf), ("states_buf", self.states_buf), ("rew_buf", self.rew_buf),
                ("learner_obs", obs_dict["obs"]), ("learner_states", obs_dict.get("states", obs_dict["obs"])),
                ("learner_reward", rew))}
            seen.append({"env_step": n, "reset_for_blow_up": bool(extras["nonfinite_resets"][0]),
                         "replaced_inputs": bool(extras["nonfinite_inputs"][0]),
                         "nonfinite": [k for k, v in bad.items() if v]})
        return out

    VecTask.step = inspected_step
    with tempfile.TemporaryDirectory() as runs:
        cfg = compose_config([f"task={args.task}", f"num_envs={args.num_envs}", f"max_iterations={args.iterations}",
                              f"sim_device={args.sim_device}", f"rl_device={args.sim_device}", "headless=True",
                              f"runs_dir={runs}", *args.overrides])
        summary = run(cfg)
        final = torch.load(Path(summary["run_dir"]) / f"model_{summary['final_iteration']}.pt", weights_only=False,
                           map_location="cpu")
    weights_finite = all(bool(torch.isfinite(v).all()) for group in ("actor_state_dict", "critic_state_dict")
                         for v in final[group].values() if v.is_floating_point())
    value_losses = [h["losses"]["value"] for h in summary["history"]]
    print(json.dumps({
        "task": args.task, "device": summary["device"], "num_envs": args.num_envs,
        "after_injection": seen,
        "nonfinite_resets": summary["nonfinite_resets"], "nonfinite_inputs": summary["nonfinite_inputs"],
        "skipped_optimizer_steps": summary["skipped_optimizer_steps"], "learner_restores": summary["learner_restores"],
        "value_losses_finite": all(math.isfinite(v) for v in value_losses), "max_value_loss": max(value_losses),
        "weights_finite": weights_finite, "versions": summary["versions"],
    }))


if __name__ == "__main__":
    main()
