"""Count the graphs torch.compile makes of a task's post-physics step, and say where and why it breaks.

On CUDA, VecTask compiles the post-physics step (``VecTask._after_physics``, ``sim.compileStep``) as one graph;
a step with a graph break is compiled as several, each break a return to Python between them (slower). Graph
breaks do not depend on the device, so this finds them on the CPU with a few envs: it builds the task, resets it,
runs one step's pre-physics and physics phases as VecTask.step does, and traces the post-physics step with
``torch._dynamo.explain`` (tracing only, no Inductor code generation: seconds per task). Prints, per task, the number
of graphs and each break's reason with its source line; exits 1 when a task's step is not one graph.

  python benchmarks/diagnostics/check_graph_breaks.py Quadcopter BallBalance [--num_envs 4]
  python benchmarks/diagnostics/check_graph_breaks.py            # the tasks listed in TASKS
"""

from __future__ import annotations

import argparse
import os
import sys

import torch
import torch._dynamo

import isaacgymenvs_mw
from isaacgymenvs_mw.tasks.base.step_execution import _with_own_code, fresh_dict

PROJECT = os.path.dirname(os.path.dirname(os.path.abspath(isaacgymenvs_mw.__file__)))
TASKS = ("Go1", "Anymal", "Cartpole", "Quadcopter", "BallBalance", "FrankaCubeLift", "FrankaCubeStack",
         "FrankaCubeLiftDepth", "AllegroHand", "ShadowHand", "FrankaCabinet")


def explain_step(task_name: str, num_envs: int = 4, evaluating: bool = False):
    """torch._dynamo.explain's result for ``task_name``'s post-physics step, traced in the state of a first step
    (``evaluating``: in test mode, where tasks record more metrics)."""
    task = isaacgymenvs_mw.make(task_name, num_envs=num_envs, sim_device="cpu", rl_device="cpu", headless=True,
                                seed=0)
    task.metrics.evaluate(evaluating)
    task.reset()
    torch._dynamo.reset()
    task.metrics.begin_step()
    with fresh_dict(task, "extras"):  # the dict the compiled step writes into (VecTask.step)
        task.execution.before(torch.zeros(num_envs, task.num_actions))
        task.execution.physics()
        # The framework compiles a copy of the step with its own code object (_CompiledStep): trace the same.
        return torch._dynamo.explain(_with_own_code(task._after_physics))()


def break_lines(explanation) -> list[str]:
    """Per graph break: its reason, then the source lines that led to it, innermost first (the project's frames, and
    the innermost frame where that is outside the project)."""
    lines = []
    for brk in explanation.break_reasons:
        frames = list(reversed(brk.user_stack))
        shown = [f for i, f in enumerate(frames) if i == 0 or PROJECT in f.filename][:4]
        lines.append(brk.reason.strip().splitlines()[0][:300])
        lines += [f"    at {f.filename}:{f.lineno}  {(f.line or '').strip()}" for f in shown]
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("tasks", nargs="*", default=list(TASKS))
    parser.add_argument("--num_envs", type=int, default=4)
    args = parser.parse_args()
    broken = []
    for name in args.tasks:
        explanation = explain_step(name, args.num_envs)
        print(f"{name}: {explanation.graph_count} graph(s), {explanation.graph_break_count} break(s)", flush=True)
        for line in break_lines(explanation):
            print(f"    {line}", flush=True)
        if explanation.graph_count != 1 or explanation.graph_break_count:
            broken.append(name)
    if broken:
        print(f"not one graph: {', '.join(broken)}")
    sys.exit(1 if broken else 0)


if __name__ == "__main__":
    main()
