"""The post-physics step of each task is one graph for torch.compile (sim.compileStep on CUDA).

A graph break makes the compiled step several graphs with Python between them, each a return to the host (slower),
and the step cannot be compiled ahead, alongside Warp's kernels (StepExecution). Breaks do not depend on the device,
so they are found here on the CPU with a few envs, by tracing the step with torch._dynamo.explain (no code generation:
seconds per task); benchmarks/check_graph_breaks.py prints where a step breaks.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from check_graph_breaks import TASKS, break_lines, explain_step  # noqa: E402


@pytest.mark.parametrize("task", TASKS)
def test_the_post_physics_step_is_one_graph(task):
    explanation = explain_step(task, num_envs=4)
    assert (explanation.graph_count, explanation.graph_break_count) == (1, 0), "\n".join(break_lines(explanation))
