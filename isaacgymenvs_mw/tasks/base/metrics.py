"""Task metrics: what a task reports beyond its reward, declared as objects and recorded by them.

A task lists its metrics in ``VecTask.declared_metrics()`` (``Metric(name, kind)``) and records their values in its
step with ``self.metrics.record(metric, value)``; ``learning/`` reads them by kind (``TaskMetrics.recorded``), never
by name, and logs each under its own name. The kinds (``METRIC_KINDS``):

* ``EPISODE_SUM``: a device scalar, the sum over the episodes that ended in this step (recorded at their reset).
  Training logs ``Episode/<name>`` (TensorBoard, the progress line, summary.json and its history), the sum divided
  by the number of episodes that ended (the terrain tasks' ``terrain_level``).
* ``RUNNING``: a device scalar the task keeps (AllegroHand's ``consecutive_successes`` running average); training logs
  ``Episode/<name>`` at its value when the iteration's statistics are read.
* ``OUTCOME``: (num_envs,), the value of each episode that ends in this step (0 elsewhere); test mode writes ``<name>``
  in eval.json, the mean over the envs of how each one's first episode ended (a task's success flag).
* ``PER_STEP``: (num_envs,), each step, while ``evaluating`` (test mode); eval.json ``<name>``, the per-step values
  averaged over each env's first episode (the legged tasks' velocity tracking error).

``success=True`` marks a metric that says how well the task meets its goal, higher being better: a success rate, IGE's
consecutive successes, the terrain curriculum's level (the terrain tasks' target). ``save_best`` and sweeps follow the
first such ``EPISODE_SUM`` or ``RUNNING`` metric (``sweep_metric=auto``, learning/best_checkpoint.py); a task without
one is followed by its episode reward. A ``PER_STEP`` metric cannot be one (it is test mode's, often an error).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import torch

EPISODE_SUM, RUNNING, OUTCOME, PER_STEP = "episode_sum", "running", "outcome", "per_step"
METRIC_KINDS = (EPISODE_SUM, RUNNING, OUTCOME, PER_STEP)


@dataclass(frozen=True)
class Metric:
    """One metric a task reports: its name in the logs, its kind and whether it measures the task's success (module
    docstring)."""

    name: str
    kind: str
    success: bool = False

    def __post_init__(self) -> None:
        if self.kind not in METRIC_KINDS:
            raise ValueError(f"Metric {self.name!r}: kind {self.kind!r}; valid: {', '.join(METRIC_KINDS)}")
        if self.success and self.kind == PER_STEP:
            raise ValueError(f"Metric {self.name!r}: success=True needs a kind of {EPISODE_SUM}, {RUNNING} or "
                             f"{OUTCOME}, not {PER_STEP}")


# VecTask's, for a task with ``reports_success``: the rate over ended episodes (Episode/success) and each env's first
# episode's success (eval.json "success").
SUCCESS_RATE = Metric("success", EPISODE_SUM, success=True)
SUCCESS = Metric("success", OUTCOME, success=True)


class TaskMetrics:
    """The metrics a task declares (``declare``: its ``declared_metrics`` hook, read once, outside the step) and the
    values recorded in the current step. ``evaluating``: test mode is on (``PER_STEP`` metrics are wanted).

    Each declared metric has one buffer for the run, made with the declarations (a device scalar, or one value per
    env), and ``record`` copies into it: a compiled step writes its metrics into tensors that exist before it, as it
    writes its other buffers, so recording adds no outputs to its graph, and test mode (which records more) runs the
    same kind of captured step as training."""

    def __init__(self, declare: Callable[[], Sequence[Metric]], num_envs: int, device: str | torch.device) -> None:
        self._declare = declare
        self._num_envs, self._device = num_envs, device
        self._declared: tuple[Metric, ...] | None = None
        self._keys: frozenset[tuple[str, str]] = frozenset()
        self._buffers: dict[tuple[str, str], torch.Tensor] = {}
        self.evaluating = False
        self.values: dict[tuple[str, str], torch.Tensor] = {}
        self._replayed: dict[tuple[str, str], torch.Tensor] = {}  # recorded while the step was captured

    @property
    def declared(self) -> tuple[Metric, ...]:
        self._declared_keys()
        return self._declared

    def _declared_keys(self) -> frozenset[tuple[str, str]]:
        """(kind, name) of every declared metric; the task's hook is read the first time."""
        if self._declared is None:
            declared = tuple(self._declare())
            self._keys = frozenset((m.kind, m.name) for m in declared)
            if len(self._keys) < len(declared):
                raise ValueError(f"declared_metrics: a (name, kind) appears twice in {declared}")
            per_env = (OUTCOME, PER_STEP)
            self._buffers = {(m.kind, m.name): torch.zeros((self._num_envs,) if m.kind in per_env else (),
                                                           device=self._device) for m in declared}
            self._declared = declared
        return self._keys

    def evaluate(self, on: bool = True) -> None:
        """Test mode (``learning/evaluation.evaluate``): the task records its ``PER_STEP`` metrics from now on."""
        self.evaluating = on

    def begin_step(self, replay: bool = False) -> None:
        """A step (or a reset) records into an empty mapping, made outside the compiled step: torch.compile guards
        on the entries of a dict the compiled code writes into, and an empty one is the same every step. The
        declarations are read here the first time, never inside the compiled step.

        ``replay``: the step replays captured CUDA graphs, which run no Python and record nothing; they rewrite in
        place the buffers recorded into while the step was captured (``hold_for_replays``), so those are its values."""
        self._declared_keys()
        self.values = dict(self._replayed) if replay else {}

    def hold_for_replays(self) -> None:
        """The step just recorded was captured: its replays report the tensors it recorded."""
        self._replayed = dict(self.values)

    def record(self, metric: Metric, value: torch.Tensor) -> None:
        """``metric``'s value in this step (its kind says the shape)."""
        key = (metric.kind, metric.name)
        if key not in self._declared_keys():
            raise ValueError(f"metrics.record: {metric} is not among the task's declared_metrics()")
        buffer = self._buffers[key]
        buffer.copy_(value)
        self.values[key] = buffer

    def record_successes(self, succeeded: torch.Tensor) -> None:
        """VecTask's SUCCESS_RATE and SUCCESS of the episodes that end in this step, ``succeeded`` ((num_envs,) bool)
        marking those that ended by reaching the goal."""
        success = succeeded.float()
        self.record(SUCCESS_RATE, success.sum())
        self.record(SUCCESS, success)

    def recorded(self, kind: str) -> dict[str, torch.Tensor]:
        """{name: value} of the metrics of ``kind`` recorded in the last step, in the order they were recorded."""
        return {name: value for (k, name), value in self.values.items() if k == kind}

    def names(self, kind: str) -> list[str]:
        """The declared metrics of ``kind``, in declaration order."""
        return [m.name for m in self.declared if m.kind == kind]
