"""On a CUDA GPU: the step as shipped (compiled and captured, sim.compileStep / sim.captureStep) computes what the
plain eager step computes.

Builds the task twice (shipped and eager step), puts both in the same deterministic state (default pose, no
noise, pushes or randomisation, same commands), drives both with the same actions and compares rewards and resets
step by step (observations are reported: one step of GPU contact physics is not bit-deterministic).
By default (``--resync``) each step starts both twins from the same state: before every step the eager twin gets a
copy of the shipped twin's whole state (the simulator's carried state and mocap poses, and every tensor the task,
its episode, its reward terms and its randomisation layer hold: goals, targets, success counters, ...), so a step's
differences are that step's own. Free-running twins (``--no_resync``) diverge in chaotic contact-rich tasks
(AllegroHand, ShadowHand): a 1e-7 difference grows until a cube falls one step earlier in one twin, a reset mismatch
that is no bug of the step. After each step the task tensors are compared too (``state_mismatches``: a tensor the
shipped step updates differently, e.g. a counter or goal a captured replay left as it was).
``--floor`` steps a second eager twin from the same state too: what two eager steps already differ by (one step of
GPU contact physics ends at slightly different contact solutions, which moves contact forces far more than positions)
is reported as ``floor`` and not held against the shipped step; zero on the CPU.
The task metrics each step records (tasks/base/metrics.py) are compared too: a metric one twin reports and the
other does not is a mismatch (a captured step whose replays lost them). Compiled random ops draw eager's numbers
(``torch._inductor.config.fallback_random``), so both twins reset to the same states. Prints one JSON line; exits 1
on a mismatch.

  python benchmarks/diagnostics/check_step_graph.py --task Go1 --num_envs 1024 --steps 60 [--randomization fixed]
  python benchmarks/diagnostics/check_step_graph.py --task FrankaCubeLift --device cpu --num_envs 8   # compiled vs eager, no graphs

``--randomization fixed`` (benchmarks/randomization_presets.py) runs both with every randomised quantity drawn at
each reset as a single value, a one-step action delay and the torque-speed limit: the same numbers for both
whatever their random streams, with the layer's writes, inertia constants and delay buffer inside the graphs.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch
import torch._inductor.config

from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, OUTCOME, RUNNING
from isaacgymenvs_mw.utils.config import compose_config

# randomization_presets.py is a user benchmark's helper one folder up, beside throughput.py.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from randomization_presets import apply as apply_randomization  # noqa: E402

DETERMINISTIC = [
    "task.env.resetDofPosScale=[1.0,1.0]",
    "task.env.resetRootVelocityRange=0.0",
]
LEGGED = ("Anymal", "Go1")  # the tasks the overrides above apply to; others are compared from copied states as-is


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="Go1")
    parser.add_argument("--num_envs", type=int, default=1024)
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--randomization", default="off", help="off (no randomisation) or fixed")
    parser.add_argument("--reset_poses", action="store_true",
                        help="also require that the worlds a step reset hold the body and site poses of their new "
                             "qpos (tasks whose reset refreshes the kinematics: Franka cube tasks, Quadcopter, "
                             "BallBalance), i.e. that the captured step replays that refresh")
    parser.add_argument("--device", default="cuda:0", help="cuda:0 (compiled and captured) or cpu (compiled only)")
    parser.add_argument("--evaluating", action="store_true",
                        help="both twins in test mode (TaskMetrics.evaluate): the step records its test-mode metrics")
    parser.add_argument("--no_resync", dest="resync", action="store_false",
                        help="let the twins run free from the first state (chaotic tasks then diverge) instead of "
                             "giving the eager twin the shipped twin's state before each step")
    parser.add_argument("--floor", action="store_true",
                        help="also step a second eager twin from the same state each step: what two eager steps "
                             "already differ by (GPU contact physics is not bit-deterministic; nothing on the CPU) "
                             "is reported as the floor and not held against the shipped step")
    args = parser.parse_args()
    torch._inductor.config.fallback_random = True
    device = args.device
    base = [f"task={args.task}", f"num_envs={args.num_envs}", f"sim_device={device}", f"rl_device={device}",
            "headless=True", *(DETERMINISTIC if args.task in LEGGED else [])]
    preset = args.randomization if args.task != "Cartpole" else "off"
    shipped = ["+task.sim.captureStep=True"] if device.startswith("cuda") else ["+task.sim.compileStep=True"]
    graphed = build_task(apply_randomization(compose_config([*base, *shipped]), preset))
    eager_overrides = [*base, "+task.sim.captureStep=False", "+task.sim.compileStep=False"]
    twins = [graphed] + [build_task(apply_randomization(compose_config(eager_overrides), preset))
                         for _ in range(2 if args.floor else 1)]
    eager = twins[1]
    for twin in twins:
        twin.metrics.evaluate(args.evaluating)
    draws = RandomStream(device)  # tasks draw from torch's global generators: each twin gets the same numbers
    draws.run(*(twin.reset for twin in twins))
    for other in twins[1:]:
        if hasattr(graphed, "commands"):
            other.commands.copy_(graphed.commands)
        other.sim.qpos.copy_(graphed.sim.qpos)
        other.sim.qvel.copy_(graphed.sim.qvel)
    gen = torch.Generator(device=device).manual_seed(0)
    worst, floor = fresh_worst(), fresh_worst()  # shipped against eager; eager against eager (--floor)
    for _ in range(args.steps):
        a = 0.3 * (2.0 * torch.rand(graphed.num_envs, graphed.num_actions, device=device, generator=gen) - 1.0)
        if args.resync:
            for other in twins[1:]:
                copy_state(graphed, other)
        results = draws.run(*(lambda twin=twin: twin.step(a) for twin in twins))
        compare_step(graphed, eager, results[0], results[1], worst)
        if args.floor:
            compare_step(eager, twins[2], results[1], results[2], floor)
        done = results[0][2]
        if args.reset_poses and bool(done.any()):
            worst["reset_pose_error"] = max(worst.get("reset_pose_error", 0.0), reset_pose_error(graphed, done.bool()))
    # GPU contact physics is not bit-deterministic, so observations of the two runs drift apart over the steps
    # (reported); rewards, resets and the task's tensors are what must agree, beyond what two eager steps differ by.
    captured = graphed.execution.graphs is not None or not device.startswith("cuda")
    # beyond the floor: rewards and reset mismatches within 10 times what the eager twins differ by (none without it)
    ok = (captured and worst["rew"] < max(1e-3, 10.0 * floor["rew"])
          and worst["reset_mismatches"] <= 10 * floor["reset_mismatches"]
          and not worst["metric_mismatches"]
          and not [name for name in worst["state_mismatches"] if name not in floor["state_mismatches"]])
    if args.reset_poses:
        ok = ok and worst.get("reset_pose_error", float("inf")) < 1e-4  # inf: no world was reset, nothing checked
    print(json.dumps({"task": args.task, "num_envs": args.num_envs, "steps": args.steps, "randomization": preset,
                      "evaluating": args.evaluating,
                      "resync": args.resync,
                      "graph_captured": graphed.execution.graphs is not None,
                      "step_execution": [graphed.step_execution, eager.step_execution], **worst,
                      "floor": floor if args.floor else None, "ok": ok}), flush=True)
    sys.exit(0 if ok else 1)


class RandomStream:
    """Torch's global random state (CPU and, on CUDA, the device's), handed to both twins from the same point."""

    def __init__(self, device: str) -> None:
        self.cuda = device.startswith("cuda")

    def _get(self) -> tuple:
        return torch.get_rng_state(), torch.cuda.get_rng_state() if self.cuda else None

    def _set(self, state: tuple) -> None:
        torch.set_rng_state(state[0])
        if self.cuda:
            torch.cuda.set_rng_state(state[1])

    def run(self, *steps) -> list:
        """Each of ``steps`` called from the same random state; the state ends where the first left it."""
        start = self._get()
        results = [steps[0]()]
        end = self._get()
        for step in steps[1:]:
            self._set(start)
            results.append(step())
        self._set(end)
        return results


def fresh_worst() -> dict:
    """The largest differences seen so far between two twins, and the names of what differed."""
    return {"obs": 0.0, "rew": 0.0, "reset_mismatches": 0, "metrics": 0.0, "metric_mismatches": [],
            "physics": 0.0, "state": 0.0, "state_mismatches": []}


def compare_step(first, second, first_result: tuple, second_result: tuple, worst: dict) -> None:
    """One step of two twins from the same state: their observations, rewards, resets, metrics and task tensors."""
    (obs_1, rew_1, done_1, _), (obs_2, rew_2, done_2, _) = first_result, second_result
    compare_state(first, second, worst)
    worst["obs"] = max(worst["obs"], float((obs_1["obs"] - obs_2["obs"]).abs().max()))
    worst["rew"] = max(worst["rew"], float((rew_1 - rew_2).abs().max()))
    worst["reset_mismatches"] += int((done_1 != done_2).sum())
    compare_metrics(first, second, worst)


def task_tensors(task) -> dict[str, torch.Tensor]:
    """Every tensor held directly by the task, its episode, its reward terms and its randomisation layer, by name
    (the state a step carries to the next beside the simulator's; constants are included, harmlessly)."""
    randomizer = getattr(task, "randomizer", None)
    owners = {"task": task, "episode": task.episode, "rewards": getattr(task, "rewards", None),
              **{f"randomizer.{name}": part for name, part in (randomizer.parts() if randomizer else {}).items()}}
    return {f"{owner}.{name}": value for owner, obj in owners.items() if obj is not None
            for name, value in vars(obj).items() if isinstance(value, torch.Tensor)}


def mocap_tensors(task) -> dict[str, torch.Tensor]:
    """The mocap poses (goal markers): state the simulator's ``save_state`` does not carry."""
    return {"sim.mocap_pos": task.sim.mocap_pos, "sim.mocap_quat": task.sim.mocap_quat}


def sim_tensors(task) -> dict[str, torch.Tensor]:
    """The simulator's state carried from one physics step to the next, and the mocap poses."""
    return {**{f"sim.{name}": view for name, view in task.sim.save_state().items()}, **mocap_tensors(task)}


def copy_state(source, target) -> None:
    """``target`` (the eager twin) gets ``source``'s whole state, in place (the shipped twin's tensors, which its
    captured graphs read, are only read)."""
    target.sim.load_state(source.sim.save_state())
    theirs = {**task_tensors(target), **mocap_tensors(target)}
    for name, value in {**task_tensors(source), **mocap_tensors(source)}.items():
        mine = theirs.get(name)
        if mine is not None and mine.shape == value.shape and mine.dtype == value.dtype and mine is not value:
            mine.copy_(value)


def compare_state(graphed, eager, worst: dict, atol: float = 1e-3, rtol: float = 1e-3) -> None:
    """After a step from the same state: the task tensors must agree (names of those that do not are listed once in
    ``state_mismatches``; their largest difference in ``state``); the simulator's state is only reported
    (``physics``: one step of GPU contact physics is not bit-deterministic)."""
    theirs = task_tensors(eager)
    for name, value in task_tensors(graphed).items():
        other = theirs.get(name)
        if other is None or other.shape != value.shape or not value.numel():
            continue
        gap = (value.double() - other.double()).abs()
        worst["state"] = max(worst["state"], float(gap.max()))
        if bool((gap > atol + rtol * other.double().abs()).any()) and name not in worst["state_mismatches"]:
            worst["state_mismatches"].append(name)
    theirs = sim_tensors(eager)
    for name, value in sim_tensors(graphed).items():
        if value.numel():
            worst["physics"] = max(worst["physics"], float((value.double() - theirs[name].double()).abs().max()))


def compare_metrics(graphed, eager, worst: dict) -> None:
    """The metrics the twins recorded in this step: the same names (a name only one reports is listed once in
    ``metric_mismatches``), and their largest difference in ``metrics``."""
    for kind in (EPISODE_SUM, RUNNING, OUTCOME):
        mine, theirs = graphed.metrics.recorded(kind), eager.metrics.recorded(kind)
        for name in mine.keys() ^ theirs.keys():
            if f"{kind}:{name}" not in worst["metric_mismatches"]:
                worst["metric_mismatches"].append(f"{kind}:{name}")
        for name in mine.keys() & theirs.keys():
            difference = (mine[name].float() - theirs[name].float()).abs().max()
            worst["metrics"] = max(worst["metrics"], float(difference))


def reset_pose_error(task, reset: torch.Tensor) -> float:
    """How far the reset worlds' body and site positions after the step are from those of their qpos, recomputed
    eagerly now (the recompute also changes the other worlds' poses, which the next physics step recomputes)."""
    sim = task.sim
    held = sim.xpos[reset].clone(), sim.site_xpos[reset].clone()
    sim.refresh_kinematics()
    now = sim.xpos[reset], sim.site_xpos[reset]
    return max((float((a - b).abs().max()) for a, b in zip(held, now) if a.numel()), default=0.0)


if __name__ == "__main__":
    main()
