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
