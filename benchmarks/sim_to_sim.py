"""Sim-to-sim: one legged checkpoint, one fixed command, the same start and metric in MuJoCo Warp (the task) and in
plain MuJoCo C (examples/deploy_mujoco.py on the exported policy). Prints one JSON object.

Both start from the nominal pose at rest (the deploy script's start; test mode's reset randomises it), follow the
command for ``--seconds`` without randomisation, and average |command_xy - v_xy| (base frame) and the yaw-rate error
over the steps after ``--settle`` seconds. MuJoCo C runs solved to convergence (the deploy script's default) and,
for comparison, with the task's own solver iteration limits (docs/deploy.md, "Solver iterations").

  python benchmarks/sim_to_sim.py --task Anymal --checkpoint runs/Anymal/<stamp>/model_400.pt --command 1.0 0 0
  python benchmarks/sim_to_sim.py --task Go1 --checkpoint runs/Go1/<stamp>/model_400.pt --command 0.5 0 0 \\
      --sim-device cpu
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

import isaacgymenvs_mw
from isaacgymenvs_mw.learning.export import export_policy
from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.utils.config import compose_config, to_dict

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
import deploy_mujoco  # noqa: E402


def build(task_name: str, command: tuple[float, float, float], seconds: float, device: str):
    """The task with one env, no randomisation, the fixed command and the nominal start."""
    overrides = [
        "task.task.randomize=False",
        *(f"task.env.commands.{key}=[{value},{value}]" for key, value in zip(("linVelX", "linVelY", "yawRate"),
                                                                             command)),
        "task.env.commands.minLinearCommand=0.0",  # the deploy script sends the command as given
        "task.env.resetDofPosScale=[1.0,1.0]", "task.env.resetRootVelocityRange=0.0",  # default pose, at rest
        f"task.env.episodeLength_s={seconds + 1.0}",  # no timeout reset inside the run
    ]
    return isaacgymenvs_mw.make(task_name, num_envs=1, sim_device=device, rl_device=device, overrides=overrides)


def run_warp(task, policy, env, seconds: float, settle: float) -> dict:
    steps, skip = int(round(seconds / task.control_dt)), int(round(settle / task.control_dt))
    task.reset()
    obs = env.get_observations()
    start = task.sim.root_pos[0].clone()
    lin, yaw, heights, fell = [], [], [], False
    with torch.inference_mode():
        for step in range(steps):
            obs, _, dones, _ = env.step(policy(obs))
            if bool(dones[0]):  # base contact: the episode ended (and the robot was put back)
                fell = True
                break
            heights.append(float(task.sim.root_pos[0, 2]))
            if step >= skip:
                cmd, vel, rate = task.commands[0], task.base_lin_vel[0], task.base_ang_vel[0, 2]
                lin.append(float(torch.norm(cmd[:2] - vel[:2])))
                yaw.append(abs(float(cmd[2] - rate)))
    return {"lin_vel_tracking_error": float(np.mean(lin)) if lin else None,
            "yaw_rate_tracking_error": float(np.mean(yaw)) if yaw else None, "fell": fell,
            "min_base_height": min(heights) if heights else None,
            "distance_xy": float(torch.norm(task.sim.root_pos[0, :2] - start[:2]))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", required=True, help="a legged task: Anymal, Go1")
    parser.add_argument("--checkpoint", type=Path, required=True)
    parser.add_argument("--command", type=float, nargs=3, default=(1.0, 0.0, 0.0), metavar=("VX", "VY", "YAW"))
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--settle", type=float, default=1.0)
    parser.add_argument("--sim-device", default="auto", help="MuJoCo Warp's device (auto: cuda:0 where there is one)")
    args = parser.parse_args()
    if not args.checkpoint.is_file():
        raise SystemExit(f"--checkpoint {args.checkpoint}: no such file")
    command = tuple(args.command)

    task = build(args.task, command, args.seconds, args.sim_device)
    env = RslRlVecEnv(task)
    train_cfg = rsl_rl_config(to_dict(compose_config([f"task={args.task}"]).train))
    train_cfg.pop("max_iterations"), train_cfg.pop("experiment_name", None)
    runner = Runner(env, train_cfg, log_dir=None, device=task.rl_device)
    runner.load_checkpoint(args.checkpoint, task)  # checks the policy fits the task's sizes
    policy = runner.get_inference_policy(device=task.rl_device)
    result = {"task": args.task, "checkpoint": str(args.checkpoint), "command": list(command),
              "seconds": args.seconds, "settle_s": args.settle, "start": "nominal pose at rest",
              "mujoco_warp": run_warp(task, policy, env, args.seconds, args.settle)}
    with tempfile.TemporaryDirectory() as tmp:
        export_policy(runner, Path(tmp), task=task)
        for key, trained in (("mujoco_c", False), ("mujoco_c_trained_solver", True)):
            out = deploy_mujoco.run(Path(tmp), command, args.seconds, args.settle, trained_solver=trained)
            result[key] = {k: out[k] for k in ("lin_vel_tracking_error", "yaw_rate_tracking_error", "fell",
                                               "min_base_height", "distance_xy", "solver_iterations")}
    result["device"] = str(task.sim_device)
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
