"""Env-steps/s of one task, three ways, in one process on the task's own compiled model.

  (a) physics:  the task's simulator replaying its captured graph (controlFrequencyInv MuJoCo Warp steps per
                env step), nothing else, in short runs from the states that (b) reaches (see _physics_rate);
  (b) vectask:  VecTask.step with uniform random actions in [-1, 1], observations, rewards and resets included;
  (c) train:    full rsl_rl PPO iterations (rollout + update) as train.py runs them.

The ratio (b)/(a) is the framework's efficiency. Prints one JSON object.

  python benchmarks/throughput.py --task Go1 --num_envs 4096 [--sim_device cuda:0] [--train_iterations 5]
  python benchmarks/throughput.py --task Go1 --num_envs 4096 deterministic=True   # the cost of deterministic mode
"""

from __future__ import annotations

import argparse
import itertools
import json
import time

import torch

from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.learning.launch import seed_run
from isaacgymenvs_mw.learning.reporting import device_description, package_versions
from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.utils.config import compose_config, to_dict


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def _rate(fn, reps: int, num_envs: int, device: str) -> float:
    _sync(device)
    t0 = time.perf_counter()
    for _ in range(reps):
        fn()
    _sync(device)
    return num_envs * reps / (time.perf_counter() - t0)


def _physics_rate(task, advance, steps: int, chunk: int = 5, between: int = 3, work=None) -> float:
    """(a), in the states that (b) visits: runs of ``chunk`` bare physics env steps, each from a state the task
    has just reached (``between`` task steps on), after which that state is put back.

    Stepping the physics alone for hundreds of steps from wherever (b) stopped would time another workload:
    with the controls frozen, Cartpole's carts run into the rail's limits and legged robots settle or fall,
    and the solver's cost follows the contacts and constraints. On CUDA each run is timed on the GPU between two
    events, so the untimed task steps and state copies around it neither count nor leave the GPU idle. ``work``:
    what one timed env step runs instead of ``sim.simulate`` (benchmarks/render_throughput.py adds the render).
    """
    sim, cuda = task.sim, task.sim.device.type == "cuda"
    runs = max(1, steps // chunk)
    events, elapsed = [], 0.0
    for _ in range(runs):
        for _ in range(between):
            advance()
        saved = sim.save_state()
        if cuda:
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
        else:
            t0 = time.perf_counter()
        for _ in range(chunk):
            (work or sim.simulate)()
        if cuda:
            end.record()
            events.append((start, end))
        else:
            elapsed += time.perf_counter() - t0
        sim.load_state(saved)
    if cuda:
        torch.cuda.synchronize()
        elapsed = sum(start.elapsed_time(end) for start, end in events) / 1000.0
    return task.num_envs * runs * chunk / elapsed


def measure(task_name: str, num_envs: int, sim_device: str, steps: int, train_iterations: int,
            overrides: list[str]) -> dict:
    cfg = compose_config([f"task={task_name}", f"num_envs={num_envs}", f"sim_device={sim_device}",
                          f"rl_device={sim_device}", "headless=True", *overrides])
    seed_run(cfg)  # deterministic=True (a run-level override) switches torch's deterministic algorithms on too
    task = build_task(cfg)
    dev = task.sim_device
    env = RslRlVecEnv(task)  # resets every env
    # Actions drawn beforehand: (b) times VecTask.step, not the random number generator.
    actions = [2.0 * torch.rand(task.num_envs, task.num_actions, device=dev) - 1.0 for _ in range(16)]
    count = itertools.count()

    def random_step() -> None:
        task.step(actions[next(count) % len(actions)])

    # Warm-up: kernels compiled and graphs captured, and the worlds in a typical mid-episode state.
    for _ in range(50):
        random_step()
    vectask = _rate(random_step, steps, task.num_envs, dev)
    physics = _physics_rate(task, random_step, steps)

    train_cfg = rsl_rl_config(to_dict(cfg.train))
    train_cfg.pop("max_iterations"), train_cfg.pop("experiment_name", None)
    runner = Runner(env, train_cfg, log_dir=None, device=dev)
    # Warm-up: optimizer state and first allocations; SyncFreePPO runs its first update eagerly and captures its
    # update graph in the second.
    runner.learn(2)
    _sync(dev)
    t0 = time.perf_counter()
    runner.learn(train_iterations)
    _sync(dev)
    train = train_cfg["num_steps_per_env"] * task.num_envs * train_iterations / (time.perf_counter() - t0)
    return {
        "task": task_name,
        "num_envs": task.num_envs,
        "controlFrequencyInv": task.control_freq_inv,
        "physics_env_steps_per_s": physics,
        "physics_steps_per_s": physics * task.control_freq_inv,
        "vectask_env_steps_per_s": vectask,
        "train_env_steps_per_s": train,
        "ratio_vectask_over_physics": vectask / physics,
        "step_execution": task.step_execution,
        "deterministic": task.sim.deterministic,
        "device": device_description(dev),
        "versions": package_versions(),
        "date": time.strftime("%Y-%m-%d"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="Cartpole")
    parser.add_argument("--num_envs", type=int, default=4096)
    parser.add_argument("--sim_device", default="auto")
    parser.add_argument("--steps", type=int, default=300, help="timed env steps for (a) and (b)")
    parser.add_argument("--train_iterations", type=int, default=5)
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides, e.g. task.sim.iterations=2")
    args = parser.parse_args()
    print(json.dumps(measure(args.task, args.num_envs, args.sim_device, args.steps, args.train_iterations,
                             args.overrides)), flush=True)


if __name__ == "__main__":
    main()
