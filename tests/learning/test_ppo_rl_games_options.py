"""SyncFreePPO's rl_games options (``kl_schedule``, ``kl_form``, ``grad_clip_scope``, ``obs_normalization_clip``)
against references written here.

The reference learner is rsl-rl-lib's PPO with an update written out plainly on the host: rl_games' per-sample store
of the mean and std refreshed as each mini-batch is seen (its ``update_mu_sigma``), the KL read with ``.item()``, the
rate moved once per epoch by rl_games' AdaptiveScheduler rule, the global gradient clip computed by hand. Same
weights, same random numbers: SyncFreePPO with the options must train to the same rates, losses and weights.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import torch
from rsl_rl.algorithms import PPO
from rsl_rl.modules import EmpiricalNormalization
from tensordict import TensorDict

from isaacgymenvs_mw.learning.ppo import ClippedEmpiricalNormalization, rl_games_kl
from isaacgymenvs_mw.utils.errors import ConfigError
from test_ppo import (DEVICE_MODES, OBS, START_LR, SYNC_FREE, assert_same_training, build, observations,
                      train)

REFERENCE = "test_ppo_rl_games_options:RlGamesReference"
RL_GAMES = {"kl_schedule": "per_epoch", "kl_form": "rl_games", "grad_clip_scope": "global"}


class RlGamesReference(PPO):
    """rsl-rl-lib's PPO whose update follows the options the way rl_games' a2c_common.py does, host-side."""

    def __init__(self, *args, kl_schedule: str = "per_mini_batch", kl_form: str = "rsl_rl",
                 grad_clip_scope: str = "per_network", learning_rate_min: float = 1e-5,
                 learning_rate_max: float = 1e-2, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.kl_schedule, self.kl_form, self.grad_clip_scope = kl_schedule, kl_form, grad_clip_scope
        self.lr_bounds = (learning_rate_min, learning_rate_max)
        self.kls: list[float] = []  # every mini-batch's KL, in order

    def kl(self, old_mean, old_std, new_mean, new_std) -> float:
        if self.kl_form == "rl_games":  # policy_kl(p0 = current, p1 = stored), summed over actions
            c1 = torch.log(old_std / new_std + 1e-5)
            c2 = (new_std ** 2 + (old_mean - new_mean) ** 2) / (2.0 * (old_std ** 2 + 1e-5))
            per_action = c1 + c2 - 0.5
        else:  # KL(old || new) of two Gaussians
            per_action = (torch.log(new_std / old_std) + (old_std ** 2 + (old_mean - new_mean) ** 2)
                          / (2.0 * new_std ** 2) - 0.5)
        return per_action.sum(dim=-1).mean().item()

    def move_rate(self, kl: float, rl_games: bool) -> None:
        low, high = self.lr_bounds
        if kl > 2.0 * self.desired_kl:
            self.learning_rate = max(self.learning_rate / 1.5, low)
        elif kl < 0.5 * self.desired_kl and (rl_games or kl > 0.0):
            self.learning_rate = min(self.learning_rate * 1.5, high)
        for group in self.optimizer.param_groups:
            group["lr"] = self.learning_rate

    def clip(self) -> None:
        groups = ([[*self.actor.parameters(), *self.critic.parameters()]] if self.grad_clip_scope == "global"
                  else [list(self.actor.parameters()), list(self.critic.parameters())])
        for params in groups:
            grads = [p.grad for p in params if p.grad is not None]
            total = math.sqrt(sum(float(g.double().square().sum()) for g in grads))
            scale = min(1.0, self.max_grad_norm / (total + 1e-6))
            for g in grads:
                g.mul_(scale)

    def update(self) -> dict[str, float]:
        st, batches = self.storage, self.num_mini_batches
        size = st.num_envs * st.num_transitions_per_env // batches
        perm = torch.randperm(batches * size, device=self.device)  # rsl-rl-lib's one shuffle per update
        obs, actions = st.observations.flatten(0, 1), st.actions.flatten(0, 1)
        values, returns = st.values.flatten(0, 1), st.returns.flatten(0, 1)
        old_log_prob, advantages = st.actions_log_prob.flatten(0, 1), st.advantages.flatten(0, 1)
        stored_mean, stored_std = (p.flatten(0, 1).clone() for p in st.distribution_params)
        per_epoch = self.kl_schedule == "per_epoch"
        sums = {"value": 0.0, "surrogate": 0.0, "entropy": 0.0}
        for _ in range(self.num_learning_epochs):
            epoch_kls = []
            for i in range(batches):
                idx = perm[i * size:(i + 1) * size]
                self.actor(obs[idx], stochastic_output=True)
                mean, std = (p.detach() for p in self.actor.output_distribution_params)
                log_prob = self.actor.get_output_log_prob(actions[idx])
                value = self.critic(obs[idx])
                entropy = self.actor.output_entropy.mean()
                kl = self.kl(stored_mean[idx], stored_std[idx], mean, std)
                self.kls.append(kl)
                epoch_kls.append(kl)
                if per_epoch:
                    stored_mean[idx], stored_std[idx] = mean, std
                else:
                    self.move_rate(kl, rl_games=False)
                ratio = torch.exp(log_prob - old_log_prob[idx].squeeze())
                adv = advantages[idx].squeeze()
                surrogate = torch.max(-adv * ratio, -adv * ratio.clamp(1 - self.clip_param, 1 + self.clip_param)).mean()
                clipped = values[idx] + (value - values[idx]).clamp(-self.clip_param, self.clip_param)
                value_loss = torch.max((value - returns[idx]) ** 2, (clipped - returns[idx]) ** 2).mean()
                loss = surrogate + self.value_loss_coef * value_loss - self.entropy_coef * entropy
                self.optimizer.zero_grad()
                loss.backward()
                self.clip()
                self.optimizer.step()
                for key, term in (("value", value_loss), ("surrogate", surrogate), ("entropy", entropy)):
                    sums[key] += term.item()
            if per_epoch:
                self.move_rate(sum(epoch_kls) / len(epoch_kls), rl_games=True)
        self.actor.update_normalization(st.observations.flatten(0, 1))
        self.critic.update_normalization(st.observations.flatten(0, 1))
        st.clear()
        return {key: total / (self.num_learning_epochs * batches) for key, total in sums.items()}


# ---------------------------------------------------------------------------------------------------- the KL forms

def test_rl_games_kl_is_its_formula_and_the_exact_kl_of_new_from_old_where_stds_are_large():
    g = torch.Generator().manual_seed(5)
    old_mean, new_mean = torch.randn(64, 4, generator=g), torch.randn(64, 4, generator=g)
    old_std, new_std = torch.rand(64, 4, generator=g) + 0.5, torch.rand(64, 4, generator=g) + 0.5
    got = rl_games_kl(old_mean, old_std, new_mean, new_std)
    rows = zip(old_mean.tolist(), old_std.tolist(), new_mean.tolist(), new_std.tolist())
    expected = [sum(math.log(s1 / s0 + 1e-5) + (s0 * s0 + (m1 - m0) ** 2) / (2 * (s1 * s1 + 1e-5)) - 0.5
                    for m1, s1, m0, s0 in zip(*row)) for row in rows]
    np.testing.assert_allclose(got.numpy(), expected, rtol=1e-5, atol=1e-6)
    # with stds far above sqrt(1e-5) the damping terms vanish: the KL of the new policy from the old one
    exact = torch.distributions.kl_divergence(torch.distributions.Normal(new_mean, new_std),
                                              torch.distributions.Normal(old_mean, old_std)).sum(-1)
    torch.testing.assert_close(got, exact, rtol=1e-3, atol=1e-4)


def test_rl_games_kl_damps_a_collapsed_std():
    """One action whose std is 0.0016 and whose mean moved by 0.01: the exact KL counts (0.01 / 0.0016)**2 / 2 = 19.5;
    rl_games' form 0.01**2 / (2 (0.0016**2 + 1e-5)) + 0.0016**2 / (2 (0.0016**2 + 1e-5)) - 0.5, about 3.98 - 0.4."""
    mean0, mean1, std = torch.tensor([[0.0]]), torch.tensor([[0.01]]), torch.tensor([[0.0016]])
    s2 = 0.0016 ** 2
    expected = math.log(1 + 1e-5) + (s2 + 1e-4) / (2 * (s2 + 1e-5)) - 0.5
    assert rl_games_kl(mean0, std, mean1, std).item() == pytest.approx(expected, rel=1e-5)
    assert expected < 4.0 < 19.0


# ---------------------------------------------------------------------------------------------------- the update

@pytest.mark.parametrize("options", [
    {**RL_GAMES, "max_grad_norm": 0.05},                                   # every option, clipping always active
    {"kl_schedule": "per_epoch", "kl_form": "rsl_rl"},
    {"kl_schedule": "per_mini_batch", "kl_form": "rl_games"},
    {"grad_clip_scope": "global", "max_grad_norm": 0.05},
    {**RL_GAMES, "desired_kl": 1e-7, "learning_rate_min": 1e-7},           # every epoch lowers the rate
    {**RL_GAMES, "desired_kl": 10.0},                                      # every epoch raises it
], ids=["all", "per_epoch", "rl_games_kl", "global_clip", "down", "up"])
@pytest.mark.parametrize(("device", "capture"), DEVICE_MODES)
def test_update_matches_the_rl_games_reference(options, device, capture):
    ref = build(REFERENCE, device=device, **options)
    cand = build(SYNC_FREE, device=device, capture_update=capture, **options)
    assert_same_training(ref, cand, train(ref, 4, data_seed=7), train(cand, 4, data_seed=7))
    assert (cand._graph is not None) == (device == "cuda" and capture == "auto")
    epochs, updates = 3, 4
    if options.get("desired_kl") == 1e-7:  # once per epoch: 12 decisions, where per mini-batch would take 24
        assert cand.learning_rate == pytest.approx(START_LR / 1.5 ** (epochs * updates), rel=1e-12)
    if options.get("desired_kl") == 10.0:  # 1e-3 * 1.5**6 passes rsl-rl-lib's ceiling, 1e-2: reached, not passed
        assert cand.learning_rate == 1e-2


def recording_kls(alg) -> list[float]:
    kls: list[float] = []
    measure = alg._kl_mean

    def recording(old, new):
        kl = measure(old, new)
        kls.append(kl.item())
        return kl

    alg._kl_mean = recording
    return kls


@pytest.mark.parametrize("kl_form", ["rsl_rl", "rl_games"])
def test_per_epoch_kl_measures_the_change_since_the_last_epoch(kl_form):
    """Each mini-batch's KL, against the reference's; and, from the second epoch on, unlike the KL since the
    rollout (per_mini_batch): the stored means and stds were refreshed."""
    fixed_rate = {"learning_rate_min": START_LR, "learning_rate_max": START_LR}  # the same steps in every run
    ref = build(REFERENCE, kl_schedule="per_epoch", kl_form=kl_form, **fixed_rate)
    cand = build(SYNC_FREE, kl_schedule="per_epoch", kl_form=kl_form, **fixed_rate)
    since_rollout = build(SYNC_FREE, kl_form=kl_form, **fixed_rate)
    kls, rollout_kls = recording_kls(cand), recording_kls(since_rollout)
    train(ref, 2, data_seed=3), train(cand, 2, data_seed=3), train(since_rollout, 1, data_seed=3)
    np.testing.assert_allclose(kls, ref.kls, rtol=1e-4, atol=2e-7)  # float32 cancellation in KLs near 0
    # The first epoch (2 mini-batches) measures from the rollout in both. So does the second epoch's first
    # mini-batch: its samples were stored by the update's first step, taken while the policy was the rollout's.
    # After that the stored values are newer than the rollout's: the change since then is smaller than the total.
    np.testing.assert_allclose(kls[:3], rollout_kls[:3], rtol=1e-5, atol=1e-9)
    assert all(a < 0.8 * b for a, b in zip(kls[3:6], rollout_kls[3:6]))


def test_recurrent_per_epoch_moves_the_rate_once_per_epoch():
    alg = build(SYNC_FREE, rnn=True, desired_kl=1e-7, learning_rate_min=1e-7, **RL_GAMES)
    history = train(alg, 2, data_seed=9)
    assert [h["lr"] for h in history] == pytest.approx([START_LR / 1.5 ** 3, START_LR / 1.5 ** 6], rel=1e-12)
    assert all(math.isfinite(h[key]) for h in history for key in ("value", "surrogate", "entropy"))


def test_defaults_are_rsl_rl_lib_behaviour():
    alg = build(SYNC_FREE)
    assert (alg.kl_schedule, alg.kl_form, alg.grad_clip_scope) == ("per_mini_batch", "rsl_rl", "per_network")
    assert type(alg.actor.obs_normalizer) is EmpiricalNormalization and alg._kl_reference is None


# ---------------------------------------------------------------------------------------------------- input clamp

def test_obs_normalization_clip_clamps_the_normalised_observations_and_exports_with_it():
    alg = build(SYNC_FREE, obs_normalization_clip=5.0)
    g = torch.Generator().manual_seed(2)
    fed = torch.randn(256, OBS, generator=g) * 3.0 + 1.0
    for model in (alg.actor, alg.critic):
        assert isinstance(model.obs_normalizer, ClippedEmpiricalNormalization)
        model.obs_normalizer.update(fed)
    data = fed.double().numpy()
    mean, std = data.mean(axis=0), data.std(axis=0)  # rsl-rl-lib: (x - mean) / (std + 1e-2); rl_games' clamp at 5
    probe = torch.randn(32, OBS, generator=g) * 40.0
    expected = np.clip((probe.double().numpy() - mean) / (std + 1e-2), -5.0, 5.0)
    for model in (alg.actor, alg.critic):
        got = model.obs_normalizer(probe).double().numpy()
        np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-5)
        assert np.abs(got).max() == pytest.approx(5.0) and np.abs(expected).max() == 5.0
    scripted = torch.jit.script(alg.get_policy().as_jit())  # the exported policy.pt clamps too
    with torch.no_grad():
        torch.testing.assert_close(scripted(probe), alg.actor(TensorDict({"policy": probe}, batch_size=[32])))


def test_clamped_normaliser_checkpoints_load_into_plain_ones():
    clipped, plain = build(SYNC_FREE, obs_normalization_clip=5.0), build(SYNC_FREE)
    train(clipped, 1, data_seed=4)
    plain.load(clipped.save(), None, strict=True)
    torch.testing.assert_close(plain.actor.obs_normalizer._mean, clipped.actor.obs_normalizer._mean)


@pytest.mark.parametrize("clip", [None, 5.0])
def test_rl_games_obs_normalization_form_divides_by_the_root_of_variance_plus_1e_5(clip):
    """rl_games' RunningMeanStd: (x - mean) / sqrt(var + 1e-5), written here with numpy; the exported policy.pt too."""
    alg = build(SYNC_FREE, obs_normalization_form="rl_games", obs_normalization_clip=clip)
    g = torch.Generator().manual_seed(5)
    fed = torch.randn(512, OBS, generator=g) * torch.tensor([1e-3, 0.01, 0.05, 0.3, 2.0, 10.0]) + 0.5
    for model in (alg.actor, alg.critic):
        model.obs_normalizer.update(fed)
    data = fed.double().numpy()
    probe = torch.randn(64, OBS, generator=g) * 0.2 + 0.5
    expected = (probe.double().numpy() - data.mean(axis=0)) / np.sqrt(data.var(axis=0) + 1e-5)
    if clip is not None:
        expected = np.clip(expected, -clip, clip)
    for model in (alg.actor, alg.critic):
        # float32 statistics: a mean of 0.5 with a spread of 1e-3 carries ~1e-3 relative rounding after scaling
        np.testing.assert_allclose(model.obs_normalizer(probe).double().numpy(), expected, rtol=2e-3, atol=1e-4)
    # the two forms differ most where the spread is near rsl-rl-lib's 1e-2: std 0.01 is halved by std + 1e-2
    plain = (probe.double().numpy() - data.mean(axis=0)) / (data.std(axis=0) + 1e-2)
    assert not np.allclose(plain[:, 1], expected[:, 1], rtol=0.2)
    scripted = torch.jit.script(alg.get_policy().as_jit())
    with torch.no_grad():
        torch.testing.assert_close(scripted(probe), alg.actor(TensorDict({"policy": probe}, batch_size=[64])))


def test_rl_games_obs_normalization_form_trains_and_checkpoints_load_into_plain_ones():
    shaped, plain = build(SYNC_FREE, obs_normalization_form="rl_games"), build(SYNC_FREE)
    history = train(shaped, 2, data_seed=4)
    assert all(math.isfinite(v) for step in history for v in step.values())
    plain.load(shaped.save(), None, strict=True)
    torch.testing.assert_close(plain.actor.obs_normalizer._var, shaped.actor.obs_normalizer._var)


# ---------------------------------------------------------------------------------------------------- bad settings

@pytest.mark.parametrize(("settings", "message"), [
    ({"kl_schedule": "epoch"}, r"train\.algorithm\.kl_schedule='epoch' is invalid: choose one of "
                               r"\['per_mini_batch', 'per_epoch'\]"),
    ({"kl_form": 3}, r"train\.algorithm\.kl_form=3 is invalid: choose one of \['rsl_rl', 'rl_games'\]"),
    ({"grad_clip_scope": "all"}, r"train\.algorithm\.grad_clip_scope='all' is invalid: choose one of "
                                 r"\['per_network', 'global'\]"),
    ({"obs_normalization_clip": 0.0}, r"train\.algorithm\.obs_normalization_clip=0\.0 is invalid: give a number > 0\.0"),
    ({"obs_normalization_form": "exact"},
     r"train\.algorithm\.obs_normalization_form='exact' is invalid: choose one of \['rsl_rl', 'rl_games'\]"),
    ({"kl_schedule": "per_epoch", "schedule": "fixed"},
     r"train\.algorithm\.kl_schedule='per_epoch' has no effect: the learning rate moves only with "
     r"train\.algorithm\.schedule=adaptive and a train\.algorithm\.desired_kl \(got schedule='fixed', "
     r"desired_kl=0\.01\); remove it or set both"),
    ({"kl_form": "rl_games", "desired_kl": None}, r"train\.algorithm\.kl_form='rl_games' has no effect: .*"),
])
def test_bad_settings_name_the_key(settings, message):
    with pytest.raises(ConfigError, match=f"^{message}$"):
        build(SYNC_FREE, **settings)


@pytest.mark.parametrize(("setting", "shown"), [({"obs_normalization_clip": 5.0}, "obs_normalization_clip=5.0"),
                                               ({"obs_normalization_form": "rl_games"},
                                                "obs_normalization_form='rl_games'")])
def test_obs_normalization_options_without_normalisers_are_refused(setting, shown):
    from test_ppo import FakeEnv, train_cfg

    cfg = train_cfg(SYNC_FREE, **setting)
    cfg["actor"]["obs_normalization"] = cfg["critic"]["obs_normalization"] = False
    with pytest.raises(ConfigError, match=rf"^train\.algorithm\.{re.escape(shown)} has no effect: neither "
                                          r"train\.actor\.obs_normalization nor train\.critic\.obs_normalization"):
        PPO.construct_algorithm(observations(torch.Generator().manual_seed(1)), FakeEnv(), cfg, "cpu")


# ---------------------------------------------------------------------------------------------------- Cartpole

def test_cartpole_trains_with_every_rl_games_option(make_cartpole):
    """The real runner on Cartpole (16 envs, CPU) with all four options: the rate moves at most once per epoch,
    losses stay finite, the weights change, and a checkpoint round-trips."""
    from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
    from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
    from isaacgymenvs_mw.utils.config import compose_config, to_dict

    overrides = [f"+train.algorithm.{key}={value}" for key, value in RL_GAMES.items()]
    cfg = compose_config(["task=Cartpole", "sim_device=cpu", "rl_device=cpu", "headless=True", *overrides,
                          "+train.algorithm.obs_normalization_clip=5.0", "+train.algorithm.learning_rate_min=1e-6"])
    runner = Runner(RslRlVecEnv(make_cartpole(16)), rsl_rl_config(to_dict(cfg.train)), log_dir=None, device="cpu")
    alg = runner.alg
    assert (alg.kl_schedule, alg.kl_form, alg.grad_clip_scope) == ("per_epoch", "rl_games", "global")
    decisions = []
    adapt = alg._adapt_learning_rate
    alg._adapt_learning_rate = lambda kl, **kw: (decisions.append((float(kl), kw)), adapt(kl, **kw))[1]
    before = [p.detach().clone() for p in alg.actor.parameters()]
    start = alg.learning_rate
    runner.learn(3)
    epochs = cfg.train.algorithm.num_learning_epochs
    assert len(decisions) == 3 * epochs and all(kw == {"rl_games_rule": True} for _, kw in decisions)
    assert all(math.isfinite(kl) for kl, _ in decisions)
    steps = math.log(alg.learning_rate / start, 1.5)
    assert abs(steps - round(steps)) < 1e-6 and abs(round(steps)) <= 3 * epochs
    assert any(not torch.equal(a, b.detach()) for a, b in zip(before, alg.actor.parameters()))
    assert isinstance(alg.actor.obs_normalizer, ClippedEmpiricalNormalization)


@pytest.mark.parametrize(("rl_games_rule", "expected"), [(True, START_LR * 1.5), (False, START_LR)])
def test_per_epoch_rule_raises_the_rate_on_a_kl_at_or_below_zero(rl_games_rule, expected):
    """rl_games' rule raises the rate on any KL under half the target, and its damped KL can be < 0; rsl-rl-lib's
    rule leaves the rate alone on a KL <= 0."""
    alg = build(SYNC_FREE, desired_kl=0.01)
    for kl in (0.0, -0.05):
        alg._lr64.fill_(START_LR)
        alg._adapt_learning_rate(torch.tensor(kl), rl_games_rule=rl_games_rule)
        assert alg._lr64.item() == pytest.approx(expected, rel=1e-12)
