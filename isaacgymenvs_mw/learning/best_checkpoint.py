"""``save_best``: which metric a run's best checkpoint follows, how its value is smoothed, and the copy it keeps.

The metric (run key ``sweep_metric``, which a sweep compares too) is chosen once for a run:

* a name the user gives (``sweep_metric=timeout_fraction``, ``sweep_metric=success``): "user choice";
* ``auto``: the task's declared success metric (``Metric(..., success=True)``, or the task's ``primary_metric`` where
  its success is one of the run's own statistics, BallBalance's ``timeout_fraction``): "declared success metric";
* ``auto`` for a task that declares none: the mean episode reward, "episode reward".

A task's success decides where it has one because reward and goal can part: Quadcopter's reward pays 1 / (1 + d²) for
a distance d to the target, 99 % of its maximum at the 0.1 m that counts as reaching it, and a policy that hovers just
outside earns nearly as much per episode as one that reaches it.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from isaacgymenvs_mw.utils.files import atomic_save

SMOOTHING = 10  # iterations averaged into one value of the metric (the best checkpoint's, the sweep's final and best)
METRIC_PREFIX = "Episode/"  # where a task's declared metrics live in a run's history (learning/vecenv.py)
BEST_CHECKPOINT = "model_best.pt"  # save_best's copy of the best saved checkpoint, in the run folder
REWARD = "mean_episode_reward"

# Why the metric was chosen, as summary.json's best_checkpoint "chosen_by" says it.
USER_CHOICE, DECLARED_SUCCESS, EPISODE_REWARD = "user choice", "declared success metric", "episode reward"


def metric_key(history: list[dict], metric: str, success: str | None) -> str:
    """The history key of ``metric``: with ``auto``, ``success`` (the task's declared success metric's key, see
    ``learning/vecenv.success_metric_key``) or else the episode reward; otherwise a key of the history as it is
    (``timeout_fraction``), else a declared metric's short name (``success`` -> ``Episode/success``)."""
    if metric == "auto":
        return success or REWARD
    if any(metric in record for record in history):
        return metric
    return metric if metric.startswith(METRIC_PREFIX) or metric.startswith("mean_") else METRIC_PREFIX + metric


def chosen_by(metric: str, success: str | None) -> str:
    """Why ``metric_key`` picks what it picks (one of USER_CHOICE, DECLARED_SUCCESS, EPISODE_REWARD)."""
    if metric != "auto":
        return USER_CHOICE
    return DECLARED_SUCCESS if success else EPISODE_REWARD


def smoothed(values: list[float], window: int = SMOOTHING) -> list[float]:
    """Trailing means over ``window`` values (fewer at the start)."""
    out, total = [], 0.0
    for i, value in enumerate(values):
        total += value
        if i >= window:
            total -= values[i - window]
        out.append(total / min(i + 1, window))
    return out


class BestCheckpoint:
    """``save_best``: model_best.pt in the run directory, a copy of the saved checkpoint at which the run's metric
    (``metric``: ``sweep_metric`` as given; ``success``: the task's declared success metric's history key, or None),
    averaged over the last ``SMOOTHING`` iterations that report it, was highest. Only saved checkpoints are candidates
    (every ``save_interval`` iterations, and the last), so keeping the best costs a file copy, not a save per
    iteration."""

    def __init__(self, run_dir: str | Path, metric: str, success: str | None) -> None:
        self.path = Path(run_dir) / BEST_CHECKPOINT
        self.metric, self.success = metric, success
        self.chosen_by = chosen_by(metric, success)
        self.key: str | None = None  # the metric's history key, known once the history has entries
        self.value: float | None = None
        self.iteration: int | None = None
        self.source: str | None = None
        self.candidates: list[str] = []  # the saved checkpoints that had the metric, in order

    def consider(self, history: list[dict], checkpoint: str) -> None:
        """``checkpoint`` was just saved after the last iteration of ``history``: keep it if its metric is the
        best."""
        if not history:
            return
        self.key = metric_key(history, self.metric, self.success)
        values = [float(r[self.key]) for r in history if r.get(self.key) is not None][-SMOOTHING:]
        if not values:  # no episode has ended yet
            return
        value = smoothed(values)[-1]  # the sweep's trailing mean, as its "best" column reads it
        if checkpoint not in self.candidates[-1:]:  # the last iteration's may be saved twice (interval, end)
            self.candidates.append(checkpoint)
        if self.value is None or value > self.value:
            atomic_save(self.path, lambda partial: shutil.copyfile(checkpoint, partial))
            self.value, self.iteration, self.source = value, int(history[-1]["iteration"]), checkpoint

    def never_moved(self) -> str | None:
        """The console line when no later checkpoint beat the first (model_best.pt is then the first), else None."""
        if len(self.candidates) < 2 or self.source != self.candidates[0]:
            return None
        later = len(self.candidates) - 1
        return (f"[train] {self.path.name} is a copy of the first checkpoint, {Path(self.source).name}: {self.key} "
                f"never rose above its value there ({self.value:.4g}) in {later} later checkpoint"
                f"{'s' if later > 1 else ''}; evaluate {Path(self.candidates[-1]).name}, or follow another metric "
                "(sweep_metric)")

    def summary(self) -> dict | None:
        """summary.json's "best_checkpoint" (None before any checkpoint had the metric): which checkpoint, and which
        metric chose it and why ("chosen_by": user choice, declared success metric or episode reward)."""
        if self.value is None:
            return None
        return {"path": str(self.path), "iteration": self.iteration, "metric": self.key,
                "chosen_by": self.chosen_by, "value": self.value, "copy_of": self.source}
