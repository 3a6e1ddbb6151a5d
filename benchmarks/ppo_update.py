"""Time one PPO update (all epochs and mini-batches) on a task's networks and batch size, without the simulator.

The rollout storage is filled with synthetic observations and rewards of the task's sizes (each observation group's
and the actions', which a 2-env build of the task reports; num_steps_per_env x num_envs samples), then `--updates`
updates are timed one by one between CUDA events after `--warmup` untimed ones (``--device cpu``: by the host clock,
single-threaded unless ``--threads``). Compares algorithm classes on identical work:

  python benchmarks/ppo_update.py --task Go1 --num_envs 4096 --algorithm SyncFreePPO --capture auto
  python benchmarks/ppo_update.py --task Go1 --num_envs 4096 --algorithm PPO

A task with image terms (CartpoleCamera) gets random 0-255 uint8 images of its camera group's shape. ``--profile N`` then profiles N more updates and prints their GPU kernels, costliest first (give
``--capture False``: a captured update shows as one graph launch). Hydra overrides go at the end.
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


def observation_groups(overrides: list[str], device: str) -> tuple[dict[str, tuple[tuple[int, ...], torch.dtype]], int]:
    """Each observation group's per-env shape and dtype, and the number of actions, from a 2-env build of the task
    (the sizes are the task's terms', as training sees them; images keep their uint8 (C, H, W))."""
    from isaacgymenvs_mw.tasks.build import build_task

    cfg = compose_config([*overrides, "num_envs=2", f"sim_device={device}", f"rl_device={device}", "headless=True"])
    task = build_task(cfg)
    obs = task.reset()
    sources = {"policy": obs["obs"]}
    if "states" in obs:  # without privileged states the critic group is the policy's tensor (see build)
        sources["critic"] = obs["states"]
    if "camera" in obs:
        sources["camera"] = obs["camera"]
    return {name: (tuple(t.shape[1:]), t.dtype) for name, t in sources.items()}, task.num_actions


def build(task: str, num_envs: int, algorithm: str, capture: str, device: str, overrides: list[str]):
    from isaacgymenvs_mw.learning.ppo import SyncFreePPO

    cfg = compose_config([f"task={task}", *overrides, f"num_envs={num_envs}"])
    train_cfg = rsl_rl_config(to_dict(cfg.train))
    train_cfg["algorithm"]["class_name"] = CLASSES[algorithm]
    if algorithm == "SyncFreePPO":
        train_cfg["algorithm"]["capture_update"] = {"auto": "auto", "True": True, "False": False}[capture]
    train_cfg["multi_gpu"] = None
    shapes, num_actions = observation_groups([f"task={task}", *overrides], device)
    groups = {name: (torch.randint(0, 256, (num_envs, *shape), dtype=dtype, device=device) if dtype == torch.uint8
                     else torch.randn(num_envs, *shape, device=device))
              for name, (shape, dtype) in shapes.items()}
    groups.setdefault("critic", groups["policy"])  # one tensor, as the env hands it (a shared trunk requires it)
    obs = TensorDict(groups, batch_size=[num_envs], device=device)
    # SyncFreePPO's construction builds either class (the one class_name names) and reads algorithm.share_trunk,
    # which rsl-rl-lib's own construction would hand to the class as an unknown argument
    alg = SyncFreePPO.construct_algorithm(obs, SizedEnv(num_envs, num_actions), train_cfg, device)
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
    parser.add_argument("--profile", type=int, default=0, help="then profile this many updates: a kernel table")
    parser.add_argument("--rows", type=int, default=25, help="kernels in the --profile table")
    parser.add_argument("--device", default="cuda:0", help="cuda:N, or cpu (small num_envs: a CPU update is slow)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads with --device cpu")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides, e.g. train.actor.cnn_precision=float32")
    args = parser.parse_args()
    device = args.device
    on_cuda = torch.device(device).type == "cuda"
    if on_cuda and not torch.cuda.is_available():
        raise SystemExit(f"--device {device}: no CUDA GPU here; give --device cpu")
    if not on_cuda:
        if args.profile:
            raise SystemExit("--profile lists GPU kernels: give a CUDA --device")
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    alg, obs, steps = build(args.task, args.num_envs, args.algorithm, args.capture, device, args.overrides)
    update_ms, host_ms, rollout_ms = [], [], []
    for i in range(args.warmup + args.updates):
        t0 = time.perf_counter()
        fill(alg, obs, steps)
        if on_cuda:
            torch.cuda.synchronize()
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
        t1 = time.perf_counter()
        alg.update()  # ends with a host read of its losses, so on the CPU the clock holds the whole update
        if on_cuda:
            end.record()
            end.synchronize()
        t2 = time.perf_counter()
        if i >= args.warmup:
            update_ms.append(start.elapsed_time(end) if on_cuda else 1e3 * (t2 - t1))
            host_ms.append(1e3 * (t2 - t1))
            rollout_ms.append(1e3 * (t1 - t0))
    if args.profile:
        profile_updates(alg, obs, steps, args.profile, args.rows)
    print(json.dumps({
        "task": args.task, "num_envs": args.num_envs, "samples_per_update": steps * args.num_envs,
        "algorithm": args.algorithm, "capture_update": getattr(alg, "capture_update", None),
        "mini_batch_steps": alg.num_learning_epochs * alg.num_mini_batches,
        "update_ms_median": statistics.median(update_ms), "update_ms_min": min(update_ms),
        "host_ms_median": statistics.median(host_ms),
        "rollout_ms_median": statistics.median(rollout_ms),  # act at every step (no simulator), then GAE
        "device": device_description(device),
        "versions": package_versions(), "date": time.strftime("%Y-%m-%d"),
    }))


def profile_updates(alg, obs: TensorDict, steps: int, updates: int, rows: int) -> None:
    """The GPU kernels of ``updates`` updates (each after a fresh rollout), per update, costliest first."""
    from torch.profiler import ProfilerActivity, profile

    totals: dict[str, list[float]] = {}
    for _ in range(updates):
        fill(alg, obs, steps)
        torch.cuda.synchronize()
        with profile(activities=[ProfilerActivity.CUDA]) as prof:
            alg.update()
            torch.cuda.synchronize()
        for event in prof.key_averages():
            if event.device_time_total > 0:
                entry = totals.setdefault(event.key, [0.0, 0.0])
                entry[0] += event.device_time_total / updates
                entry[1] += event.count / updates
    print(f"GPU kernels of one update ({sum(us for us, _ in totals.values()) / 1e3:.1f} ms in all):")
    for name, (us, count) in sorted(totals.items(), key=lambda kv: -kv[1][0])[:rows]:
        print(f"{us / 1e3:9.2f} ms {count:6.1f}x  {name[:110]}")


if __name__ == "__main__":
    main()
