"""Training and evaluation with rsl-rl-lib's PPO, configured by cfg/train/<Task>PPO.yaml.

rsl_rl's OnPolicyRunner builds PPO, saves and loads checkpoints and exports policies; its ``learn`` loop is
replaced here so that a rollout never waits on the GPU (episode statistics stay on the device and are read
once per iteration), each iteration prints one line, and every run leaves summary.json behind.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import platform
import shutil
import time
from importlib import metadata
from pathlib import Path

import torch
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils.log_writer import LogWriter

from isaacgymenvs_mw.learning.guard import LearnerGuard, learner_tensors
from isaacgymenvs_mw.learning.loggers import make_writer
from isaacgymenvs_mw.learning.ppo import LR_MIN
from isaacgymenvs_mw.learning.sweep import BEST_CHECKPOINT, SMOOTHING, metric_key, smoothed
from isaacgymenvs_mw.learning.train_config import check_train_config
from isaacgymenvs_mw.learning.training_run import (  # noqa: F401  (also imported from here)
    TrainingRun,
    _duration,
    _FirstCollectProgress,
    episode_metrics,
    keep_stop_handler,
    steady_iteration_s,
)
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.tasks.base.metrics import OUTCOME, PER_STEP
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.files import atomic_save
from isaacgymenvs_mw.utils.stop import PROCESS_STOP, StopRequested  # noqa: F401  (StopRequested: imported from here too)

# An action whose noise std is below this while the KL-adaptive rate sits at its floor has collapsed: moving its mean
# by 0.18 std (0.0018 here, under a thousandth of the [-1, 1] range) already spends a KL target of 0.016, so every
# update stops there and the other actions barely learn (ShadowHand's wrist, H100, 2026-11-26).
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
    for dist in ("torch", "warp-lang", "mujoco", "mujoco-warp", "rsl-rl-lib", "rl-games"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def device_description(device: str) -> str:
    if device.startswith("cuda"):
        return f"{device} ({torch.cuda.get_device_name(torch.device(device))})"
    return f"cpu ({platform.processor() or platform.machine()}, {os.cpu_count()} cores)"


class Runner(OnPolicyRunner, TrainingRun):
    """OnPolicyRunner with a sync-free rollout, one progress line per iteration, and a run summary."""

    def __init__(self, env: RslRlVecEnv, train_cfg: dict, log_dir: str | None, device: str,
                 verbose: bool = False) -> None:
        # rsl_rl prints the observation groups and both networks layer by layer; only verbose runs show that.
        with contextlib.nullcontext() if verbose else contextlib.redirect_stdout(io.StringIO()):
            super().__init__(env, train_cfg, log_dir=log_dir, device=device)
        self.log_dir = log_dir
        self.init_training_run(LearnerGuard(lambda: learner_tensors(self.alg)),
                               is_main=not self.is_distributed or self.gpu_global_rank == 0)

    @property
    def steps_per_env(self) -> int:
        return int(self.cfg["num_steps_per_env"])

    def current_learning_rate(self) -> float:
        return float(self.alg.learning_rate)

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
                self._save_every(it + 1, int(self.cfg["save_interval"]))
        except BaseException as err:
            self._save_interrupted(start_it, err)
            raise
        else:  # saved while the writer is open, so that W&B uploads the final checkpoint too
            self._save_last()
        finally:
            if writer is not None:
                writer.close()
                if isinstance(writer, LogWriter):
                    writer.stop()
                self.logger.writer = None

    def save(self, path: str, infos: dict | None = None) -> None:
        """rsl-rl-lib's checkpoint, written whole or not at all (a full disk leaves no truncated model_*.pt), with the
        run's env steps, from which a resumed run's count goes on; the upload (W&B) then sends the finished file."""
        state = {**self.alg.save(), "iter": self.current_learning_iteration,
                 "infos": {**(infos or {}), "env_steps": self.total_env_steps}}
        atomic_save(path, lambda partial: torch.save(state, partial))
        self.logger.save_model(path, self.current_learning_iteration)

    def _action_noise(self) -> dict[str, float]:
        """The policy's action noise as its parameters hold it after the update: the mean and the smallest standard
        deviation over the actions. The smallest is the one to watch: a few collapsed actions pin the KL-adaptive rate
        at its floor (ShadowHand, H100, 2026-11-26). One small read; empty for a policy without a state-independent
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
        collapsed with it in two seeds, H200, 2026-11-26), or, for a policy that has it already, a floor."""
        std_type = (self.cfg["actor"].get("distribution_cfg") or {}).get("std_type", "scalar")  # actor: checked
        if std_type == "log":
            return "+train.actor.distribution_cfg.std_range=[0.1,10.0]"
        return "train.actor.distribution_cfg.std_type=log"

    def _notice_noise_collapse(self, record: dict) -> None:
        it = record["iteration"] - 1
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
        self.candidates: list[str] = []  # the saved checkpoints that had the metric, in order

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
        """summary.json's "best_checkpoint" (None before any checkpoint had the metric)."""
        if self.value is None:
            return None
        return {"path": str(self.path), "iteration": self.iteration, "metric": self.key, "value": self.value,
                "copy_of": self.source}


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
