"""The AMP learner feature (learning/amp.py) against formulas written here (issue 73)."""

from __future__ import annotations

import math

import pytest
import torch
from conftest import tensorboard_scalars

from isaacgymenvs_mw.learning.amp import (
    AMPConfig,
    AMPVecEnv,
    Discriminator,
    ReplayBuffer,
    discriminator_loss,
    style_reward,
    with_amp,
)
from isaacgymenvs_mw.learning.vecenv import EpisodeStats
from isaacgymenvs_mw.utils.errors import ConfigError


def test_style_reward_formula():
    d = torch.tensor([-3.0, -1.0, 0.0, 1.0, 2.5, 4.0])
    want = [max(0.0, 1.0 - 0.25 * (x - 1.0) ** 2) * 2.0 for x in d.tolist()]
    torch.testing.assert_close(style_reward(d, "lsgan", 2.0), torch.tensor(want))
    p = torch.sigmoid(d)
    torch.testing.assert_close(style_reward(d, "bce", 2.0), -2.0 * torch.log(torch.clamp(1 - p, min=1e-4)))


def test_humanoid_amp_learner_is_iges():
    """The shipped HumanoidAMPPPO's discriminator is IGE's (isaacgymenvs/learning/amp_continuous.py): BCE, and the
    style reward of a logit d is 2 (disc_reward_scale) x -ln(max(1 - 1 / (1 + e^-d), 1e-4)), worked out here with
    math, not torch. It pays for every transition, also those D scores as the policy's (d <= -1), where the
    paper's least-squares reward is 0: an episode that lasts longer earns more."""
    from isaacgymenvs_mw.utils.config import compose_config, to_dict

    train = to_dict(compose_config(["task=HumanoidAMP"]).train)
    env = with_amp(_Env(), train)
    assert env.amp_cfg.loss == "bce" and env.amp_cfg.disc_reward_scale == 2.0
    logits = [-6.0, -3.0, -1.0, 0.0, 1.5, 12.0]
    want = [-2.0 * math.log(max(1.0 - 1.0 / (1.0 + math.exp(-x)), 1e-4)) for x in logits]
    got = style_reward(torch.tensor(logits), env.amp_cfg.loss, env.amp_cfg.disc_reward_scale)
    torch.testing.assert_close(got, torch.tensor(want))
    assert (got[:3] > 0).all()
    # the discriminator loss is BCE on the logits (motion 1, policy 0), halved as IGE halves it
    torch.manual_seed(0)
    disc = Discriminator(3, (8,), "relu")
    policy, motion = torch.randn(6, 3), torch.randn(5, 3)
    cfg = AMPConfig(loss=env.amp_cfg.loss, hidden_dims=(8,), grad_penalty=0.0, logit_reg=0.0, weight_decay=0.0)
    with torch.no_grad():
        p_motion, p_policy = torch.sigmoid(disc(motion)), torch.sigmoid(disc(policy))
        bce = 0.5 * (-torch.log(p_motion).mean() - torch.log(1 - p_policy).mean())
    torch.testing.assert_close(discriminator_loss(disc, policy, motion, cfg)["loss"].detach(), bce)


def test_discriminator_loss_formula():
    torch.manual_seed(0)
    cfg = AMPConfig(hidden_dims=(8,), grad_penalty=5.0, logit_reg=0.05, weight_decay=1e-4)
    disc = Discriminator(3, cfg.hidden_dims, "tanh")
    policy, motion = torch.randn(6, 3), torch.randn(5, 3)
    parts = discriminator_loss(disc, policy, motion, cfg)
    # by hand: tanh layer then a linear logit, its input gradient W2 diag(1 - h^2) W1
    w1, b1, w2, b2 = disc.trunk[0].weight, disc.trunk[0].bias, disc.logit.weight, disc.logit.bias
    with torch.no_grad():
        def d_of(x):
            return (torch.tanh(x @ w1.T + b1) @ w2.T + b2).squeeze(-1)
        h = torch.tanh(motion @ w1.T + b1)
        grad = ((1 - h ** 2) * w2) @ w1
        want = (0.5 * (((d_of(motion) - 1) ** 2).mean() + ((d_of(policy) + 1) ** 2).mean())
                + 5.0 * (grad ** 2).sum(-1).mean() + 0.05 * (w2 ** 2).sum()
                + 1e-4 * ((w1 ** 2).sum() + (w2 ** 2).sum()))
    torch.testing.assert_close(parts["loss"].detach(), want)
    parts["loss"].backward()  # the penalty's graph is differentiable
    assert w1.grad is not None and torch.isfinite(w1.grad).all()


def test_replay_buffer_ring_and_keep_prob():
    buf = ReplayBuffer(5, 1, "cpu", keep_prob=0.0)
    buf.store(torch.arange(3.0).view(-1, 1))
    assert buf.count == 3
    buf.store(torch.arange(3.0, 7.0).view(-1, 1))  # not yet full: all kept, the ring wraps
    assert buf.count == 5 and sorted(buf.data.flatten().tolist()) == [2.0, 3.0, 4.0, 5.0, 6.0]
    buf.store(torch.full((4, 1), 9.0))  # full, keep_prob 0: nothing new
    assert 9.0 not in buf.data.flatten().tolist()


class _Task:
    num_envs = 4

    def __init__(self):
        self.amp_obs = torch.zeros(4, 3)

    def fetch_amp_obs_demo(self, n):
        return torch.ones(n, 3)


class _Env:
    device = "cpu"

    def __init__(self):
        self.task = _Task()
        self.stats = EpisodeStats(4, "cpu")

    def step(self, actions):
        self.task.amp_obs = torch.randn(4, 3) * 0.1
        return {}, torch.full((4,), 0.5), torch.zeros(4, dtype=torch.bool), {
            "nonfinite_resets": torch.tensor([False, False, False, True])}


def test_wrapper_mixes_rewards_and_trains_each_rollout():
    torch.manual_seed(0)
    train = {"runner": {"num_steps_per_env": 2},
             "amp": {"task_reward_w": 0.5, "disc_reward_w": 2.0, "hidden_dims": [16], "minibatch_size": 8,
                     "updates_per_rollout": 3, "replay_buffer_size": 64, "learning_rate": 1e-3}}
    env = with_amp(_Env(), train)
    assert isinstance(env, AMPVecEnv)
    before = [p.clone() for p in env.disc.parameters()]
    _, rew, _, _ = env.step(torch.zeros(4, 1))
    with torch.no_grad():
        d = env.disc(env.norm(env.task.amp_obs))
    want = 0.5 * 0.5 + 2.0 * style_reward(d, "lsgan", 2.0)
    want[3] = 0.25  # a blown-up world gets no style reward
    torch.testing.assert_close(rew, want)
    assert all(torch.equal(a, b) for a, b in zip(before, env.disc.parameters()))  # no update mid-rollout
    env.step(torch.zeros(4, 1))
    assert not all(torch.equal(a, b) for a, b in zip(before, env.disc.parameters()))
    assert env.replay.count == 8
    assert "AMP/disc_loss" in env.stats.pop()


def test_test_mode_scores_average_the_first_episodes_and_the_motions():
    """AMPScores: the discriminator's logit and style reward averaged over the transitions of envs still in their first
    episode, and over motion samples; here D(x) = x0 + x1 + x2 - 1 for x >= 0, so the means are worked out by hand."""
    train = {"runner": {"num_steps_per_env": 2},
             "amp": {"hidden_dims": [4], "normalize_input": False, "loss": "bce", "disc_reward_scale": 2.0}}
    env = with_amp(_Env(), train)
    with torch.no_grad():
        for layer in (env.disc.trunk[0], env.disc.logit):
            layer.weight.zero_()
            layer.bias.zero_()
        env.disc.trunk[0].weight[0] = 1.0  # the first hidden unit sums the inputs
        env.disc.logit.weight[0, 0] = 1.0
        env.disc.logit.bias.fill_(-1.0)
    scores = env.test_mode_scores()
    env.task.amp_obs = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [1.0, 1.0, 1.0]])
    scores.observe(torch.tensor([True, True, True, True]))  # logits -1, 0, 1, 2
    env.task.amp_obs = torch.full((4, 3), 0.5)
    scores.observe(torch.tensor([False, True, False, False]))  # logit 0.5, env 1 only
    got = scores.result()
    logits = [-1.0, 0.0, 1.0, 2.0, 0.5]
    reward = [-2.0 * math.log(max(1.0 - 1.0 / (1.0 + math.exp(-x)), 1e-4)) for x in logits]
    assert got["amp_d_policy"] == pytest.approx(sum(logits) / 5)
    assert got["amp_style_reward_policy"] == pytest.approx(sum(reward) / 5, rel=1e-6)
    # the fake motion library returns ones: logit 2 for each of the 5 samples drawn
    assert got["amp_d_motion"] == pytest.approx(2.0)
    assert got["amp_style_reward_motion"] == pytest.approx(-2.0 * math.log(1.0 - 1.0 / (1.0 + math.exp(-2.0))))


def test_bad_amp_settings_name_the_key():
    with pytest.raises(ConfigError, match=r"train\.amp\.loss"):
        with_amp(_Env(), {"runner": {"num_steps_per_env": 2}, "amp": {"loss": "wgan"}})
    with pytest.raises(ConfigError, match=r"train\.amp: unknown key"):
        with_amp(_Env(), {"runner": {"num_steps_per_env": 2}, "amp": {"disc_coef": 5}})
    plain = _Env()
    assert with_amp(plain, {"runner": {"num_steps_per_env": 2}}) is plain


def test_two_training_iterations_with_amp(tmp_path):
    """HumanoidAMP trains 2 rsl-rl iterations through the wrapper; the discriminator learns once per rollout."""
    import isaacgymenvs_mw
    from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
    from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
    from isaacgymenvs_mw.utils.config import compose_config, to_dict

    train = to_dict(compose_config(["task=HumanoidAMP"]).train)
    train["runner"].update(num_steps_per_env=4, max_iterations=2, logger="tensorboard")
    for part in ("actor", "critic"):
        train[part]["hidden_dims"] = [32, 32]
    train["amp"].update(hidden_dims=[32], minibatch_size=16, updates_per_rollout=2, replay_buffer_size=256)
    task = isaacgymenvs_mw.make(task="HumanoidAMP", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True)
    env = with_amp(RslRlVecEnv(task), train)
    cfg = rsl_rl_config(train)
    cfg.pop("max_iterations")
    before = [p.clone() for p in env.disc.parameters()]
    runner = Runner(env, cfg, log_dir=None, device="cpu")
    runner.learn(2)
    assert env.replay.count == 2 * 4 * 2
    assert not all(torch.equal(a, b) for a, b in zip(before, env.disc.parameters()))
    # IGE's HumanoidAMPPPO: fixed_sigma with sigma_init -2.9, so the policy's std is exp(-2.9) after learning too
    std = runner.alg.actor.distribution.std_param
    torch.testing.assert_close(std.detach(), torch.full_like(std, math.exp(-2.9)), rtol=0, atol=1e-4)
    assert runner.alg.bounds_loss_coef == 10.0  # IGE's bounds_loss_coef


def test_train_py_switches_amp_on_from_the_train_yaml(tmp_path, run_args):
    """launch.run (train.py's path) wraps the env when the train YAML has an amp section: the discriminator's loss and
    the style reward reach TensorBoard once per iteration, the style reward within IGE's BCE reward's range."""
    from isaacgymenvs_mw.learning.launch import run
    from isaacgymenvs_mw.utils.config import compose_config

    small = ["train.runner.num_steps_per_env=4", "train.amp.hidden_dims=[32]", "train.amp.minibatch_size=16",
             "train.amp.updates_per_rollout=2", "train.actor.hidden_dims=[32]", "train.critic.hidden_dims=[32]"]
    assert run(compose_config(["task=HumanoidAMP", "num_envs=2", "max_iterations=2", *small, *run_args]))
    (run_dir,) = (tmp_path / "runs" / "HumanoidAMP").iterdir()
    scalars = tensorboard_scalars(run_dir)
    assert [step for step, _ in scalars["AMP/disc_loss"]] == [0, 1]
    # IGE's BCE style reward: scale x -log(max(1 - sigmoid(D), 1e-4)), between 0 and 2 ln(1e4)
    assert all(0.0 <= value <= 2.0 * math.log(1e4) for _, value in scalars["AMP/style_reward"])
    # test mode from the run's checkpoint (the discriminator in it is loaded and left alone)
    result = run(compose_config(["task=HumanoidAMP", "num_envs=2", "test=True", f"checkpoint={run_dir / 'model_2.pt'}",
                                 "task.env.episodeLength_s=0.5", *small, *run_args]))
    assert result["episodes"] == 2
    # and its discriminator's scores on the policy's transitions and on the motions, in IGE's BCE reward's range
    assert all(0.0 <= result[f"amp_style_reward_{who}"] <= 2.0 * math.log(1e4) for who in ("policy", "motion"))
    assert math.isfinite(result["amp_d_policy"]) and math.isfinite(result["amp_d_motion"])


def test_a_checkpoint_keeps_the_discriminator_and_a_resumed_run_gets_it_back(tmp_path):
    """The runner's checkpoint holds the AMP wrapper's discriminator, optimiser and input statistics; a new run that
    loads the checkpoint starts from the same discriminator, not a new one."""
    import isaacgymenvs_mw
    from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
    from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
    from isaacgymenvs_mw.utils.config import compose_config, to_dict

    train = to_dict(compose_config(["task=HumanoidAMP"]).train)
    train["runner"].update(num_steps_per_env=4, max_iterations=1)
    for part in ("actor", "critic"):
        train[part]["hidden_dims"] = [32]
    train["amp"].update(hidden_dims=[32], minibatch_size=16, updates_per_rollout=2, replay_buffer_size=256)
    cfg = rsl_rl_config(train)
    cfg.pop("max_iterations")

    def runner_on_new_task():
        task = isaacgymenvs_mw.make(task="HumanoidAMP", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True)
        env = with_amp(RslRlVecEnv(task), train)
        return task, env, Runner(env, cfg, log_dir=None, device="cpu")

    _, trained_env, trained = runner_on_new_task()
    trained.learn(1)
    trained.save(str(tmp_path / "model_1.pt"))
    task, fresh_env, fresh = runner_on_new_task()
    assert not all(torch.equal(a, b) for a, b in zip(trained_env.disc.parameters(), fresh_env.disc.parameters()))
    fresh.load_checkpoint(tmp_path / "model_1.pt", task)
    for a, b in zip(trained_env.disc.parameters(), fresh_env.disc.parameters()):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    torch.testing.assert_close(fresh_env.norm.mean, trained_env.norm.mean, rtol=0, atol=0)
    assert fresh_env.optimizer.state_dict()["state"].keys() == trained_env.optimizer.state_dict()["state"].keys()


def test_motion_match_diagnostic_statistics():
    """benchmarks/diagnostics/amp_motion_match.py's per-group statistics, against numpy: a policy shifted by half a
    unit in one group and twice as spread in the other."""
    import sys
    from pathlib import Path

    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks" / "diagnostics"))
    from amp_motion_match import feature_match

    torch.manual_seed(0)
    motion = torch.randn(4000, 3, dtype=torch.float64)
    policy = torch.cat((motion[:, :1] + 0.5, 2.0 * motion[:, 1:]), dim=1)
    got = feature_match(policy, motion, [("shifted", 1), ("spread", 2)])
    m = motion.numpy()
    assert got["shifted"]["mean_gap_in_motion_std"] == pytest.approx(0.5 / np.std(m[:, 0], ddof=1), rel=1e-9)
    assert got["shifted"]["median_std_ratio"] == pytest.approx(1.0, rel=1e-9)
    gaps = np.abs(2.0 * m[:, 1:].mean(axis=0) - m[:, 1:].mean(axis=0)) / np.std(m[:, 1:], axis=0, ddof=1)
    assert got["spread"]["mean_gap_in_motion_std"] == pytest.approx(gaps.mean(), rel=1e-9)
    assert got["spread"]["median_std_ratio"] == pytest.approx(2.0, rel=1e-9)
    assert got["spread"]["features"] == 2
