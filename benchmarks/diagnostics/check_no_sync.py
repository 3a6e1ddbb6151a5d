"""Check on a CUDA GPU that VecTask.step and the PPO rollout loop never wait for the device.

Runs, after a warm-up, `--steps` env steps (VecTask.step with random actions) and then one full rollout
(`num_steps_per_env` steps of policy inference + env step + storage, as Runner.learn does), the returns, and, with
SyncFreePPO, every mini-batch step of the PPO update (forward, backward, learning-rate rule, Adam) under
``torch.cuda.set_sync_debug_mode("error")``, which raises on any host-device synchronisation. The periodic
host work (overflow poll every `sim.overflowCheckInterval` steps, episode statistics and the update's loss read
once per iteration) is outside that window by construction. Prints one JSON line; exits 1 on a sync.

  python benchmarks/diagnostics/check_no_sync.py --task Anymal --num_envs 4096 [--randomization full]

``--randomization full`` (benchmarks/randomization_presets.py) checks the step with every randomised quantity drawn
at each reset, an action delay, noise, pushes and the torque-speed limit.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
import traceback

import torch

from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.utils.config import compose_config, to_dict

# randomization_presets.py is a user benchmark's helper one folder up, beside throughput.py.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from randomization_presets import apply as apply_randomization  # noqa: E402


def check(task_name: str, num_envs: int, steps: int, randomization: str = "shipped") -> dict:
    if not torch.cuda.is_available():
        raise SystemExit("check_no_sync.py needs a CUDA GPU (sync debug mode is a CUDA feature)")
    cfg = compose_config([f"task={task_name}", f"num_envs={num_envs}", "sim_device=cuda:0", "rl_device=cuda:0",
                          "headless=True"])
    task = build_task(apply_randomization(cfg, randomization))
    env = RslRlVecEnv(task)
    train_cfg = rsl_rl_config(to_dict(cfg.train))
    train_cfg.pop("max_iterations"), train_cfg.pop("experiment_name", None)
    runner = Runner(env, train_cfg, log_dir=None, device=task.rl_device)
    # Compiles kernels, captures the step graphs and (second update, SyncFreePPO) the update graph,
    # allocates storage: all allowed to sync.
    runner.learn(2)
    env.stats.pop()
    # Keep the window between two periodic host checks.
    steps = min(steps, task.overflow_check_interval - 1 - task.control_steps % task.overflow_check_interval)
    result = {"task": task_name, "num_envs": num_envs, "randomization": randomization, "vectask_steps": steps,
              "rollout_steps": train_cfg["num_steps_per_env"], "ok": False}
    try:
        torch.cuda.synchronize()
        torch.cuda.set_sync_debug_mode("error")
        with torch.inference_mode():
            for _ in range(steps):
                task.step(2.0 * torch.rand(task.num_envs, task.num_actions, device=task.device) - 1.0)
            obs = env.get_observations()
            for _ in range(train_cfg["num_steps_per_env"] - 1):
                actions = runner.alg.act(obs)
                obs, rewards, dones, extras = env.step(actions)
                runner.alg.process_env_step(obs, rewards, dones, extras)
            runner.alg.compute_returns(obs)
        if hasattr(runner.alg, "run_mini_batches"):  # SyncFreePPO: every optimisation step of the update, too
            runner.alg.run_mini_batches()  # with a captured update: the graph's replay
            result["update_captured"] = runner.alg.capture_update
            result["update_mini_batches"] = runner.alg.num_learning_epochs * runner.alg.num_mini_batches
        result["ok"] = True
    except RuntimeError as err:
        result["error"] = str(err).splitlines()[0]
        result["where"] = traceback.format_exc().splitlines()[-6:]
    finally:
        torch.cuda.set_sync_debug_mode("default")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="Anymal")
    parser.add_argument("--num_envs", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--randomization", default="shipped", help="off, shipped or full")
    args = parser.parse_args()
    result = check(args.task, args.num_envs, args.steps, args.randomization)
    print(json.dumps(result), flush=True)
    sys.exit(0 if result["ok"] else 1)


if __name__ == "__main__":
    main()
