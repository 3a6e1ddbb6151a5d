"""What a training run keeps and reports, whichever learner updates the policy (learning/runner.py: rsl-rl-lib's PPO;
learning/rl_games_runner.py: rl_games'): the iteration's statistics, history and progress line, TensorBoard
scalars, checkpoints (and the best one), the time budget, stop requests and the learner's finiteness guard.

A runner that inherits ``TrainingRun`` calls ``init_training_run`` in its constructor and provides ``env`` (with
``stats``, ``num_envs``, ``episode_length_buf``, ``max_episode_length``), ``steps_per_env``, ``gpu_world_size``,
``is_distributed``, ``device``, ``save``/``load`` and ``current_learning_rate``.
"""

from __future__ import annotations

import math
import os
import time
from collections import deque

import torch

from isaacgymenvs_mw.learning.guard import LearnerGuard, NoGoodState
from isaacgymenvs_mw.learning.vecenv import METRIC_GROUP
from isaacgymenvs_mw.utils.files import DiskWriteError
from isaacgymenvs_mw.utils.stop import PROCESS_STOP, StopRequested


class TrainingRun:
    """The learner-independent half of a runner (see the module's docstring)."""

    steps_per_env: int  # env steps per environment in one iteration's rollout

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
        self.best = None  # save_best: a BestCheckpoint that model_best.pt follows
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
        env = self.env
        stats = env.stats.pop()  # the env statistics' one host read of the iteration
        world = self.gpu_world_size
        env_steps = self.steps_per_env * env.num_envs * world
        self.total_env_steps += env_steps
        self.train_time += collect_s + learn_s
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
        if writer is not None:
            for key, value in losses.items():
                writer.add_scalar(f"Loss/{key}", value, it)
            writer.add_scalar("Loss/learning_rate", record["learning_rate"], it)
            if "action_std_mean" in record:
                writer.add_scalar("Policy/mean_std", record["action_std_mean"], it)
                writer.add_scalar("Policy/min_std", record["action_std_min"], it)
                writer.add_scalar("Policy/min_std_action", record["action_std_min_index"], it)
            writer.add_scalar("Perf/total_fps", fps, it)
            writer.add_scalar("Perf/collection_time", collect_s, it)
            writer.add_scalar("Perf/learning_time", learn_s, it)
            for key, value in stats.items():
                if key in ("episodes", "nonfinite_resets", "nonfinite_inputs"):
                    continue
                tag = key if "/" in key else f"Train/{key}"
                writer.add_scalar(tag, value, it)
                if key in ("mean_episode_reward", "mean_episode_length"):
                    writer.add_scalar(f"{tag}/time", value, int(self.train_time))
        if writer is not None:
            writer.add_scalar("Sim/nonfinite_resets", self.nonfinite_resets, it)
            writer.add_scalar("Learner/skipped_optimizer_steps", self.skipped_steps, it)
            writer.add_scalar("Learner/nonfinite_inputs", self.nonfinite_inputs, it)
            writer.add_scalar("Learner/restores", self.guard.restores, it)
        if stats["nonfinite_resets"]:
            print(f"[it {it + 1:>5}] {int(stats['nonfinite_resets'])} env(s) had NaN/inf or diverged (a speed "
                  f"above 1e4) simulator state and were reset ({self.nonfinite_resets} so far)", flush=True)
        if stats.get("nonfinite_inputs"):
            print(f"[it {it + 1:>5}] {int(stats['nonfinite_inputs'])} observation(s) or reward(s) held NaN/inf and "
                  f"were replaced by 0 before the learner saw them ({self.nonfinite_inputs} so far)", flush=True)
        if skipped:
            print(f"[it {it + 1:>5}] {skipped} optimiser step(s) skipped: their loss or gradient was not finite "
                  f"({self.skipped_steps} so far)", flush=True)
        if restored is not None:
            print(f"[it {it + 1:>5}] {restored}", flush=True)
        if stats["episodes"]:
            episodes = f"ep_rew {stats['mean_episode_reward']:9.2f} | ep_len {stats['mean_episode_length']:7.1f}"
            for key, value in stats.items():  # the metrics the task declares (e.g. a curriculum's terrain level)
                if key.startswith(METRIC_GROUP):
                    episodes += f" | {key[len(METRIC_GROUP):]} {value:5.2f}"
        else:  # a host read, but only on iterations where no episode ended
            longest = int(env.episode_length_buf.max())
            # "yet" only before the first episode end: later, a quiet iteration is one where every env is mid-episode
            # (e.g. time-outs of envs reset together), not a run that has never ended an episode.
            when = "this iteration" if self.recent else "yet"
            episodes = f"no episode ended {when} (longest {longest}/{int(env.max_episode_length)} steps)"
        eta = _duration(steady_iteration_s(self.history) * (last_it - it - 1)) if it + 1 < last_it else "0s"
        print(
            f"[it {it + 1:>5}/{last_it}] steps {self.total_env_steps:>11,} | {fps:>10,.0f} steps/s | "
            f"{episodes} | value_loss {losses.get('value', float('nan')):8.4f} | "
            f"collect {collect_s:6.2f}s learn {learn_s:5.2f}s | ETA {eta}",
            flush=True,
        )

    def recent_means(self) -> dict[str, float]:
        """Episode statistics over the last few iterations (weighted by episodes)."""
        total = sum(s["episodes"] for s in self.recent)
        if total == 0:
            return {}
        keys = [k for k in self.recent[-1] if k not in ("episodes", "nonfinite_resets", "nonfinite_inputs")]
        return {k: sum(s.get(k, 0.0) * s["episodes"] for s in self.recent) / total for k in keys}


class _FirstCollectProgress:
    """A line every ``every_s`` seconds while the first iteration collects, so that a run with many worlds on a CPU
    (or a long first compile) does not look hung. Host clocks only: no GPU sync, and silent when steps are fast."""

    def __init__(self, iteration: int, steps: int, started: float, every_s: float = 15.0):
        self.iteration, self.steps, self.started, self.every_s = iteration, steps, started, every_s
        self.last_print = started

    def step_done(self, step: int) -> None:
        now = time.perf_counter()
        if now - self.last_print < self.every_s or step == self.steps:
            return
        self.last_print = now
        spent = now - self.started
        left = spent / step * (self.steps - step)
        print(f"[it {self.iteration:>5}] collecting: env step {step}/{self.steps} after {_duration(spent)}, "
              f"about {_duration(left)} more before the update", flush=True)


def keep_stop_handler() -> None:
    """Put the process's stop handler back if a library replaced it (see utils/stop.py), saying so once."""
    message = PROCESS_STOP.reassert()
    if message is not None:
        print(message, flush=True)


def episode_metrics(means: dict[str, float]) -> dict[str, float]:
    """The task's declared metrics among episode statistics, by their own names (``terrain_level``)."""
    return {key[len(METRIC_GROUP):]: value for key, value in means.items() if key.startswith(METRIC_GROUP)}


def steady_iteration_s(history: list[dict]) -> float:
    """Mean seconds per iteration without this run's first one (Warp and torch.compile compile during it, which
    made a Go1Terrain ETA read 8h10m), or NaN while only the first has run."""
    steady = history[1:]
    if not steady:
        return float("nan")
    return sum(r["collect_s"] + r["learn_s"] for r in steady) / len(steady)


def _duration(seconds: float) -> str:
    """Seconds as 42s, 3m05s or 1h02m ('--' when not known yet)."""
    if not math.isfinite(seconds):
        return "--"
    s = int(round(seconds))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"
