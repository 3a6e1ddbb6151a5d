"""Time one PPO update (all epochs and mini-batches) on a task's networks and batch size, without the simulator.

The rollout storage is filled with synthetic observations and rewards of the task's sizes (numObservations,
numStates, numActions, num_steps_per_env x num_envs), then `--updates` updates are timed one by one between CUDA
events after `--warmup` untimed ones. Compares algorithm classes on identical work:

  python benchmarks/ppo_update.py --task Go1 --num_envs 4096 --algorithm SyncFreePPO --capture auto
  python benchmarks/ppo_update.py --task Go1 --num_envs 4096 --algorithm PPO
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch
from tensordict import TensorDict

from isaacgymenvs_mw.learning.reporting import device_description, package_versions
from isaacgymenvs_mw.learning.runner import rsl_rl_config
from isaacgymenvs_mw.utils.config import compose_config, to_dict

CLASSES = {"PPO": "PPO", "SyncFreePPO": "isaacgymenvs_mw.learning.ppo:SyncFreePPO"}


class SizedEnv:
    def __init__(self, num_envs: int, num_actions: int) -> None:
        self.num_envs, self.num_actions = num_envs, num_actions


def build(task: str, num_envs: int, algorithm: str, capture: str, device: str):
    from rsl_rl.algorithms import PPO

    cfg = compose_config([f"task={task}", f"num_envs={num_envs}"])
    env_cfg = cfg.task.env
    train_cfg = rsl_rl_config(to_dict(cfg.train))
    train_cfg["algorithm"]["class_name"] = CLASSES[algorithm]
    if algorithm == "SyncFreePPO":
        train_cfg["algorithm"]["capture_update"] = {"auto": "auto", "True": True, "False": False}[capture]
    train_cfg["multi_gpu"] = None
    num_states = int(env_cfg.get("numStates", 0)) or int(env_cfg.numObservations)
    obs = TensorDict({"policy": torch.randn(num_envs, int(env_cfg.numObservations), device=device),
                      "critic": torch.randn(num_envs, num_states, device=device)}, batch_size=[num_envs], device=device)
    alg = PPO.construct_algorithm(obs, SizedEnv(num_envs, int(env_cfg.numActions)), train_cfg, device)
    return alg, obs, train_cfg["num_steps_per_env"]


def fill(alg, obs: TensorDict, steps: int) -> None:
    with torch.inference_mode():
        for _ in range(steps):
            actions = alg.act(obs)
            rewards = -actions.square().sum(dim=1)
            dones = (torch.rand_like(rewards) < 0.005).float()
            alg.process_env_step(obs, rewards, dones, {"time_outs": torch.zeros_like(dones)})
        alg.compute_returns(obs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="Go1")
    parser.add_argument("--num_envs", type=int, default=4096)
    parser.add_argument("--algorithm", choices=sorted(CLASSES), default="SyncFreePPO")
    parser.add_argument("--capture", choices=["auto", "True", "False"], default="auto",
                        help="SyncFreePPO's train.algorithm.capture_update")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--updates", type=int, default=20)
    args = parser.parse_args()
    if not torch.cuda.is_available():
        raise SystemExit("ppo_update.py times the update on a CUDA GPU")
    device = "cuda:0"
    torch.manual_seed(0)
    alg, obs, steps = build(args.task, args.num_envs, args.algorithm, args.capture, device)
    gpu_ms, host_ms = [], []
    for i in range(args.warmup + args.updates):
        fill(alg, obs, steps)
        torch.cuda.synchronize()
        start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        t0 = time.perf_counter()
        start.record()
        alg.update()
        end.record()
        end.synchronize()
        if i >= args.warmup:
            gpu_ms.append(start.elapsed_time(end))
            host_ms.append(1e3 * (time.perf_counter() - t0))
    print(json.dumps({
        "task": args.task, "num_envs": args.num_envs, "samples_per_update": steps * args.num_envs,
        "algorithm": args.algorithm, "capture_update": getattr(alg, "capture_update", None),
        "mini_batch_steps": alg.num_learning_epochs * alg.num_mini_batches,
        "update_ms_median": statistics.median(gpu_ms), "update_ms_min": min(gpu_ms),
        "host_ms_median": statistics.median(host_ms), "device": device_description(device),
        "versions": package_versions(), "date": time.strftime("%Y-%m-%d"),
    }))


if __name__ == "__main__":
    main()
