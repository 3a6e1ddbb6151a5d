"""Where do two runs with the same seed first differ? The step, bisected: physics alone, then VecTask.step.

check_deterministic.py says whether two trainings differ; this says in which part of the step they first do.

  physics   From one saved state (after ``--warmup`` random env steps, so that feet touch the ground), the carried
            state is put back and ``--steps`` physics calls run twice with the same controls; after each call
            every view of the simulator's state (qpos, qvel, qacc, contact and constraint forces, ...) is
            compared bit for bit. Reports the first call that differs, the fields that do and their largest
            absolute difference.
  vectask   Two tasks built with the same seed in this process step with the same action sequence; their
            observations, rewards and resets are compared after each step (first step that differs, which
            observation columns, largest difference).

Prints one JSON object. Run on the GPU (the CPU device runs Warp kernels serially and is deterministic):

  python benchmarks/diagnostics/determinism_bisect.py --task Go1 --sim_device cuda:0               # deterministic=True
  python benchmarks/diagnostics/determinism_bisect.py --task Go1 --sim_device cuda:0 --off         # the mode off
"""

from __future__ import annotations

import argparse
import json
import time

import torch

import isaacgymenvs_mw


def build(args, seed: int):
    return isaacgymenvs_mw.make(args.task, num_envs=args.num_envs, sim_device=args.sim_device,
                                rl_device=args.sim_device, seed=seed,
                                overrides=[f"deterministic={not args.off}", *args.overrides])


def state_views(sim) -> dict[str, torch.Tensor]:
    """Every torch view the simulator exposes of its data (float and integer tensors), by attribute name."""
    return {name: value for name, value in vars(sim).items()
            if isinstance(value, torch.Tensor) and value.shape[:1] == (sim.num_worlds,)}


def differences(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> dict[str, float]:
    """Fields that are not bit-identical, with their largest absolute difference."""
    out = {}
    for name, x in a.items():
        y = b[name]
        same = torch.equal(x, y) if not x.is_floating_point() else bool(
            ((x == y) | (torch.isnan(x) & torch.isnan(y))).all())
        if not same:
            out[name] = float((x.double() - y.double()).abs().nan_to_num(0.0).max())
    return out


def bisect_physics(args) -> dict:
    task = build(args, args.seed)
    task.reset()
    generator = torch.Generator(device=task.device).manual_seed(args.seed)
    for _ in range(args.warmup):
        task.step(2.0 * torch.rand((task.num_envs, task.num_actions), generator=generator, device=task.device) - 1.0)
    sim = task.sim
    start = sim.save_state()
    trials = []
    for _ in range(2):
        sim.load_state(start)
        frames = []
        for _ in range(args.steps):
            sim.simulate()
            frames.append({k: v.clone() for k, v in state_views(sim).items()})
        trials.append(frames)
    for k, (a, b) in enumerate(zip(*trials)):
        diff = differences(a, b)
        if diff:
            return {"identical": False, "first_differing_call": k, "fields": diff}
    return {"identical": True, "calls": args.steps}


def rng_state() -> tuple:
    return torch.get_rng_state(), torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None


def set_rng_state(state: tuple) -> None:
    torch.set_rng_state(state[0])
    if state[1] is not None:
        torch.cuda.set_rng_state_all(state[1])


def bisect_vectask(args) -> dict:
    # Each task draws from torch's global random streams: each gets its own copy of them, seeded alike.
    tasks, streams = [], []
    for _ in range(2):
        tasks.append(build(args, args.seed))
        tasks[-1].reset()
        streams.append(rng_state())
    generator = torch.Generator(device=tasks[0].device).manual_seed(args.seed)
    for k in range(args.steps):
        actions = 2.0 * torch.rand((tasks[0].num_envs, tasks[0].num_actions), generator=generator,
                                   device=tasks[0].device) - 1.0
        out = []
        for i, task in enumerate(tasks):
            set_rng_state(streams[i])
            out.append(task.step(actions.clone())[:3])
            streams[i] = rng_state()
        (obs_a, rew_a, reset_a), (obs_b, rew_b, reset_b) = out
        parts = {"obs": (obs_a["obs"], obs_b["obs"]), "rew": (rew_a, rew_b), "reset": (reset_a, reset_b)}
        diff = differences({k: v[0] for k, v in parts.items()}, {k: v[1] for k, v in parts.items()})
        if diff:
            columns = (obs_a["obs"] != obs_b["obs"]).any(dim=0).nonzero().flatten().tolist()
            layout, start, terms = tasks[0].observations.obs_layout, 0, []
            for term in (layout.terms if layout is not None else ()):  # the named terms those columns belong to
                if any(start <= c < start + term.size for c in columns):
                    terms.append(term.name)
                start += term.size
            return {"identical": False, "first_differing_step": k, "fields": diff, "obs_columns": columns[:40],
                    "obs_terms": terms, "physics_state": differences(state_views(tasks[0].sim),
                                                                     state_views(tasks[1].sim))}
    return {"identical": True, "steps": args.steps}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="Go1")
    parser.add_argument("--num_envs", type=int, default=4096)
    parser.add_argument("--sim_device", default="cuda:0")
    parser.add_argument("--seed", type=int, default=42)
    parser.add_argument("--warmup", type=int, default=50, help="random env steps before the physics comparison")
    parser.add_argument("--steps", type=int, default=100, help="physics calls / env steps compared")
    parser.add_argument("--off", action="store_true", help="deterministic=False")
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. task.sim.iterations=4")
    args = parser.parse_args()
    started = time.perf_counter()
    result = {"task": args.task, "num_envs": args.num_envs, "deterministic": not args.off,
              "physics": bisect_physics(args), "vectask": bisect_vectask(args),
              "seconds": round(time.perf_counter() - started, 1), "torch": torch.__version__,
              "date": time.strftime("%Y-%m-%d")}
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
