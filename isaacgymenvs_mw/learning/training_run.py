"""What a training run keeps and reports, whichever learner updates the policy (learning/runner.py: rsl-rl-lib's PPO;
learning/rl_games_runner.py: rl_games'): the iteration's statistics and history (reported by learning/reporting.py),
checkpoints (and the best one, learning/best_checkpoint.py), the time budget, stop requests and the learner's
finiteness guard.

A runner that inherits ``TrainingRun`` calls ``init_training_run`` in its constructor and provides ``env`` (with
``stats``, ``num_envs``, ``episode_length_buf``, ``max_episode_length``), ``steps_per_env``, ``gpu_world_size``,
``is_distributed``, ``device``, ``save``/``load`` and ``current_learning_rate``.
"""

from __future__ import annotations

import os
from collections import deque
from pathlib import Path

import torch

from isaacgymenvs_mw.learning.guard import LearnerGuard, NoGoodState
from isaacgymenvs_mw.learning.reporting import INCIDENT_COUNTS, duration, report_iteration, steady_iteration_s
from isaacgymenvs_mw.learning.vecenv import METRIC_GROUP
from isaacgymenvs_mw.utils.files import DiskWriteError
from isaacgymenvs_mw.utils.stop import PROCESS_STOP, StopRequested


class TrainingRun:
    """The learner-independent half of a runner (see the module's docstring)."""

    steps_per_env: int  # env steps per environment in one iteration's rollout

    # What each learner's runner provides (learning/learners.py: its Learner makes it).
    def load_checkpoint(self, checkpoint: Path, task, state: dict | None = None) -> None:
        """Load ``checkpoint`` (``state``: its contents, read already) after checking it fits ``task`` and the train
        YAML, and continue the run's env-step count (and the task's schedules) from it."""
        raise NotImplementedError

    def export_modules(self) -> tuple[torch.nn.Module, torch.jit.ScriptModule]:
        """The deterministic policy on the CPU: a module for ONNX export and its TorchScript form."""
        raise NotImplementedError

    def init_training_run(self, guard: LearnerGuard, is_main: bool) -> None:
        self.is_main = is_main
        self.recent: deque[dict[str, float]] = deque(maxlen=5)  # last iterations' episode stats
        self.history: list[dict] = []
        self.total_env_steps = 0
        self.train_time = 0.0
        self.nonfinite_resets = 0
        self.run_config: dict | None = None  # the resolved run config, attached to W&B runs
        self.experiment = "run"  # W&B's default project
        self.stop_signal: int | None = None  # set from a signal handler; learn() stops at the next env step
        self.interrupted_checkpoint: str | None = None  # the model_<it>_interrupted.pt a stop wrote
        self.time_budget_reached = False  # learn() ended at max_train_time_s, before its last iteration
        self.last_checkpoint: str | None = None
        self.best = None  # save_best: the BestCheckpoint (learning/best_checkpoint.py) model_best.pt follows
        self.best_after = 0  # model_best.pt considers checkpoints from this iteration on (rl_games' save_best_after)
        # Learner health: optimiser steps skipped for a non-finite loss or gradient, worlds whose observation or
        # reward held NaN/inf, and how often the last finite learner state was put back.
        self.skipped_steps = 0
        self.nonfinite_inputs = 0
        self.guard = guard
        self._good_iteration: int | None = None  # the iteration whose learner state the guard holds
        self.noise_collapse: dict | None = None  # summary.json's record of the first collapsed action noise

    def current_learning_rate(self) -> float:
        raise NotImplementedError

    def _action_noise(self) -> dict[str, float]:
        """The policy's action noise after the update (action_std_min, action_std_mean, action_std_min_index), or
        empty where the policy has no state-independent noise."""
        return {}

    def _notice_noise_collapse(self, record: dict) -> None:
        """Say once when an action's noise has collapsed (a learner whose rate can be pinned by it)."""

    def _budget_spent(self, budget_s: float) -> bool:
        """Whether the training time has reached ``budget_s``; with several GPUs, on any rank (so that all stop
        after the same iteration: their clocks differ slightly)."""
        spent = self.train_time >= budget_s
        if self.is_distributed:
            flag = torch.tensor(float(spent), device=self.device)
            torch.distributed.all_reduce(flag, op=torch.distributed.ReduceOp.MAX)
            spent = bool(flag.item())
        return spent

    def _save_every(self, iteration: int, interval: int) -> None:
        """The periodic checkpoint: ``model_<iteration>.pt`` every ``interval`` iterations (0: none), main rank only."""
        if self.is_main and self.log_dir and interval > 0 and iteration % interval == 0:
            self._save(os.path.join(self.log_dir, f"model_{iteration}.pt"))

    def _save_interrupted(self, start_it: int, err: BaseException) -> None:
        """An interrupted run keeps what it learned so far: ``model_<it>_interrupted.pt`` once an iteration ended
        (unless ``err`` is the disk it would go to refusing a write)."""
        if (self.is_main and self.log_dir and self.current_learning_iteration > start_it
                and not isinstance(err, DiskWriteError)):
            path = os.path.join(self.log_dir, f"model_{self.current_learning_iteration}_interrupted.pt")
            self._save(path)
            self.interrupted_checkpoint = path

    def _save_last(self) -> None:
        if self.is_main and self.log_dir:
            self._save(os.path.join(self.log_dir, f"model_{self.current_learning_iteration}.pt"))

    def _save(self, path: str) -> None:
        self.save(path)
        self.last_checkpoint = path
        if self.best is not None and self.current_learning_iteration >= self.best_after:
            self.best.consider(self.history, path)

    def _keep_learner_finite(self, iteration: int) -> str | None:
        """After an update: keep the learner's state when it is finite; put the last finite one back when it is not
        (the last checkpoint where none is in memory). Returns the line that says what was put back, else None."""
        try:
            if self.guard.check():
                self._good_iteration = iteration
                return None
            return (f"the learner's weights, optimiser state or normaliser statistics were not finite after "
                    f"iteration {iteration}; restored their state after iteration {self._good_iteration}")
        except NoGoodState:
            if self.last_checkpoint is None:
                raise RuntimeError(f"the learner's weights, optimiser state or normaliser statistics were not finite "
                                   f"after iteration {iteration}, and no finite state or checkpoint exists to "
                                   "restore") from None
            self.load(self.last_checkpoint, map_location=self.device)
            self.guard.restores += 1
            self.current_learning_iteration = iteration
            self._good_iteration = None
            return (f"the learner's weights, optimiser state or normaliser statistics were not finite after "
                    f"iteration {iteration}; restored them from {self.last_checkpoint}")

    def learner_health(self) -> dict[str, int]:
        """What summary.json reports of the learner's defences against non-finite numbers."""
        return {"skipped_optimizer_steps": self.skipped_steps, "nonfinite_inputs": self.nonfinite_inputs,
                "learner_restores": self.guard.restores}

    def _stop_if_requested(self) -> None:
        if self.stop_signal is not None:
            raise StopRequested(self.stop_signal)

    def _log_iteration(self, writer, it: int, last_it: int, collect_s: float, learn_s: float, losses: dict,
                       skipped: int = 0, restored: str | None = None) -> None:
        """Read the iteration's episode statistics, count its steps, time and incidents, append its history entry, and
        report it (learning/reporting.py) on the main rank."""
        env = self.env
        stats = env.stats.pop()  # the env statistics' one host read of the iteration
        env_steps = self.steps_per_env * env.num_envs * self.gpu_world_size
        self.total_env_steps += env_steps
        self.train_time += collect_s + learn_s
        ended_before = bool(self.recent)
        if stats["episodes"] > 0:
            self.recent.append(stats)
        fps = env_steps / max(collect_s + learn_s, 1e-9)
        record = {"iteration": it + 1, "env_steps": self.total_env_steps, "time_s": self.train_time,
                  "steps_per_s": fps, "collect_s": collect_s, "learn_s": learn_s, **{k: v for k, v in stats.items()},
                  "losses": {k: float(v) for k, v in losses.items()}, "learning_rate": self.current_learning_rate(),
                  **self._action_noise()}
        self.history.append(record)
        self.nonfinite_resets += int(stats["nonfinite_resets"])
        self.nonfinite_inputs += int(stats.get("nonfinite_inputs", 0))
        self.skipped_steps += skipped
        record.update(skipped_optimizer_steps=skipped, learner_restored=restored is not None)
        if not self.is_main:
            return
        self._notice_noise_collapse(record)
        eta = duration(steady_iteration_s(self.history) * (last_it - it - 1)) if it + 1 < last_it else "0s"
        report_iteration(writer, record, stats, losses, {**self.learner_health(), "nonfinite_resets":
                                                         self.nonfinite_resets}, last_it, eta,
                         lambda: int(env.episode_length_buf.max()), int(env.max_episode_length), ended_before,
                         restored)

    def recent_means(self) -> dict[str, float]:
        """Episode statistics over the last few iterations (weighted by episodes)."""
        total = sum(s["episodes"] for s in self.recent)
        if total == 0:
            return {}
        keys = [k for k in self.recent[-1] if k not in INCIDENT_COUNTS]
        return {k: sum(s.get(k, 0.0) * s["episodes"] for s in self.recent) / total for k in keys}


def keep_stop_handler() -> None:
    """Put the process's stop handler back if a library replaced it (see utils/stop.py), saying so once."""
    message = PROCESS_STOP.reassert()
    if message is not None:
        print(message, flush=True)


def episode_metrics(means: dict[str, float]) -> dict[str, float]:
    """The task's declared metrics among episode statistics, by their own names (``terrain_level``)."""
    return {key[len(METRIC_GROUP):]: value for key, value in means.items() if key.startswith(METRIC_GROUP)}
