"""The training loop and what a run keeps and reports, whichever learner updates the policy (each learner's runner
is named in learning/learners.py): the iterations, the time budget, stop requests, checkpoints whatever ends the run
(periodic, last, interrupted, and the best one, learning/best_checkpoint.py), the iteration's statistics and history
(reported by learning/reporting.py) and the learner's finiteness guard.

A runner that inherits ``TrainingRun`` calls ``init_training_run`` in its constructor and provides ``env`` (a
``TaskEnv`` of learning/vecenv.py), ``steps_per_env``, ``save_interval``, ``gpu_world_size``, ``is_distributed``,
``device``, ``save``/``load``, ``current_learning_rate`` and one iteration, ``_train_iteration`` (a rollout that calls
``_step_done`` after each env step, then the update); ``learn`` runs the loop around it.
"""

from __future__ import annotations

import os
import time
from collections import deque
from pathlib import Path
from typing import NamedTuple

import torch

from isaacgymenvs_mw.learning.guard import LearnerGuard, NoGoodState
from isaacgymenvs_mw.learning.loggers import make_writer
from isaacgymenvs_mw.learning.reporting import (INCIDENT_COUNTS, FirstCollectProgress, duration, report_iteration,
                                                steady_iteration_s)
from isaacgymenvs_mw.learning.vecenv import METRIC_GROUP
from isaacgymenvs_mw.utils.files import DiskWriteError
from isaacgymenvs_mw.utils.stop import PROCESS_STOP, StopRequested


class Iteration(NamedTuple):
    """What one iteration of a learner tells the loop: its seconds collecting and updating, its mean losses, and the
    optimiser steps it skipped for a non-finite loss or gradient."""

    collect_s: float
    learn_s: float
    losses: dict
    skipped: int = 0


class TrainingRun:
    """The learner-independent half of a runner (see the module's docstring)."""

    steps_per_env: int  # env steps per environment in one iteration's rollout
    save_interval: int  # a periodic checkpoint every this many iterations (0: none)
    test_actions = "mean"  # test mode's actions: the mean, or "sampled" (runner.test_actions, rl_games' player)

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
        self.best_after = 0  # model_best.pt considers checkpoints from this iteration on (a learner's option)
        # Learner health: optimiser steps skipped for a non-finite loss or gradient, worlds whose observation or
        # reward held NaN/inf, and how often the last finite learner state was put back.
        self.skipped_steps = 0
        self.nonfinite_inputs = 0
        self.guard = guard
        self._good_iteration: int | None = None  # the iteration whose learner state the guard holds
        self.noise_collapse: dict | None = None  # summary.json's record of the first collapsed action noise
        self._steps_done = 0  # env steps of this learn() call, counted by _step_done
        self._progress: FirstCollectProgress | None = None  # the first iteration's progress lines (main rank)

    def learn(self, num_learning_iterations: int, init_at_random_ep_len: bool = False,
              max_train_time_s: float | None = None) -> None:
        """Train for ``num_learning_iterations``, or until ``max_train_time_s`` seconds of training (rollouts and
        updates, as ``train_time_s`` counts them) are spent, or the learner's own goal is reached: the run then ends
        after that iteration as it would after its last one (final checkpoint, summary). An exception or a stop
        request ends it with ``model_<it>_interrupted.pt`` instead."""
        writer = None
        if self.log_dir and self.is_main:
            writer = make_writer(self._logger_config(), self.log_dir, self.experiment, self.run_config)
            self._attach_writer(writer)
        env = self.env
        if init_at_random_ep_len:
            env.episode_length_buf = torch.randint_like(env.episode_length_buf, high=int(env.max_episode_length))
        start_it = self.current_learning_iteration
        last_it = start_it + num_learning_iterations
        try:
            self._begin_learning()
            self._steps_done = 0
            self._progress = (FirstCollectProgress(start_it + 1, self.steps_per_env, time.perf_counter())
                              if self.is_main else None)
            for it in range(start_it, last_it):
                done = self._train_iteration(it, writer)
                self.current_learning_iteration = it + 1
                restored = self._keep_learner_finite(it + 1)
                self._log_iteration(writer, it, last_it, done.collect_s, done.learn_s, done.losses, done.skipped,
                                    restored)
                keep_stop_handler()
                self._stop_if_requested()
                if max_train_time_s is not None and self._budget_spent(max_train_time_s):
                    self.time_budget_reached = True
                    break
                if self._reached_goal():
                    break
                self._save_every(it + 1, self.save_interval)
        except BaseException as err:
            self._save_interrupted(start_it, err)
            raise
        else:  # saved while the writer is open, so that W&B uploads the final checkpoint too
            self._save_last()
        finally:
            self._end_learning()
            if writer is not None:
                writer.close()
                self._detach_writer(writer)

    def _step_done(self) -> None:
        """After each env step of a rollout: a stop request ends the run here, and the first iteration shows its
        progress. The first step compiles (torch, Triton), which may replace the stop handler: it is checked after
        it."""
        self._steps_done += 1
        if self._steps_done == 1:
            keep_stop_handler()
        self._stop_if_requested()
        if self._progress is not None and self._steps_done <= self.steps_per_env:
            self._progress.step_done(self._steps_done)

    # The learner's side of the loop.
    def _train_iteration(self, it: int, writer) -> Iteration:
        """One iteration (0-based ``it``): a rollout of ``steps_per_env`` env steps, each followed by
        ``_step_done()``, then the update. ``writer``: the run's TensorBoard writer, or None."""
        raise NotImplementedError

    def _begin_learning(self) -> None:
        """Before the first iteration of ``learn`` (the learner's buffers, first observation, training mode)."""

    def _end_learning(self) -> None:
        """After ``learn``, however it ended."""

    def _reached_goal(self) -> bool:
        """Whether the learner's own end (a score, a frame count) is reached after an iteration."""
        return False

    def _logger_config(self) -> dict:
        """The train YAML section that names the logger (``logger``: TensorBoard or W&B); empty: TensorBoard."""
        return {}

    def _attach_writer(self, writer) -> None:
        """Give the learner the run's writer (its own scalars, checkpoint uploads)."""

    def _detach_writer(self, writer) -> None:
        """Take the writer back from the learner once it is closed."""

    def release(self) -> None:
        """Free what the learner holds on the device that would keep the process group from closing (a captured
        update's NCCL work)."""

    def leave_process_group(self) -> None:
        """multi_gpu=True: the runner joined a NCCL group; leaving it lets each rank exit without NCCL's leak
        warning. A captured update holds NCCL work that would make leaving hang, so it is freed first."""
        self.release()
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            torch.distributed.destroy_process_group()

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
