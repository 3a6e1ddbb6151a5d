"""Camera rendering throughput: MuJoCo Warp's batch renderer alone and inside VecTask.step, one JSON row per
(num_envs, outputs), on a task with a camera (default CartpoleCamera, its camera ``front`` resized).

Each row, for the task built with ``env.cameras.<camera>.outputs`` = the row's outputs (rgb, depth or both) and the
image terms to match:
  render_frames_per_s          Simulator.render_cameras() alone (poses, BVH refit, render, unpack: one graph replay
                               on CUDA), world-frames per second (a frame = every camera of one world)
  physics_env_steps_per_s      the task's physics alone (throughput.py's (a))
  physics_render_env_steps_per_s  physics then render, per env step, timed the same way
  vectask_env_steps_per_s      VecTask.step with random actions: physics, the task's terms, resets, render, images
  ratio_vectask_over_physics_render   the framework's efficiency with a camera (target >= 0.8)
  image_bytes_per_env, rollout_storage_mb_per_1000_envs   the "camera" group a step returns (uint8, frames stacked)
                               and what rsl_rl's rollout storage keeps of it per 1000 envs (num_steps_per_env steps)

  python benchmarks/render_throughput.py --num_envs 4096 8192 --width 64 --height 64 [--sim_device cuda:0]
  python benchmarks/render_throughput.py --num_envs 4096 --outputs rgb depth rgb,depth task.env.history.camera.length=1
"""

from __future__ import annotations

import argparse
import itertools
import json
import time

import torch
from throughput import _physics_rate, _rate

from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.learning.launch import seed_run
from isaacgymenvs_mw.learning.reporting import device_description, package_versions
from isaacgymenvs_mw.utils.config import compose_config


def measure(task_name: str, camera: str, num_envs: int, width: int, height: int, outputs: list[str],
            sim_device: str, steps: int, overrides: list[str]) -> dict:
    key = f"task.env.cameras.{camera}"
    cfg = compose_config([f"task={task_name}", f"num_envs={num_envs}", f"sim_device={sim_device}",
                          f"rl_device={sim_device}", "headless=True", f"{key}.width={width}", f"{key}.height={height}",
                          f"{key}.outputs=[{','.join(outputs)}]", *overrides])
    seed_run(cfg)
    task = build_task(cfg)
    dev, sim = task.sim_device, task.sim
    task.reset()
    actions = [2.0 * torch.rand(task.num_envs, task.num_actions, device=dev) - 1.0 for _ in range(16)]
    count = itertools.count()

    def random_step() -> None:
        task.step(actions[next(count) % len(actions)])

    def physics_and_render() -> None:
        sim.simulate()
        sim.render_cameras()

    for _ in range(50):  # warm-up: kernels compiled, graphs captured, worlds mid-episode
        random_step()
    vectask = _rate(random_step, steps, task.num_envs, dev)
    render = _rate(sim.render_cameras, steps, task.num_envs, dev)
    physics = _physics_rate(task, random_step, steps)
    physics_render = _physics_rate(task, random_step, steps, work=physics_and_render)
    image_bytes = int(torch.Size(task.observations.image_shape).numel())
    steps_per_env = int(cfg.train.runner.num_steps_per_env)
    return {
        "task": task_name,
        "num_envs": task.num_envs,
        "camera": f"{width}x{height}",
        "outputs": outputs,
        "image_shape": list(task.observations.image_shape),
        "render_frames_per_s": render,
        "physics_env_steps_per_s": physics,
        "physics_render_env_steps_per_s": physics_render,
        "vectask_env_steps_per_s": vectask,
        "ratio_vectask_over_physics_render": vectask / physics_render,
        "image_bytes_per_env": image_bytes,
        "rollout_storage_mb_per_1000_envs": steps_per_env * 1000 * image_bytes / 1e6,
        "max_memory_allocated_gb": torch.cuda.max_memory_allocated() / 1e9 if dev.startswith("cuda") else None,
        "step_execution": task.step_execution,
        "device": device_description(dev),
        "versions": package_versions(),
        "date": time.strftime("%Y-%m-%d"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="CartpoleCamera")
    parser.add_argument("--camera", default="front", help="the env.cameras entry to resize")
    parser.add_argument("--num_envs", type=int, nargs="+", default=[4096, 8192])
    parser.add_argument("--width", type=int, default=64)
    parser.add_argument("--height", type=int, default=64)
    parser.add_argument("--outputs", nargs="+", default=["rgb", "depth", "rgb,depth"],
                        help="one row per entry: comma-separated camera outputs")
    parser.add_argument("--sim_device", default="auto")
    parser.add_argument("--steps", type=int, default=200, help="timed env steps or renders per measurement")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides")
    args = parser.parse_args()
    for num_envs in args.num_envs:
        for outputs in args.outputs:
            row = measure(args.task, args.camera, num_envs, args.width, args.height, outputs.split(","),
                          args.sim_device, args.steps, args.overrides)
            print(json.dumps(row), flush=True)
            if args.sim_device != "cpu" and torch.cuda.is_available():
                torch.cuda.empty_cache()
                torch.cuda.reset_peak_memory_stats()


if __name__ == "__main__":
    main()
