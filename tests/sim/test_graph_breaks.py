"""The post-physics step of each task is one graph for torch.compile (sim.compileStep on CUDA).

A graph break makes the compiled step several graphs with Python between them, each a return to the host (slower),
and the step cannot be compiled ahead, alongside Warp's kernels (StepExecution). Breaks do not depend on the device,
so they are found here on the CPU with a few envs, by tracing the step with torch._dynamo.explain (no code generation:
seconds per task); benchmarks/diagnostics/check_graph_breaks.py prints where a step breaks.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks" / "diagnostics"))
from check_graph_breaks import TASKS, break_lines, explain_step  # noqa: E402


@pytest.mark.parametrize("task", TASKS)
def test_the_post_physics_step_is_one_graph(task):
    explanation = explain_step(task, num_envs=4)
    assert (explanation.graph_count, explanation.graph_break_count) == (1, 0), "\n".join(break_lines(explanation))


def _output_count(explanation) -> int:
    output = next(node for node in explanation.graphs[0].graph.nodes if node.op == "output")
    return len(output.args[0])


@pytest.mark.parametrize("task", ["Go1", "Quadcopter", "Ant"])  # the tasks that record more metrics in test mode
def test_test_mode_metrics_add_no_outputs_to_the_step(task):
    # Metrics are copied into buffers that exist before the step (TaskMetrics), so the test-mode step is the training
    # step's graph with more writes, not more outputs. On the GPU, Quadcopter's captured test mode lost a fifth of
    # its episodes, and only with its test-mode metrics recorded; their extra graph outputs were the one difference
    # found in its compiled step (4 x H200, 2026-11-26).
    training, testing = explain_step(task, num_envs=4), explain_step(task, num_envs=4, evaluating=True)
    assert testing.graph_count == 1
    assert _output_count(testing) == _output_count(training)
