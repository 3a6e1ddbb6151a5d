"""Training and evaluation with rsl-rl-lib's PPO, configured by cfg/train/<Task>PPO.yaml.

rsl_rl's OnPolicyRunner builds PPO, saves and loads checkpoints and exports policies; its ``learn`` loop is
replaced here so that a rollout never waits on the GPU (episode statistics stay on the device and are read
once per iteration), each iteration prints one line, and every run leaves summary.json behind.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import platform
import shutil
import time
from collections import deque
from importlib import metadata
from pathlib import Path

import torch
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils.log_writer import LogWriter

from isaacgymenvs_mw.learning.guard import LearnerGuard, NoGoodState, learner_tensors
from isaacgymenvs_mw.learning.loggers import make_writer
from isaacgymenvs_mw.learning.ppo import LR_MIN
from isaacgymenvs_mw.learning.sweep import BEST_CHECKPOINT, SMOOTHING, metric_key, smoothed
from isaacgymenvs_mw.learning.train_config import check_train_config
from isaacgymenvs_mw.learning.vecenv import METRIC_GROUP, RslRlVecEnv
from isaacgymenvs_mw.tasks.base.metrics import OUTCOME, PER_STEP
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.files import DiskWriteError, atomic_save
from isaacgymenvs_mw.utils.stop import PROCESS_STOP, StopRequested  # noqa: F401  (StopRequested: imported from here too)

# An action whose noise std is below this while the KL-adaptive rate sits at its floor has collapsed: moving its mean
# by 0.18 std (0.0018 here, under a thousandth of the [-1, 1] range) already spends a KL target of 0.016, so every
# update stops there and the other actions barely learn (ShadowHand's wrist, docs/PERFORMANCE.md).
NOISE_COLLAPSE_STD = 0.01


def rsl_rl_config(train_cfg: dict) -> dict:
    """Flatten our train YAML (runner/algorithm/actor/critic) into the dict OnPolicyRunner expects."""
    check_train_config(train_cfg)
    runner = dict(train_cfg["runner"])
    for key in ("num_steps_per_env", "max_iterations", "save_interval", "obs_groups"):
        if key not in runner:
            raise ConfigError(f"train.runner.{key} is required")
    return {**runner, "algorithm": dict(train_cfg["algorithm"]), "actor": dict(train_cfg["actor"]),
            "critic": dict(train_cfg["critic"])}


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist in ("torch", "warp-lang", "mujoco", "mujoco-warp", "rsl-rl-lib"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def device_description(device: str) -> str:
    if device.startswith("cuda"):
        return f"{device} ({torch.cuda.get_device_name(torch.device(device))})"
    return f"cpu ({platform.processor() or platform.machine()}, {os.cpu_count()} cores)"


class Runner(OnPolicyRunner):
    """OnPolicyRunner with a sync-free rollout, one progress line per iteration, and a run summary."""

    def __init__(self, env: RslRlVecEnv, train_cfg: dict, log_dir: str | None, device: str,
                 verbose: bool = False) -> None:
        # rsl_rl prints the observation groups and both networks layer by layer; only verbose runs show that.
        with contextlib.nullcontext() if verbose else contextlib.redirect_stdout(io.StringIO()):
            super().__init__(env, train_cfg, log_dir=log_dir, device=device)
        self.log_dir = log_dir
        self.is_main = not self.is_distributed or self.gpu_global_rank == 0
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
        self.best: BestCheckpoint | None = None  # save_best: model_best.pt follows the run's metric
        # Learner health: optimiser steps skipped for a non-finite loss or gradient, worlds whose observation or
        # reward held NaN/inf, and how often the last finite learner state was put back.
        self.skipped_steps = 0
        self.nonfinite_inputs = 0
        self.guard = LearnerGuard(lambda: learner_tensors(self.alg))
        self._good_iteration: int | None = None  # the iteration whose learner state the guard holds
        self.noise_collapse: dict | None = None  # summary.json's record of the first collapsed action noise

    def learn(self, num_learning_iterations: int, init_at_random_ep_len: bool = False,
              max_train_time_s: float | None = None) -> None:
        """Train for ``num_learning_iterations``, or until ``max_train_time_s`` seconds of training (rollouts and
        updates, as ``train_time_s`` counts them) are spent: the run then ends after that iteration as it would
        after its last one (final checkpoint, summary)."""
        env: RslRlVecEnv = self.env  # type: ignore[assignment]
        writer = None
        if self.log_dir and self.is_main:
            writer = make_writer(self.cfg, self.log_dir, self.experiment, self.run_config)
            self.logger.writer = writer  # rsl-rl-lib's save() uploads checkpoints through it (W&B)
        if init_at_random_ep_len:
            env.episode_length_buf = torch.randint_like(env.episode_length_buf, high=int(env.max_episode_length))
        obs = env.get_observations().to(self.device)
        self.alg.train_mode()
        if self.is_distributed:
            self.alg.broadcast_parameters()
        steps = self.cfg["num_steps_per_env"]
        start_it = self.current_learning_iteration
        last_it = start_it + num_learning_iterations
        it = start_it
        # On CUDA the host queues the update while the GPU still runs the rollout, so host clocks cannot split an
        # iteration; events on the GPU mark where the rollout ends.
        on_cuda = torch.device(self.device).type == "cuda"
        rollout_end = torch.cuda.Event(enable_timing=True) if on_cuda else None
        update_end = torch.cuda.Event(enable_timing=True) if on_cuda else None
        try:
            for it in range(start_it, last_it):
                t0 = time.perf_counter()  # the GPU is idle here: the last iteration ended with a host read
                progress = _FirstCollectProgress(it + 1, steps, t0) if it == start_it and self.is_main else None
                with torch.inference_mode():
                    for step in range(steps):
                        actions = self.alg.act(obs)
                        obs, rewards, dones, extras = env.step(actions.to(env.device))
                        obs, rewards, dones = obs.to(self.device), rewards.to(self.device), dones.to(self.device)
                        self.alg.process_env_step(obs, rewards, dones, extras)
                        if step == 0 and it == start_it:  # the first step compiles (torch, Triton): check after it
                            keep_stop_handler()
                        self._stop_if_requested()
                        if progress is not None:
                            progress.step_done(step + 1)
                    self.alg.compute_returns(obs)
                t1 = time.perf_counter()
                if on_cuda:
                    rollout_end.record()
                losses = self.alg.update()  # ends by reading its losses, so the GPU has finished
                t2 = time.perf_counter()
                learn_s = t2 - t1
                if on_cuda:
                    update_end.record()
                    update_end.synchronize()
                    learn_s = rollout_end.elapsed_time(update_end) / 1000.0
                self.current_learning_iteration = it + 1
                skipped = self.alg.take_skipped_steps() if hasattr(self.alg, "take_skipped_steps") else 0
                restored = self._keep_learner_finite(it + 1)
                self._log_iteration(writer, it, last_it, t2 - t0 - learn_s, learn_s, losses, skipped, restored)
                keep_stop_handler()
                self._stop_if_requested()
                if max_train_time_s is not None and self._budget_spent(max_train_time_s):
                    self.time_budget_reached = True
                    break
                if self.is_main and self.log_dir and (it + 1) % self.cfg["save_interval"] == 0:
                    self._save(os.path.join(self.log_dir, f"model_{it + 1}.pt"))
        except BaseException as err:
            # An interrupted run keeps what it learned so far (unless the disk it would go to refused a write).
            if (self.is_main and self.log_dir and self.current_learning_iteration > start_it
                    and not isinstance(err, DiskWriteError)):
                path = os.path.join(self.log_dir, f"model_{self.current_learning_iteration}_interrupted.pt")
                self._save(path)
                self.interrupted_checkpoint = path
            raise
        else:  # saved while the writer is open, so that W&B uploads the final checkpoint too
            if self.is_main and self.log_dir:
                self._save(os.path.join(self.log_dir, f"model_{self.current_learning_iteration}.pt"))
        finally:
            if writer is not None:
                writer.close()
                if isinstance(writer, LogWriter):
                    writer.stop()
                self.logger.writer = None

    def _budget_spent(self, budget_s: float) -> bool:
        """Whether the training time has reached ``budget_s``; with several GPUs, on any rank (so that all stop
        after the same iteration: their clocks differ slightly)."""
        spent = self.train_time >= budget_s
        if self.is_distributed:
            flag = torch.tensor(float(spent), device=self.device)
            torch.distributed.all_reduce(flag, op=torch.distributed.ReduceOp.MAX)
            spent = bool(flag.item())
        return spent

    def _save(self, path: str) -> None:
        # rsl-rl-lib's save(), written whole or not at all (a full disk leaves no truncated model_*.pt); the upload
        # (W&B) then sends the finished file.
        state = {**self.alg.save(), "iter": self.current_learning_iteration,
                 "infos": {"env_steps": self.total_env_steps}}  # a resumed run's env-step count goes on from here
        atomic_save(path, lambda partial: torch.save(state, partial))
        self.logger.save_model(path, self.current_learning_iteration)
        self.last_checkpoint = path
        if self.best is not None:
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

    def _action_noise(self) -> dict[str, float]:
        """The policy's action noise as its parameters hold it after the update: the mean and the smallest standard
        deviation over the actions. The smallest is the one to watch: a few collapsed actions pin the KL-adaptive rate
        at its floor (ShadowHand, docs/PERFORMANCE.md). One small read; empty for a policy without a state-independent
        Gaussian (rsl-rl-lib's GaussianDistribution and ours keep ``std_param`` or ``log_std_param``)."""
        distribution = getattr(self.alg.get_policy(), "distribution", None)
        with torch.no_grad():
            if isinstance(getattr(distribution, "std_param", None), torch.Tensor):
                std = distribution.std_param.clamp(*distribution.std_range)
            elif isinstance(getattr(distribution, "log_std_param", None), torch.Tensor):
                std = distribution.log_std_param.clamp(*distribution.log_std_range).exp()
            else:
                return {}
            low, mean, index = torch.stack([std.min(), std.mean(), std.argmin().to(std.dtype)]).tolist()
        return {"action_std_min": low, "action_std_mean": mean, "action_std_min_index": int(index)}

    def _collapsed_noise(self, record: dict) -> dict | None:
        """The collapse this iteration shows (see NOISE_COLLAPSE_STD), named by the action's actuator, or None."""
        alg = self.alg
        adaptive = getattr(alg, "desired_kl", None) is not None and getattr(alg, "schedule", None) == "adaptive"
        floor = getattr(alg, "learning_rate_min", LR_MIN)
        if not adaptive or "action_std_min" not in record or record["action_std_min"] >= NOISE_COLLAPSE_STD:
            return None
        if record["learning_rate"] > floor * (1.0 + 1e-6):
            return None
        index = record["action_std_min_index"]
        actuators = self.env.task.action_actuators()
        return {"iteration": record["iteration"], "action": index,
                "actuator": actuators[index] if actuators else None, "std": record["action_std_min"],
                "mean_std": record["action_std_mean"], "learning_rate": record["learning_rate"]}

    def _noise_lever(self) -> str:
        """The override to try first against a collapse: the noise learned as a log (on AllegroHand no action's noise
        collapsed with it in two seeds, docs/PERFORMANCE.md), or, for a policy that has it already, a floor."""
        std_type = (self.cfg["actor"].get("distribution_cfg") or {}).get("std_type", "scalar")  # actor: checked
        if std_type == "log":
            return "+train.actor.distribution_cfg.std_range=[0.1,10.0]"
        return "train.actor.distribution_cfg.std_type=log"

    def _log_iteration(self, writer, it: int, last_it: int, collect_s: float, learn_s: float, losses: dict,
                       skipped: int = 0, restored: str | None = None) -> None:
        env: RslRlVecEnv = self.env  # type: ignore[assignment]
        stats = env.stats.pop()  # the env statistics' one host read of the iteration
        world = self.gpu_world_size
        env_steps = self.cfg["num_steps_per_env"] * env.num_envs * world
        self.total_env_steps += env_steps
        self.train_time += collect_s + learn_s
        if stats["episodes"] > 0:
            self.recent.append(stats)
        fps = env_steps / max(collect_s + learn_s, 1e-9)
        record = {"iteration": it + 1, "env_steps": self.total_env_steps, "time_s": self.train_time,
                  "steps_per_s": fps, "collect_s": collect_s, "learn_s": learn_s, **{k: v for k, v in stats.items()},
                  "losses": {k: float(v) for k, v in losses.items()}, "learning_rate": float(self.alg.learning_rate),
                  **self._action_noise()}
        self.history.append(record)
        self.nonfinite_resets += int(stats["nonfinite_resets"])
        self.nonfinite_inputs += int(stats.get("nonfinite_inputs", 0))
        self.skipped_steps += skipped
        record.update(skipped_optimizer_steps=skipped, learner_restored=restored is not None)
        if not self.is_main:
            return
        if self.noise_collapse is None:
            self.noise_collapse = self._collapsed_noise(record)
            if self.noise_collapse is not None:
                c = self.noise_collapse
                which = f"action {c['action']}" + (f" ({c['actuator']})" if c["actuator"] else "")
                print(f"[it {it + 1:>5}] the action noise has collapsed: {which} has a std of {c['std']:.4f} (mean "
                      f"over the actions {c['mean_std']:.3g}) while the adaptive learning rate sits at its floor "
                      f"({c['learning_rate']:.0e}), so each update spends the KL target on that action alone. If the "
                      f"curve flattens short of the goal, see the README's levers (e.g. {self._noise_lever()})",
                      flush=True)
        if writer is not None:
            for key, value in losses.items():
                writer.add_scalar(f"Loss/{key}", value, it)
            writer.add_scalar("Loss/learning_rate", self.alg.learning_rate, it)
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


class BestCheckpoint:
    """``save_best``: model_best.pt in the run directory, a copy of the saved checkpoint at which the run's metric
    (``sweep_metric``: ``auto`` is the task's primary metric, else its first declared one, else the episode reward),
    averaged over the last ``SMOOTHING`` iterations that report it, was highest. Only saved checkpoints are candidates
    (every ``save_interval`` iterations, and the last), so keeping the best costs a file copy, not a save per
    iteration."""

    def __init__(self, run_dir: str | Path, metric: str, declared: list[str]) -> None:
        self.path = Path(run_dir) / BEST_CHECKPOINT
        self.metric, self.declared = metric, declared
        self.key: str | None = None  # the metric's history key, known once the history has entries
        self.value: float | None = None
        self.iteration: int | None = None
        self.source: str | None = None

    def consider(self, history: list[dict], checkpoint: str) -> None:
        """``checkpoint`` was just saved after the last iteration of ``history``: keep it if its metric is the
        best."""
        if not history:
            return
        self.key = metric_key(history, self.metric, self.declared)
        values = [float(r[self.key]) for r in history if r.get(self.key) is not None][-SMOOTHING:]
        if not values:  # no episode has ended yet
            return
        value = smoothed(values)[-1]  # the sweep's trailing mean, as its "best" column reads it
        if self.value is None or value > self.value:
            atomic_save(self.path, lambda partial: shutil.copyfile(checkpoint, partial))
            self.value, self.iteration, self.source = value, int(history[-1]["iteration"]), checkpoint

    def summary(self) -> dict | None:
        """summary.json's "best_checkpoint" (None before any checkpoint had the metric)."""
        if self.value is None:
            return None
        return {"path": str(self.path), "iteration": self.iteration, "metric": self.key, "value": self.value,
                "copy_of": self.source}


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


def evaluate(task, policy, device: str) -> dict:
    """Run every env for one full episode with the deterministic policy; report per-episode means.

    Each env contributes its first episode, so the result is an unbiased sample of ``num_envs`` episodes from
    the task's reset distribution (commands too, for the legged tasks).
    """
    task.metrics.evaluate()  # the task records its per-step metrics (tasks/base/metrics.py), if it declares any
    env = RslRlVecEnv(task)
    n = env.num_envs
    ret = torch.zeros(n, device=env.device)
    length = torch.zeros(n, device=env.device)
    finished = torch.zeros(n, dtype=torch.bool, device=env.device)
    result_ret = torch.zeros(n, device=env.device)
    result_len = torch.zeros(n, device=env.device)
    result_timeout = torch.zeros(n, dtype=torch.bool, device=env.device)
    metric_sums: dict[str, torch.Tensor] = {}
    outcomes: dict[str, torch.Tensor] = {}  # per env, how its first episode ended (e.g. success 1 / 0)
    # Results per group the task declares (the terrain tasks: each env's level during its first episode; levels
    # change only at resets), as the task defines them at the start.
    groups = {name: value.clone() for name, value in task.evaluation_groups().items()}
    obs = env.get_observations()
    max_steps = task.longest_episode() + 2
    with torch.inference_mode():
        for step in range(max_steps):
            actions = policy(obs.to(device))
            obs, rew, dones, extras = env.step(actions.to(env.device))
            if step == 0:  # the first step compiles (torch, Triton): check after it
                keep_stop_handler()
            active = ~finished
            ret += rew * active
            length += active.float()
            for key, value in task.metrics.recorded(PER_STEP).items():
                # per-env per-step values, averaged over the steps each env spent in its first episode
                metric_sums[key] = metric_sums.get(key, torch.zeros(n, device=env.device)) + value * active
            just_done = active & (dones != 0)
            result_ret = torch.where(just_done, ret, result_ret)
            result_len = torch.where(just_done, length, result_len)
            timed_out = extras["time_outs"] != 0
            if "successes" in extras:  # bootstrapped like time-outs for learning, but not time-outs
                timed_out &= ~extras["successes"]
            result_timeout |= just_done & timed_out
            for key, value in task.metrics.recorded(OUTCOME).items():
                # per-env values of the episodes that ended in this step (a task's success flag)
                outcomes[key] = torch.where(just_done, value, outcomes.get(key, torch.zeros(n, device=env.device)))
            finished |= just_done
            if step % 50 == 0 and bool(finished.all()):
                break
    if not bool(finished.all()):
        # Envs still running at the cap count with what they reached.
        result_ret = torch.where(finished, result_ret, ret)
        result_len = torch.where(finished, result_len, length)
    out = {
        "episodes": n,
        "mean_episode_reward": float(result_ret.mean()),
        "mean_episode_length": float(result_len.mean()),
        "timeout_fraction": float(result_timeout.float().mean()),
    }
    for key, value in metric_sums.items():
        out[key] = float((value / length.clamp(min=1)).mean())
    for key, value in outcomes.items():  # an episode still running at the cap counts 0
        out[key] = float(value.mean())
    for name, labels in groups.items():
        out[f"per_{name}"] = {}
        for label in sorted(set(labels.tolist())):
            sel = labels == label
            row = {"episodes": int(sel.sum()), "survival": float(result_timeout[sel].float().mean()),
                   "mean_episode_length": float(result_len[sel].mean())}
            row.update({k: float((v / length.clamp(min=1))[sel].mean()) for k, v in metric_sums.items()})
            out[f"per_{name}"][str(label)] = row
    return out


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` as JSON whole or not at all: a reader, or a process writing the same file, never sees half."""
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(data, indent=2, sort_keys=False) + "\n"
    atomic_save(path, lambda partial: Path(partial).write_text(text))
