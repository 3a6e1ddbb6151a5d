"""What a training run reports, whichever learner updates the policy: each iteration's progress line, warnings and
TensorBoard scalars (``report_iteration``, from ``TrainingRun._log_iteration``), the diagnosis of a collapsed action
noise, and the device and versions that summary.json, eval.json and the benchmarks record."""

from __future__ import annotations

import json
import math
import os
import platform
import time
from importlib import metadata
from pathlib import Path
from typing import Callable

import torch

from isaacgymenvs_mw.learning.vecenv import METRIC_GROUP
from isaacgymenvs_mw.utils.files import atomic_save

# An action whose noise std is below this while the KL-adaptive rate sits at its floor has collapsed: moving its mean
# by 0.18 std (0.0018 here, under a thousandth of the [-1, 1] range) already spends a KL target of 0.016, so every
# update stops there and the other actions barely learn (ShadowHand's wrist on an H100).
NOISE_COLLAPSE_STD = 0.01

# Episode statistics that are counts of incidents, reported apart from the episodes' means.
INCIDENT_COUNTS = ("episodes", "nonfinite_resets", "nonfinite_inputs")


def report_iteration(writer, record: dict, stats: dict, losses: dict, health: dict[str, int], last_it: int,
                     eta: str, longest_episode: Callable[[], int], max_episode_length: int,
                     ended_before: bool, restored: str | None) -> None:
    """The iteration ``record`` (a history entry) on TensorBoard (``writer``, or None) and the console: incidents
    (worlds reset for NaN/inf, inputs replaced, optimiser steps skipped, a restored learner) and the progress line.
    ``stats``: the env's episode statistics of the iteration; ``health``: the run's totals so far
    (``TrainingRun.learner_health`` and ``nonfinite_resets``); ``longest_episode``: the longest running episode's
    steps, read only on an iteration where no episode ended; ``ended_before``: some earlier iteration ended one."""
    it = record["iteration"] - 1
    if writer is not None:
        write_scalars(writer, it, record, stats, losses, health)
    for line in incident_lines(record, stats, health, restored):
        print(line, flush=True)
    if stats["episodes"]:
        episodes = f"ep_rew {stats['mean_episode_reward']:9.2f} | ep_len {stats['mean_episode_length']:7.1f}"
        for key, value in stats.items():  # the metrics the task declares (e.g. a curriculum's terrain level)
            if key.startswith(METRIC_GROUP):
                episodes += f" | {key[len(METRIC_GROUP):]} {value:5.2f}"
    else:  # a host read, but only on iterations where no episode ended
        # "yet" only before the first episode end: later, a quiet iteration is one where every env is mid-episode
        # (e.g. time-outs of envs reset together), not a run that has never ended an episode.
        when = "this iteration" if ended_before else "yet"
        episodes = f"no episode ended {when} (longest {longest_episode()}/{max_episode_length} steps)"
    print(
        f"[it {it + 1:>5}/{last_it}] steps {record['env_steps']:>11,} | {record['steps_per_s']:>10,.0f} steps/s | "
        f"{episodes} | value_loss {losses.get('value', float('nan')):8.4f} | "
        f"collect {record['collect_s']:6.2f}s learn {record['learn_s']:5.2f}s | ETA {eta}",
        flush=True,
    )


def write_scalars(writer, it: int, record: dict, stats: dict, losses: dict, health: dict[str, int]) -> None:
    """The iteration's TensorBoard scalars: losses, learning rate, action noise, throughput, episode statistics (and
    the reward and length against training time), and the learner-health totals."""
    for key, value in losses.items():
        writer.add_scalar(f"Loss/{key}", value, it)
    writer.add_scalar("Loss/learning_rate", record["learning_rate"], it)
    if "action_std_mean" in record:
        writer.add_scalar("Policy/mean_std", record["action_std_mean"], it)
        writer.add_scalar("Policy/min_std", record["action_std_min"], it)
        writer.add_scalar("Policy/min_std_action", record["action_std_min_index"], it)
    writer.add_scalar("Perf/total_fps", record["steps_per_s"], it)
    writer.add_scalar("Perf/collection_time", record["collect_s"], it)
    writer.add_scalar("Perf/learning_time", record["learn_s"], it)
    for key, value in stats.items():
        if key in INCIDENT_COUNTS:
            continue
        tag = key if "/" in key else f"Train/{key}"
        writer.add_scalar(tag, value, it)
        if key in ("mean_episode_reward", "mean_episode_length"):
            writer.add_scalar(f"{tag}/time", value, int(record["time_s"]))
    writer.add_scalar("Sim/nonfinite_resets", health["nonfinite_resets"], it)
    writer.add_scalar("Learner/skipped_optimizer_steps", health["skipped_optimizer_steps"], it)
    writer.add_scalar("Learner/nonfinite_inputs", health["nonfinite_inputs"], it)
    writer.add_scalar("Learner/restores", health["learner_restores"], it)


def incident_lines(record: dict, stats: dict, health: dict[str, int], restored: str | None) -> list[str]:
    """The console lines of what went wrong in the iteration and was repaired, with the run's totals."""
    at = f"[it {record['iteration']:>5}]"
    lines = []
    if stats["nonfinite_resets"]:
        lines.append(f"{at} {int(stats['nonfinite_resets'])} env(s) had NaN/inf or diverged (a speed above 1e4) "
                     f"simulator state and were reset ({health['nonfinite_resets']} so far)")
    if stats.get("nonfinite_inputs"):
        lines.append(f"{at} {int(stats['nonfinite_inputs'])} observation(s) or reward(s) held NaN/inf and were "
                     f"replaced by 0 before the learner saw them ({health['nonfinite_inputs']} so far)")
    if record["skipped_optimizer_steps"]:
        lines.append(f"{at} {record['skipped_optimizer_steps']} optimiser step(s) skipped: their loss or gradient "
                     f"was not finite ({health['skipped_optimizer_steps']} so far)")
    if restored is not None:
        lines.append(f"{at} {restored}")
    return lines


def collapsed_noise(record: dict, adaptive: bool, floor: float, actuators: list[str] | None) -> dict | None:
    """The collapse the iteration ``record`` shows (see NOISE_COLLAPSE_STD), or None: the action whose noise std is
    below NOISE_COLLAPSE_STD while the learning rate, ``adaptive`` to a KL target, sits at its ``floor``; named by its
    actuator (``actuators``: the task's, in action order, where its actions are actuators)."""
    if not adaptive or "action_std_min" not in record or record["action_std_min"] >= NOISE_COLLAPSE_STD:
        return None
    if record["learning_rate"] > floor * (1.0 + 1e-6):
        return None
    index = record["action_std_min_index"]
    return {"iteration": record["iteration"], "action": index,
            "actuator": actuators[index] if actuators else None, "std": record["action_std_min"],
            "mean_std": record["action_std_mean"], "learning_rate": record["learning_rate"]}


def noise_collapse_line(collapse: dict, lever: str) -> str:
    """The console line that reports ``collapse`` (``collapsed_noise``) and the override to try first."""
    which = f"action {collapse['action']}" + (f" ({collapse['actuator']})" if collapse["actuator"] else "")
    return (f"[it {collapse['iteration']:>5}] the action noise has collapsed: {which} has a std of "
            f"{collapse['std']:.4f} (mean over the actions {collapse['mean_std']:.3g}) while the adaptive learning "
            f"rate sits at its floor ({collapse['learning_rate']:.0e}), so each update spends the KL target on that "
            f"action alone. If the curve flattens short of the goal, see the README's levers (e.g. {lever})")


class FirstCollectProgress:
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
        print(f"[it {self.iteration:>5}] collecting: env step {step}/{self.steps} after {duration(spent)}, "
              f"about {duration(left)} more before the update", flush=True)


def steady_iteration_s(history: list[dict]) -> float:
    """Mean seconds per iteration without this run's first one (Warp and torch.compile compile during it, which
    made a Go1Terrain ETA read 8h10m), or NaN while only the first has run."""
    steady = history[1:]
    if not steady:
        return float("nan")
    return sum(r["collect_s"] + r["learn_s"] for r in steady) / len(steady)


def duration(seconds: float) -> str:
    """Seconds as 42s, 3m05s or 1h02m ('--' when not known yet)."""
    if not math.isfinite(seconds):
        return "--"
    s = int(round(seconds))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


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


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` as JSON whole or not at all: a reader, or a process writing the same file, never sees half."""
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(data, indent=2, sort_keys=False) + "\n"
    atomic_save(path, lambda partial: Path(partial).write_text(text))
