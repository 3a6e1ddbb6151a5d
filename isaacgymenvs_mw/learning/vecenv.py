"""VecTask -> a learner's env: the set-up and step record every adapter shares (``TaskEnv``: task facts, per-episode
statistics kept on the device and read once per iteration, NaN counts) and rsl_rl's VecEnv (``RslRlVecEnv``)."""

from __future__ import annotations

import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, RUNNING
from isaacgymenvs_mw.tasks.base.vec_task import VecTask

# The task's declared metrics (tasks/base/metrics.py) of kinds EPISODE_SUM (sums over the episodes that ended in a
# step) and RUNNING (device scalars the task keeps, at their value when the iteration's statistics are read) are
# logged as Episode/<name> in TensorBoard and the history, shown on the progress line, and written to summary.json by
# name; per-term reward sums (``extras["episode_terms"]``) as Episode_Reward/<name>.
METRIC_GROUP = "Episode/"


def training_metric_keys(task: VecTask) -> list[str]:
    """The history keys of the metrics the task declares for training (EPISODE_SUM and RUNNING), in their order,
    after the task's ``primary_metric`` when it names one (summary.json's "metrics")."""
    declared = [METRIC_GROUP + m.name for m in task.metrics.declared if m.kind in (EPISODE_SUM, RUNNING)]
    return ([task.primary_metric] if task.primary_metric else []) + declared


def success_metric_key(task: VecTask) -> str | None:
    """The history key of the task's declared success: its ``primary_metric``, else its first ``Metric(success=True)``
    of a training kind (EPISODE_SUM, RUNNING), else None. What ``sweep_metric=auto`` follows (save_best, sweeps)."""
    if task.primary_metric:
        return task.primary_metric
    return next((METRIC_GROUP + m.name for m in task.metrics.declared
                 if m.success and m.kind in (EPISODE_SUM, RUNNING)), None)


class EpisodeStats:
    """Sums over finished episodes, accumulated with tensor ops only; ``pop()`` syncs once and clears."""

    def __init__(self, num_envs: int, device: str) -> None:
        self.ret = torch.zeros(num_envs, device=device)
        self.length = torch.zeros(num_envs, device=device)
        # [count, return sum, length sum, timeouts, worlds reset for NaN/inf state]
        self.totals = torch.zeros(5, device=device, dtype=torch.float64)
        self._terms: dict[tuple[str, ...], torch.Tensor] = {}  # names -> accumulated sums
        self._running: dict[str, torch.Tensor] = {}  # name -> the task's running value (a device scalar)
        # name -> a device counter the task increments inside its step; read and zeroed by pop()
        self._counters: dict[str, torch.Tensor] = {}

    def record(self, rewards: torch.Tensor, dones: torch.Tensor, time_outs: torch.Tensor,
               nonfinite: torch.Tensor) -> None:
        self.ret += rewards
        self.length += 1
        done = dones.float()
        self.totals += torch.stack(
            (done.sum(), (self.ret * done).sum(), (self.length * done).sum(), (time_outs.float() * done).sum(),
             nonfinite.float().sum())
        ).double()
        keep = 1.0 - done
        self.ret *= keep
        self.length *= keep

    def add_terms(self, episode_terms: dict[str, torch.Tensor], group: str = "Episode_Reward") -> None:
        """Task-reported sums over the episodes that ended this step (already summed over envs); logged per
        episode as ``<group>/<name>``."""
        names = tuple(f"{group}/{k}" for k in episode_terms)
        values = torch.stack(tuple(episode_terms.values())).double()
        if names in self._terms:
            self._terms[names] += values
        else:
            self._terms[names] = values  # a fresh tensor from torch.stack, owned here

    def set_running(self, metrics: dict[str, torch.Tensor], group: str) -> None:
        """Task-kept running values (device scalars), reported as ``<group>/<name>`` at their latest value."""
        for key, value in metrics.items():
            self._running[f"{group}/{key}"] = value

    def count(self, name: str, counter: torch.Tensor) -> None:
        """Report ``counter`` (a device scalar the task adds to, e.g. inside a captured step) as ``name`` at each
        ``pop``, which zeroes it: counted for free in the step, read with the iteration's one host read."""
        self._counters[name] = counter.reshape(())  # a view: a (1,) counter reads and zeroes as a scalar

    def pop(self) -> dict[str, float]:
        # The running values and counters come back with the totals, in the same device-to-host read.
        names, counters = list(self._running), list(self._counters)
        extra = [self._running[k] for k in names] + [self._counters[k] for k in counters]
        values = self.totals if not extra else torch.cat((self.totals, torch.stack(extra).double()))
        count, ret, length, timeouts, nonfinite, *rest = values.tolist()
        latest, counted = rest[:len(names)], rest[len(names):]
        for counter in self._counters.values():
            counter.zero_()
        out = {"episodes": count, "nonfinite_resets": nonfinite, **dict(zip(counters, counted)),
               **dict(zip(names, latest))}
        if count > 0:
            out.update(
                mean_episode_reward=ret / count,
                mean_episode_length=length / count,
                timeout_fraction=timeouts / count,
            )
            for names, acc in self._terms.items():
                for key, value in zip(names, acc.tolist()):
                    out[key] = value / count
        self.totals.zero_()
        self._terms = {}  # made afresh inside the next rollout's inference mode
        return out


def record_step(stats: EpisodeStats, task: VecTask, rew: torch.Tensor, reset: torch.Tensor, extras: dict) -> None:
    """Add one env step's outcome to ``stats``: episode returns and lengths, time-outs, the task's reward terms and
    declared metrics (every learner's env adapter calls this after ``task.step``)."""
    # "time_outs" also holds the successes, which the learner bootstraps alike; the statistics count time-outs.
    time_outs = extras["time_outs"] & ~extras["successes"] if "successes" in extras else extras["time_outs"]
    stats.record(rew, reset, time_outs, extras["nonfinite_resets"])
    if "episode_terms" in extras:  # tasks that report them set them every step
        stats.add_terms(extras["episode_terms"])
    sums, running = task.metrics.recorded(EPISODE_SUM), task.metrics.recorded(RUNNING)
    if sums:  # e.g. the terrain curriculum's level
        stats.add_terms(sums, group=METRIC_GROUP.rstrip("/"))
    if running:
        stats.set_running(running, group=METRIC_GROUP.rstrip("/"))


class TaskEnv:
    """What every learner's env adapter shares: the task's facts (envs, actions, episode length, device), the
    episode statistics with the task's count of non-finite inputs, the recipe's reward scale, and a task step that
    records its outcome. ``reward_scale``: the recipe's factor on the task's reward; the statistics report the
    scaled reward, the one the learner learns from."""

    def __init__(self, task: VecTask, reward_scale: float = 1.0) -> None:
        self.task = task
        self.reward_scale = float(reward_scale)
        self.num_envs = task.num_envs
        self.num_actions = task.num_actions
        self.max_episode_length = task.max_episode_length
        self.device = task.rl_device
        self.stats = EpisodeStats(task.num_envs, task.rl_device)
        self.stats.count("nonfinite_inputs", task.nonfinite_inputs_count)

    @property
    def episode_length_buf(self) -> torch.Tensor:
        return self.task.progress_buf

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        self.task.progress_buf.copy_(value)

    def step_task(self, actions: torch.Tensor) -> tuple[dict, torch.Tensor, torch.Tensor, torch.Tensor, dict]:
        """One task step, recorded in the statistics: the obs dict, the task's reward, the reward scaled by
        ``reward_scale``, the resets and the extras."""
        obs_dict, rew, reset, extras = self.task.step(actions)
        scaled = rew * self.reward_scale if self.reward_scale != 1.0 else rew
        record_step(self.stats, self.task, scaled, reset, extras)
        return obs_dict, rew, scaled, reset, extras


class RslRlVecEnv(TaskEnv, VecEnv):
    """Presents a VecTask to rsl_rl: TensorDict groups 'policy' (obs), 'critic' (states; obs if numStates is 0) and,
    for a task with image terms, 'camera' ((num_envs, C, H, W) uint8; ``learning/models.py`` scales it).
    ``reward_scale``: the recipe's factor on the task's reward (``train.runner.reward_scale``), applied before the
    learner and the episode statistics see it."""

    def __init__(self, task: VecTask, reward_scale: float = 1.0) -> None:
        super().__init__(task, reward_scale)
        self.cfg = task.cfg
        self._obs = self._to_tensordict(task.reset())

    def _to_tensordict(self, obs_dict: dict[str, torch.Tensor]) -> TensorDict:
        # "critic" always exists, so one train YAML serves with and without privileged states (numStates 0).
        groups = {"policy": obs_dict["obs"], "critic": obs_dict.get("states", obs_dict["obs"])}
        if "camera" in obs_dict:
            groups["camera"] = obs_dict["camera"]
        return TensorDict(groups, batch_size=[self.num_envs], device=self.device)

    def get_observations(self) -> TensorDict:
        return self._obs

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        obs_dict, _, rew, reset, extras = self.step_task(actions)
        self._obs = self._to_tensordict(obs_dict)
        return self._obs, rew, reset, extras

    def close(self) -> None:
        self.task.close()
