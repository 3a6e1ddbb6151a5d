"""The one reward-scale convention of new tasks, ``env.rewards.scales`` ({term: scale}), and IsaacGymEnvs' flat
``<name>RewardScale`` keys a port may keep: both read by ``RewardTerms.from_env`` into the same weighted sum."""

from __future__ import annotations

import pytest
import torch

from isaacgymenvs_mw.tasks.base.rewards import RewardTerms
from isaacgymenvs_mw.utils.errors import ConfigError

N = 4


class TwoTerms:
    """A task's reward methods, with values chosen so that every weighted sum below is exact in float32."""

    def _reward_reach(self) -> torch.Tensor:
        return torch.tensor([1.0, 2.0, 0.5, 0.0])

    def _reward_effort(self) -> torch.Tensor:
        return torch.tensor([4.0, 0.0, 2.0, 1.0])


def total(terms: RewardTerms) -> torch.Tensor:
    return terms.compute(torch.zeros(N, dtype=torch.bool))


def test_new_tasks_give_their_scales_as_env_rewards_scales():
    env = {"rewards": {"scales": {"reach": 2.0, "effort": -0.25}}}
    terms = RewardTerms.from_env(TwoTerms(), env, N, "cpu")
    assert terms.names == ["reach", "effort"]
    assert torch.equal(total(terms), torch.tensor([2.0 - 1.0, 4.0, 1.0 - 0.5, -0.25]))


def test_a_zero_scale_leaves_its_term_out():
    terms = RewardTerms.from_env(TwoTerms(), {"rewards": {"scales": {"reach": 1.0, "effort": 0.0}}}, N, "cpu")
    assert terms.names == ["reach"]


def test_a_port_reads_isaacgymenvs_flat_keys_into_the_same_sum():
    env = {"reachRewardScale": 2.0, "effortPenaltyScale": -0.25}
    flat = RewardTerms.from_env(TwoTerms(), env, N, "cpu",
                                ige_keys={"reach": "reachRewardScale", "effort": "effortPenaltyScale"})
    nested = RewardTerms.from_env(TwoTerms(), {"rewards": {"scales": {"reach": 2.0, "effort": -0.25}}}, N, "cpu")
    assert torch.equal(total(flat), total(nested))


def test_the_constructor_options_pass_through():
    env = {"rewards": {"scales": {"reach": 2.0, "effort": -0.25}}}
    terms = RewardTerms.from_env(TwoTerms(), env, N, "cpu", dt=0.5, only_positive=True)
    # (2 x reach - 0.25 x effort) x 0.5, clamped at 0
    assert torch.equal(total(terms), torch.tensor([0.5, 2.0, 0.25, 0.0]))


@pytest.mark.parametrize("env,ige_keys,message", [
    ({"rewards": {"scales": {"reach": "far"}}}, None,
     "env.rewards.scales.reach='far' is invalid: give a finite number"),
    ({"rewards": {}}, None, "env.rewards.scales is required: give {term: scale} (terms: ['effort', 'reach'])"),
    ({"reachRewardScale": 1.0}, {"reach": "reachRewardScale", "effort": "effortPenaltyScale"},
     "env.effortPenaltyScale is required: give the scale of the reward term effort"),
    ({"rewards": {"scales": {"speed": 1.0}}}, None,
     "env.rewards.scales.speed: unknown reward term (all unknown: ['speed']); available terms: ['effort', 'reach']"),
])
def test_bad_scales_fail_in_one_line_naming_the_key(env, ige_keys, message):
    with pytest.raises(ConfigError) as err:
        RewardTerms.from_env(TwoTerms(), env, N, "cpu", ige_keys=ige_keys)
    assert str(err.value) == message


# reward_shaper.scale_value of IsaacGymEnvs' <Task>PPO.yaml (isaac-sim/IsaacGymEnvs, isaacgymenvs/cfg/train)
IGE_SHAPER_SCALE = {"Ant": 0.01, "Humanoid": 0.01, "FrankaCabinet": 0.01, "AllegroHand": 0.01, "ShadowHand": 0.01}


@pytest.mark.parametrize("task", sorted(IGE_SHAPER_SCALE))
def test_the_rsl_rl_recipe_scales_the_reward_as_isaacgymenvs_train_yaml_does(task):
    """The task YAML holds IsaacGymEnvs' reward unscaled; the rsl_rl recipe's runner.reward_scale is the factor
    IsaacGymEnvs' rl_games YAML put on it (issue 70)."""
    from isaacgymenvs_mw.learning.train_config import recipe_reward_scale
    from isaacgymenvs_mw.utils.config import compose_config, to_dict

    cfg = compose_config([f"task={task}"])
    assert "rewardScale" not in cfg.task.env
    assert recipe_reward_scale(to_dict(cfg.train)) == IGE_SHAPER_SCALE[task]


def test_the_env_adapter_gives_ppo_the_task_reward_times_the_recipe_scale():
    from isaacgymenvs_mw import make
    from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv

    task = make("Ant", num_envs=3, sim_device="cpu", rl_device="cpu", seed=0)
    env = RslRlVecEnv(task, reward_scale=0.01)
    _, rew, _, _ = env.step(torch.rand(3, task.num_actions) * 2 - 1)
    torch.testing.assert_close(rew, task.rew_buf * 0.01)
    assert not torch.equal(rew, task.rew_buf)


def test_env_reward_scale_in_a_task_yaml_says_where_the_factor_went():
    from isaacgymenvs_mw import make
    from isaacgymenvs_mw.utils.errors import ConfigError

    with pytest.raises(ConfigError, match=r"^Ant: task\.env\.rewardScale=0\.01 is no longer a task key: the learner "
                                          r"recipe scales the reward \(train\.runner\.reward_scale"):
        make("Ant", num_envs=2, sim_device="cpu", rl_device="cpu", overrides=["+task.env.rewardScale=0.01"])
