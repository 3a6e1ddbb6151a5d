"""What a task writes for VecTask, and the checks, made at construction, that it did.

A task writes, in torch on ``self.device``, the terms of VecTask's after-physics sequence, not the sequence:
  * ``pre_physics_step(a)``    -- turn clipped actions into actuator commands (``self.sim.ctrl``)
  * ``check_termination()``    -- the envs that failed this step (bool mask); default: none (time-outs only)
  * ``check_success()``        -- the envs that reached the goal this step (bool mask; default: none). Their
    episodes end, and the learner bootstraps them like time-outs: a reached goal is not a dead end, so ending
    there never costs the policy the reward it would have kept earning (without it, FrankaCabinet's policy learned
    to hold the drawer just short of open)
  * ``compute_reward()``       -- fill ``rew_buf`` (``tasks/base/rewards.py`` sums named terms)
  * ``reset_idx(env_mask)``    -- re-initialise the envs selected by a boolean mask of shape (num_envs,)
  * ``compute_observations()`` -- fill ``obs_buf`` (and ``states_buf`` when numStates > 0), or declare the terms
    (``observation_terms()``, ``state_terms()``, ``image_terms()``) that VecTask's observations compute
  * optional ``refresh_state()`` (quantities the terms read) and ``after_reset(new_episode)`` (per-step bookkeeping
    that must see the new episodes, e.g. commands resampled on a timer)
  * optional ``declared_metrics()`` -- what the task reports beyond its reward (``Metric(name, kind)``, recorded with
    ``self.metrics.record``; ``tasks/base/metrics.py``)
"""

from __future__ import annotations

from typing import Any

from isaacgymenvs_mw.utils.errors import ConfigError

# Hooks a task must write, and why VecTask cannot supply them.
REQUIRED_HOOKS = {
    "pre_physics_step": "it turns the policy's actions into actuator commands (self.sim.ctrl); only the task knows "
                        "what an action means",
    "compute_reward": "it fills rew_buf after the physics (VecTask's post_physics_step calls it after the "
                      "terminations and before the resets)",
    "compute_observations": "it fills obs_buf (and states_buf when numStates > 0); reset() and every step return "
                            "what it writes",
}


def hook_message(cls: type, name: str) -> str:
    return f"{cls.__name__} must implement {name}(): {REQUIRED_HOOKS[name]}"


def check_required_hooks(cls: type, base: type) -> None:
    """Fail, naming each, when task class ``cls`` leaves a required hook to ``base`` (VecTask). A ported
    ``post_physics_step`` computes the reward itself; declared observation terms compute the observation."""
    supplied = {"compute_reward": cls.post_physics_step is not base.post_physics_step,
                "compute_observations": cls.observation_terms is not base.observation_terms}
    missing = [name for name in REQUIRED_HOOKS
               if getattr(cls, name) is getattr(base, name) and not supplied.get(name, False)]
    if missing:
        raise NotImplementedError("; ".join(hook_message(cls, name) for name in missing))


def check_actuator_count(task: str, num_actions: int, sim: Any) -> None:
    """``env.numActions`` must equal the model's actuator count (``ctrl`` columns)."""
    nu = sim.num_actuators
    if nu == 0:
        raise ConfigError(
            f"{task}: env.numActions={num_actions} but the model has no actuators: give the asset's joints a drive "
            "(env.control.driveMode / defaultDriveMode) or use an MJCF with <actuator>"
        )
    if nu != num_actions:
        listing = [f"{a} -> {j}" for a, j in zip(sim.actuator_names, sim.actuator_joints)]
        raise ConfigError(
            f"{task}: env.numActions={num_actions} but the model has {nu} actuators "
            f"(ctrl columns, name -> joint: {listing}); set env.numActions: {nu}, or change the drives"
        )
