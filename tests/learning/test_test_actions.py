"""Test mode's actions (runner.test_actions for rsl_rl): the policy's mean, or draws from its Gaussian, as
IsaacGymEnvs' player draws them for AllegroKuka (its player.deterministic False)."""

from __future__ import annotations

import pytest
import torch

from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError


def _cartpole_runner(test_actions: str):
    from isaacgymenvs_mw.learning.learners import learner_for
    from isaacgymenvs_mw.tasks.build import build_task

    cfg = compose_config(["task=Cartpole", "num_envs=64", "sim_device=cpu", "rl_device=cpu", "headless=True",
                          f"++train.runner.test_actions={test_actions}"])
    learner = learner_for(cfg)
    learner.check()
    task = build_task(cfg)
    make_runner, _ = learner.runner_factory(task)
    return task, make_runner()


def test_sampled_test_actions_are_the_mean_plus_std_times_a_normal_draw():
    task, runner = _cartpole_runner("sampled")
    assert runner.test_actions == "sampled"
    actor = runner.alg.get_policy()
    with torch.no_grad():
        actor.distribution.std_param.fill_(0.3)  # rsl-rl-lib's scalar std: the draws' spread
    obs = task.reset()
    from tensordict import TensorDict

    obs = TensorDict({"policy": obs["obs"]}, batch_size=[64])
    policy = runner.get_inference_policy("cpu")
    torch.manual_seed(5)
    with torch.no_grad():
        drawn = policy(obs)
        mean = actor(obs)
    torch.manual_seed(5)
    want = mean + 0.3 * torch.randn_like(mean)  # the same draw, from the same seed
    torch.testing.assert_close(drawn, want)
    spread = (drawn - mean) / 0.3
    assert abs(float(spread.mean())) < 0.3 and 0.7 < float(spread.std()) < 1.3


def test_mean_test_actions_by_default_and_allegro_kuka_samples_as_isaacgymenvs():
    task, runner = _cartpole_runner("mean")
    obs = task.reset()
    from tensordict import TensorDict

    obs = TensorDict({"policy": obs["obs"]}, batch_size=[64])
    policy = runner.get_inference_policy("cpu")
    with torch.no_grad():
        torch.testing.assert_close(policy(obs), policy(obs))  # no draw
    for name in ("AllegroKuka", "AllegroKukaRegrasping", "AllegroKukaThrow"):
        assert compose_config([f"task={name}"]).train.runner.test_actions == "sampled"
    assert "test_actions" not in compose_config(["task=AllegroHand"]).train.runner


def test_bad_test_actions_is_one_line(tmp_path, run_args):
    with pytest.raises(ConfigError, match=r"train\.runner\.test_actions='random' is invalid: choose one of"):
        run(compose_config(["task=Cartpole", "++train.runner.test_actions=random", *run_args]))
