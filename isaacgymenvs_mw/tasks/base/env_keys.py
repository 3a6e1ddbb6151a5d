"""Reading VecTask's own keys of a task YAML's ``env`` section: the step's settings, the episode length, whole
numbers and positive numbers with their one-line errors, and IsaacGymEnvs keys that have no counterpart here."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Mapping

import torch

from isaacgymenvs_mw.sim import check_sim_keys, match_joint_numbers
from isaacgymenvs_mw.tasks.base.history import HistorySpec, parse_history
from isaacgymenvs_mw.utils.config import check_num_envs, real_number, whole_number
from isaacgymenvs_mw.utils.errors import ConfigError

# Episode-length keys of earlier versions and of IsaacGymEnvs' tasks (policy steps): refused, naming the new key.
OLD_EPISODE_KEYS = ("maxEpisodeLength", "episodeLength")


@dataclass(frozen=True)
class TaskSettings:
    """The keys of a task YAML that VecTask's construction reads (docs/config.md), checked."""

    num_envs: int  # env.numEnvs
    num_obs: int | None  # env.numObservations (0: derived from the task's declared terms)
    num_states: int | None  # env.numStates (None: absent)
    num_actions: int  # env.numActions
    control_freq_inv: int  # env.controlFrequencyInv
    clip_obs: float  # env.clipObservations
    clip_actions: float  # env.clipActions
    history: dict[str, HistorySpec]  # env.history
    render_interval: int  # env.renderInterval
    action_delay: int  # env.control.actionDelay (policy steps)
    overflow_check_interval: int  # sim.overflowCheckInterval
    observe_sensors: dict[str, float]  # env.observeSensors: {sensor name: scale}


def task_settings(config: Mapping, declares_layout: bool) -> TaskSettings:
    """The settings of a task's ``config`` (its ``env`` and ``sim`` sections), failing in one line naming the key.
    ``declares_layout``: the task declares observation terms, so ``env.numObservations`` may be left out."""
    env = config["env"]
    refuse_removed_keys(env)
    settings = TaskSettings(
        num_envs=check_num_envs(required(env, "numEnvs"), "env.numEnvs"),
        # A task that declares its observation terms derives these sizes; a YAML value must then agree.
        num_obs=require_int(env, "numObservations", minimum=1, default=0 if declares_layout else None),
        num_states=None if env.get("numStates") is None else require_int(env, "numStates", minimum=0),
        num_actions=require_int(env, "numActions", minimum=1),
        control_freq_inv=require_int(env, "controlFrequencyInv", minimum=1, default=1),
        clip_obs=positive_env_number(env, "clipObservations", math.inf),
        clip_actions=positive_env_number(env, "clipActions", math.inf),
        history=parse_history(env),
        render_interval=require_int(env, "renderInterval", minimum=1, default=1),
        action_delay=whole_number(env.get("control", {}).get("actionDelay", 0), "env.control.actionDelay", 0),
        overflow_check_interval=int(config.get("sim", {}).get("overflowCheckInterval", 500)),
        observe_sensors=observed_sensors(env.get("observeSensors")),
    )
    check_sim_keys(config.get("sim", {}))
    warn_unused_ige_keys(env)
    return settings



def observed_sensors(cfg: Mapping | None) -> dict[str, float]:
    """``env.observeSensors``: {sensor name: scale}, the sensors every task observes after its own terms (whether
    each is a sensor of the model is checked once the model is built). Empty or absent: none."""
    key = "env.observeSensors"
    if cfg is not None and not hasattr(cfg, "items"):
        raise ConfigError(f"{key}={cfg!r} is invalid: give a mapping {{sensor name: scale}}, e.g. {{imu: 1.0}}")
    return {str(name): real_number(scale, f"{key}.{name}") for name, scale in (cfg or {}).items()}

def joint_velocity_clamp(env: Mapping, dof_names: list[str], device: str) -> torch.Tensor | None:
    """``env.control.velocityClamp`` ({joint or regex: speed}, or one number for every joint) as a (joints,) tensor
    over the robot's ``dof_vel`` columns, inf for a joint it does not name; None when the key is absent.

    IsaacGymEnvs' DOF ``velocity`` property, as a clamp of the joint speed once per policy step (VecTask's
    after-physics phase), not PhysX's solver limit; docs/config.md."""
    value = env.get("control", {}).get("velocityClamp")
    if value is None:
        return None
    limits = match_joint_numbers(value, dof_names, "env.control.velocityClamp", low=0.0)
    return torch.tensor([limits.get(name, math.inf) for name in dof_names], dtype=torch.float32, device=device)


def episode_length(env: dict, control_dt: float, steps_in_code: int | None) -> tuple[int, float]:
    """``env.episodeLength_s`` -> (policy steps, seconds), rounded up (an episode never ends before the time asked
    for) after rounding off float noise, so that N steps given as N x control dt stay N steps. Seconds, not steps:
    the duration stays the same when sim.dt or controlFrequencyInv change. A ported task without the key may set
    ``max_episode_length`` (steps) in code before VecTask's constructor runs (``steps_in_code``)."""
    for old in OLD_EPISODE_KEYS:
        if old in env:
            try:
                hint = f"env.episodeLength_s: {float(env[old]) * control_dt:.6g}"
            except (TypeError, ValueError):
                hint = "env.episodeLength_s (seconds)"
            raise ConfigError(f"env.{old}={env[old]!r} is no longer read: give the episode length in seconds, "
                              f"{hint} ({env[old]} policy steps x control dt {control_dt:.6g} s)")
    seconds = env.get("episodeLength_s")
    if seconds is None:
        if steps_in_code is None:
            raise ConfigError("env.episodeLength_s is required in the task YAML: the episode length in seconds "
                              f"(policy steps x control dt {control_dt:.6g} s)")
        return int(steps_in_code), int(steps_in_code) * control_dt
    try:
        seconds = float(seconds)
    except (TypeError, ValueError):
        raise ConfigError(f"env.episodeLength_s={seconds!r} is invalid: give a number of seconds") from None
    steps = math.ceil(round(seconds / control_dt, 6)) if seconds > 0 else 0
    if steps < 2:
        raise ConfigError(f"env.episodeLength_s={seconds} is {steps} policy step(s) of {control_dt:.6g} s; give at "
                          f"least 2 steps ({2 * control_dt:.6g} s): an episode ends one step before the cap")
    return steps, seconds


# Keys that another key now says: refused, naming the one to use (one source for each fact).
REMOVED_ENV_KEYS = {
    "imageOutputs": "the policy observes the outputs its cameras render: set env.cameras.<name>.outputs",
}


def refuse_removed_keys(env: dict) -> None:
    """Fail, in one line, on an ``env`` key of ``REMOVED_ENV_KEYS``."""
    for key, instead in REMOVED_ENV_KEYS.items():
        if key in env:
            raise ConfigError(f"env.{key}={env[key]!r} is no longer read: {instead}")


IGE_UNUSED_ENV_KEYS = {
    "envSpacing": "each env is its own MuJoCo world, so there is no shared space to lay envs out in",
    "enableDebugVis": "there is no debug drawing (headless=False opens MuJoCo's viewer on env 0; capture_video records "
                      "it)",
    "enableCameraSensors": "IsaacGym's camera sensors are not made from this key",
    "aggregateMode": "PhysX aggregates (broad-phase groups of an actor's bodies) have no MuJoCo counterpart",
    "plane.staticFriction": "MuJoCo has one sliding friction per contact: set env.plane.friction",
    "plane.dynamicFriction": "MuJoCo has one sliding friction per contact: set env.plane.friction",
    "plane.restitution": "MuJoCo's contacts are soft constraints without a restitution coefficient",
}


def warn_unused_ige_keys(env: dict) -> list[str]:
    """Warn once, naming every ``IGE_UNUSED_ENV_KEYS`` key present in the ``env`` section; returns them."""
    present = []
    for key in IGE_UNUSED_ENV_KEYS:
        section, _, name = key.rpartition(".")
        node = env.get(section) if section else env
        if hasattr(node, "keys") and name in node:
            present.append(key)
    if present:
        warnings.warn("IsaacGymEnvs key(s) with no effect here: "
                      + "; ".join(f"env.{k} ({IGE_UNUSED_ENV_KEYS[k]})" for k in present)
                      + ". Remove them from the task YAML to silence this.", RuntimeWarning, stacklevel=4)
    return present


def refuse_reward_scale(task: str, env: dict) -> None:
    """``env.rewardScale`` moved to the learner recipe (IsaacGymEnvs' task YAMLs have no such key: its rl_games train
    YAML scales the reward), so that an IsaacGymEnvs train YAML sees IsaacGymEnvs' reward and scales it once."""
    if "rewardScale" in env:
        raise ConfigError(f"{task}: env.rewardScale={env['rewardScale']} is no longer a task key: the learner recipe "
                          "scales the reward (train.runner.reward_scale for rsl_rl, "
                          "train.params.config.reward_shaper.scale_value for rl_games); remove it from the task YAML")


def required(section: dict, key: str):
    """``env.<key>`` of the ``env`` section, which the task YAML must give."""
    if section.get(key) is None:
        raise ConfigError(f"env.{key} is required in the task YAML")
    return section[key]


def require_int(section: dict, key: str, minimum: int, default: int | None = None) -> int:
    if section.get(key) is None and default is not None:
        return default
    return whole_number(required(section, key), f"env.{key}", minimum)


def positive_env_number(section: dict, key: str, default: float) -> float:
    """``env.<key>`` of the ``env`` section as a float, ``default`` when absent; an error unless it is > 0."""
    value = section.get(key, default)
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"env.{key}={section[key]!r} is invalid: give a number > 0") from None
    if not value > 0:
        raise ConfigError(f"env.{key}={value} is invalid: give a number > 0 (inf for no clipping)")
    return value
