"""Where the GPU time of one VecTask.step goes beyond the physics: a kernel table from torch's profiler.

The step runs uncaptured (captureStep off) so that each kernel shows up on its own, compiled as it ships on a GPU
(``--compile False`` for the plain eager step). Kernels that the bare physics (``sim.simulate``) also launches count as
physics; the others are the framework's (actions, rewards, resets, observations). Prints those sorted by GPU time
per step; then the physics kernels the step runs for longer than the bare physics does (a task's own MuJoCo Warp
passes, e.g. the kinematics refresh after a reset, launch the physics' kernels again: their surplus is the task's
cost, not the physics'); then (``--physics_rows N``) the N costliest physics kernels per env step; then one JSON
summary.

  python benchmarks/profile_step.py --task Go1 --num_envs 4096 [--compile False] [--physics_rows 20]
"""

from __future__ import annotations

import argparse
import json

import torch
from torch.profiler import ProfilerActivity, profile

from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.utils.config import compose_config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="Go1")
    parser.add_argument("--num_envs", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--rows", type=int, default=25)
    parser.add_argument("--physics_rows", type=int, default=0, help="also list the costliest physics kernels")
    parser.add_argument("--compile", choices=["True", "False"], default="True", help="sim.compileStep")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides")
    args = parser.parse_args()
    if not torch.cuda.is_available():
        raise SystemExit("profile_step.py profiles the GPU's kernels: it needs a CUDA GPU")
    cfg = compose_config([f"task={args.task}", f"num_envs={args.num_envs}", "sim_device=cuda:0", "rl_device=cuda:0",
                          "headless=True", "+task.sim.captureStep=False", f"+task.sim.compileStep={args.compile}",
                          *args.overrides])
    task = build_task(cfg)
    task.reset()
    actions = [2.0 * torch.rand(task.num_envs, task.num_actions, device=task.device) - 1.0 for _ in range(4)]
    for i in range(30):
        task.step(actions[i % 4])
    torch.cuda.synchronize()
    step_kernels = _kernels(lambda: task.step(actions[0]), args.steps)
    physics_kernels = _kernels(task.sim.simulate, args.steps)
    # A kernel the bare physics also launches (Warp's, and the memsets inside its graph) counts as physics.
    framework = {k: v for k, v in step_kernels.items() if k not in physics_kernels}
    for name, (us, count) in sorted(framework.items(), key=lambda kv: -kv[1][0])[: args.rows]:
        print(f"{us:9.1f} us/step {count:5.1f}x  {name[:110]}")
    # The step's time in a physics kernel beyond what the bare physics spends in it (launches and microseconds).
    surplus = {k: (us - physics_kernels[k][0], count - physics_kernels[k][1])
               for k, (us, count) in step_kernels.items()
               if k in physics_kernels and count - physics_kernels[k][1] > 0.5}
    if surplus:
        print("physics kernels the step launches beyond the bare physics (the task's own MuJoCo Warp passes):")
        for name, (us, count) in sorted(surplus.items(), key=lambda kv: -kv[1][0])[: args.rows]:
            print(f"{us:9.1f} us/step {count:5.1f}x  {name[:110]}")
    if args.physics_rows:
        print(f"physics ({task.control_freq_inv} MuJoCo Warp steps per env step):")
        for name, (us, count) in sorted(physics_kernels.items(), key=lambda kv: -kv[1][0])[: args.physics_rows]:
            print(f"{us:9.1f} us/step {count:5.1f}x  {name[:110]}")
    print(json.dumps({
        "task": args.task, "num_envs": args.num_envs, "step_execution": task.step_execution,
        "step_gpu_us": sum(us for us, _ in step_kernels.values()),
        "physics_gpu_us": sum(us for us, _ in physics_kernels.values()),
        "framework_gpu_us": sum(us for us, _ in framework.values()),
        "framework_kernels": sum(count for _, count in framework.values()),
        "physics_surplus_gpu_us": sum(us for us, _ in surplus.values()),
    }), flush=True)


def _kernels(fn, reps: int) -> dict[str, tuple[float, float]]:
    """GPU kernels that ``fn`` launches: name -> (microseconds per call, launches per call)."""
    with profile(activities=[ProfilerActivity.CUDA], acc_events=True) as prof:
        for _ in range(reps):
            fn()
        torch.cuda.synchronize()
    return {e.key: (e.device_time_total / reps, e.count / reps)
            for e in prof.key_averages() if e.device_time_total > 0}


if __name__ == "__main__":
    main()
