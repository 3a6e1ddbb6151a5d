"""``algorithm.share_trunk``: the policy's mean and the value read one MLP trunk (rl_games' ``separate: False``).

References: the model's outputs against the same network written out with torch.nn.functional from its weights; the
update against rsl-rl-lib's own ``PPO`` holding the same shared models (same weights, same random numbers); a short
Cartpole training with the real runner, its checkpoint reloaded and its exported TorchScript policy run.
"""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
from tensordict import TensorDict

from isaacgymenvs_mw.learning.models import SharedTrunkCritic
from isaacgymenvs_mw.learning.ppo import SyncFreePPO
from isaacgymenvs_mw.utils.errors import ConfigError
from test_ppo import (ACTIONS, DEVICE_MODES, NUM_ENVS, NUM_STEPS, OBS, SYNC_FREE, FakeEnv, observations, parameters,
                      train, train_cfg)


def build_shared(algorithm_class: str = SYNC_FREE, device: str = "cpu", **algorithm):
    torch.manual_seed(0)
    cfg = train_cfg(algorithm_class, share_trunk=True, **algorithm)
    cfg["obs_groups"]["critic"] = ["policy"]
    return SyncFreePPO.construct_algorithm(observations(torch.Generator().manual_seed(1), device), FakeEnv(), cfg,
                                           device)


def by_hand(alg, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The shared network from its weights: normalise as rsl-rl-lib does, two ELU layers, then the two heads."""
    layers = [m for m in alg.actor.mlp if isinstance(m, torch.nn.Linear)]
    norm = alg.actor.obs_normalizer
    h = (x - norm._mean) / (norm._std + norm.eps)
    for layer in layers[:-1]:
        h = F.elu(h @ layer.weight.T + layer.bias)
    mean = h @ layers[-1].weight.T + layers[-1].bias
    head = alg.critic.value_head
    return mean, h @ head.weight.T + head.bias


def test_the_shared_model_is_one_trunk_with_two_linear_heads():
    alg = build_shared()
    alg.actor.update_normalization(TensorDict({"policy": torch.randn(64, OBS) * 2.0 + 0.5}, batch_size=[64]))
    x = torch.randn(20, OBS, generator=torch.Generator().manual_seed(3))
    obs = TensorDict({"policy": x}, batch_size=[20])
    with torch.no_grad():
        mean, value = by_hand(alg, x)
        torch.testing.assert_close(alg.actor(obs), mean)
        torch.testing.assert_close(alg.critic(obs), value)
    # one trunk: the critic owns only its head; the optimiser holds every parameter once
    assert [name for name, _ in alg.critic.named_parameters()] == ["value_head.weight", "value_head.bias"]
    owned = [p for group in alg.optimizer.param_groups for p in group["params"]]
    assert len({id(p) for p in owned}) == len(owned) == len(list(alg.actor.parameters())) + 2
    # the value loss reaches the trunk: its first layer's gradient is not the policy's alone
    alg.critic(obs).sum().backward()
    assert alg.actor.mlp[0].weight.grad.abs().sum() > 0 and alg.actor.mlp[-1].weight.grad is None


@pytest.mark.parametrize("grad_clip_scope", ["per_network", "global"])
@pytest.mark.parametrize(("device", "capture"), DEVICE_MODES)
def test_update_matches_rsl_rl_ppo_with_the_same_shared_models(device, capture, grad_clip_scope):
    """rsl-rl-lib's PPO clips per network (the actor's parameters, trunk included, then the value head): the global
    clip is compared where the clip never binds."""
    norm = 1.0 if grad_clip_scope == "per_network" else 1e6
    ref = build_shared("PPO", device=device, max_grad_norm=norm)
    cand = build_shared(device=device, capture_update=capture, grad_clip_scope=grad_clip_scope, max_grad_norm=norm)
    assert type(cand) is SyncFreePPO and isinstance(cand.critic, SharedTrunkCritic)
    ref_history, cand_history = train(ref, 3, data_seed=5), train(cand, 3, data_seed=5)
    for ref_step, cand_step in zip(ref_history, cand_history, strict=True):
        assert cand_step["lr"] == pytest.approx(ref_step["lr"], rel=1e-12)
        for key in ("value", "surrogate", "entropy"):
            assert cand_step[key] == pytest.approx(ref_step[key], rel=1e-4, abs=1e-6), key
    for ref_param, cand_param in zip(parameters(ref), parameters(cand), strict=True):
        torch.testing.assert_close(cand_param, ref_param, rtol=1e-4, atol=1e-6)
    # the one observation normaliser (the actor's), updated once per update
    torch.testing.assert_close(cand.actor.obs_normalizer._var, ref.actor.obs_normalizer._var)
    assert int(cand.actor.obs_normalizer.count) == int(ref.actor.obs_normalizer.count) == 3 * NUM_ENVS * NUM_STEPS
    assert (cand._graph is not None) == (device == "cuda" and capture == "auto")


def test_checkpoint_round_trip_keeps_the_shared_model():
    alg = build_shared()
    train(alg, 1, data_seed=2)
    saved = alg.save()
    assert set(saved["critic_state_dict"]) == {"value_head.weight", "value_head.bias"}
    fresh = build_shared()
    fresh.load(saved, None, strict=True)
    x = TensorDict({"policy": torch.randn(5, OBS)}, batch_size=[5])
    with torch.no_grad():
        torch.testing.assert_close(fresh.actor(x), alg.actor(x))
        torch.testing.assert_close(fresh.critic(x), alg.critic(x))


@pytest.mark.parametrize(("change", "message"), [
    (lambda cfg: cfg["obs_groups"].update(critic=["critic"]),
     r"^train\.algorithm\.share_trunk=True needs train\.runner\.obs_groups\.critic equal to "
     r"train\.runner\.obs_groups\.actor \(the value reads the policy's trunk\), got \['critic'\] and \['policy'\] "
     r"\(a privileged critic state, e\.g\. task\.env\.asymmetric_observations=True\); "
     r"give train\.runner\.obs_groups\.critic=\['policy'\] or train\.algorithm\.share_trunk=False$"),
    (lambda cfg: cfg["algorithm"].update(share_trunk="yes"),
     r"^train\.algorithm\.share_trunk='yes' is invalid: give True or False$"),
    (lambda cfg: cfg["actor"].update(class_name="RNNModel", rnn_type="gru", rnn_hidden_dim=8, rnn_num_layers=1),
     r"^train\.algorithm\.share_trunk=True needs train\.actor\.class_name=MLPModel .*got RNNModel$"),
])
def test_bad_settings_name_the_key(change, message):
    cfg = train_cfg(SYNC_FREE, share_trunk=True)
    cfg["obs_groups"]["critic"] = ["policy"]
    obs = observations(torch.Generator().manual_seed(1))
    obs["critic"] = torch.zeros(obs.batch_size[0], 2)
    change(cfg)
    with pytest.raises(ConfigError, match=message):
        SyncFreePPO.construct_algorithm(obs, FakeEnv(), cfg, "cpu")


def test_a_critic_group_bound_to_the_policys_tensor_reads_the_trunk():
    # Without privileged states the env gives the critic group the policy's own tensor (learning/vecenv.py), so a
    # recipe's `critic: [critic]` names the policy's observation, and a shared trunk accepts it.
    cfg = train_cfg(SYNC_FREE, share_trunk=True)
    cfg["obs_groups"]["critic"] = ["critic"]
    obs = observations(torch.Generator().manual_seed(1))
    obs["critic"] = obs["policy"]
    alg = SyncFreePPO.construct_algorithm(obs, FakeEnv(), cfg, "cpu")
    assert cfg["obs_groups"]["critic"] == ["policy"]
    assert type(alg.critic).__name__ == "SharedTrunkCritic" and alg.critic._actor is alg.actor
    x = TensorDict({"policy": torch.randn(4, OBS)}, batch_size=[4])  # no "critic" entry: the value reads the policy's
    with torch.no_grad():
        assert alg.critic(x).shape == (4, 1)


def test_share_trunk_false_builds_separate_networks():
    torch.manual_seed(0)
    cfg = train_cfg(SYNC_FREE, share_trunk=False)
    alg = SyncFreePPO.construct_algorithm(observations(torch.Generator().manual_seed(1)), FakeEnv(), cfg, "cpu")
    assert type(alg.critic).__name__ == "MLPModel"
    assert alg.critic.mlp[0].weight is not alg.actor.mlp[0].weight and alg.critic.mlp[-1].out_features == 1


def test_cartpole_trains_with_a_shared_trunk_and_exports_it(make_cartpole, tmp_path):
    """The real runner on Cartpole (16 envs, CPU), 2 iterations: losses finite, trunk and value head trained, the
    checkpoint loads into a fresh runner with the same outputs, and the exported TorchScript policy gives the actor's
    mean actions; a config without share_trunk refuses the checkpoint in one line."""
    from isaacgymenvs_mw.learning.export import export_policy
    from isaacgymenvs_mw.learning.runner import check_network_sizes
    from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
    from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
    from isaacgymenvs_mw.utils.config import compose_config, to_dict

    def runner(*overrides: str) -> Runner:
        cfg = compose_config(["task=Cartpole", "sim_device=cpu", "rl_device=cpu", "headless=True", *overrides])
        return Runner(RslRlVecEnv(make_cartpole(16)), rsl_rl_config(to_dict(cfg.train)), log_dir=None, device="cpu")

    shared = runner("+train.algorithm.share_trunk=True", "+train.algorithm.grad_clip_scope=global")
    alg = shared.alg
    assert isinstance(alg.critic, SharedTrunkCritic)
    before = {name: p.detach().clone() for name, p in [*alg.actor.named_parameters(),
                                                       *alg.critic.named_parameters()]}
    losses = []
    update = alg.update
    alg.update = lambda: (lambda out: (losses.append(out), out)[1])(update())
    shared.learn(2)
    assert len(losses) == 2 and all(math.isfinite(v) for out in losses for v in out.values())
    after = dict([*alg.actor.named_parameters(), *alg.critic.named_parameters()])
    assert not torch.equal(before["mlp.0.weight"], after["mlp.0.weight"].detach())
    assert not torch.equal(before["value_head.weight"], after["value_head.weight"].detach())

    path = tmp_path / "model.pt"
    shared.save(str(path))
    again = runner("+train.algorithm.share_trunk=True")
    again.load(str(path))
    obs = shared.env.get_observations()
    with torch.no_grad():
        torch.testing.assert_close(again.alg.actor(obs), alg.actor(obs))
        torch.testing.assert_close(again.alg.critic(obs), alg.critic(obs))

    _, jit_path = export_policy(shared, tmp_path / "exported")
    policy = torch.jit.load(str(jit_path))
    with torch.no_grad():
        torch.testing.assert_close(policy(obs["policy"]), alg.actor(obs))
    assert (tmp_path / "exported" / "policy.onnx").stat().st_size > 0
    assert policy(obs["policy"]).shape[-1] == shared.env.num_actions

    state = torch.load(path, weights_only=False)
    with pytest.raises(ConfigError, match=r"^checkpoint='.*model\.pt' was trained with train\.algorithm\.share_trunk="
                                          r"True, this run builds share_trunk=False: give "
                                          r"\+\+train\.algorithm\.share_trunk=True$") as refused:
        check_network_sizes(runner(), state, path)
    # The override it names composes whether the recipe holds the key (AllegroHand's shares its trunk) or not
    # (Cartpole's): a single + fails on a recipe that holds it.
    hint = str(refused.value).rsplit(" ", 1)[-1]
    for task, held in (("Cartpole", False), ("AllegroHand", True)):
        assert ("share_trunk" in compose_config([f"task={task}"]).train.algorithm) == held
        assert compose_config([f"task={task}", hint]).train.algorithm.share_trunk is True


def test_the_value_head_sits_on_the_last_hidden_layer():
    alg = build_shared()
    assert alg.critic.value_head.in_features == alg.actor.mlp[-1].in_features == 16
    assert alg.actor.mlp[-1].out_features == ACTIONS


def count_trunk_passes(alg) -> list[int]:
    """A counter of the trunk's passes: calls of its first layer."""
    passes = [0]
    alg.actor.mlp[0].register_forward_hook(lambda *_: passes.__setitem__(0, passes[0] + 1))
    return passes


def test_one_trunk_pass_gives_the_two_pass_losses_and_gradients():
    """A mini-batch's forward as PPO runs it (the policy, then the value on the same batch; one pass of the trunk)
    against the same losses written out by hand with the trunk computed twice, once per head, from copies of the
    weights: the same value, log-probabilities and losses, and the same gradient on every parameter."""
    alg = build_shared()
    alg.actor.update_normalization(TensorDict({"policy": torch.randn(64, OBS) * 2.0 + 0.5}, batch_size=[64]))
    data = torch.Generator().manual_seed(4)
    x, actions = torch.randn(20, OBS, generator=data), torch.randn(20, ACTIONS, generator=data)
    advantages, returns = torch.randn(20, generator=data), torch.randn(20, 1, generator=data)
    old_log_prob = torch.randn(20, generator=data) * 0.1 - 4.0
    obs = TensorDict({"policy": x}, batch_size=[20])
    passes = count_trunk_passes(alg)

    alg.actor(obs, stochastic_output=True)
    log_prob = alg.actor.get_output_log_prob(actions)
    values = alg.critic(obs)
    assert passes[0] == 1
    ratio = torch.exp(log_prob - old_log_prob)
    surrogate = torch.max(-advantages * ratio, -advantages * ratio.clamp(0.8, 1.2)).mean()
    value_loss = (returns - values).pow(2).mean()
    entropy = alg.actor.output_entropy.mean()
    (surrogate + value_loss - 0.01 * entropy).backward()
    named = dict([*alg.actor.named_parameters(), *alg.critic.named_parameters()])

    w = {name: p.detach().clone().requires_grad_() for name, p in named.items()}
    norm = alg.actor.obs_normalizer

    def trunk_by_hand(inputs: torch.Tensor) -> torch.Tensor:
        h = (inputs - norm._mean) / (norm._std + norm.eps)
        for i in (0, 2):
            h = F.elu(h @ w[f"mlp.{i}.weight"].T + w[f"mlp.{i}.bias"])
        return h

    mean = trunk_by_hand(x) @ w["mlp.4.weight"].T + w["mlp.4.bias"]  # first pass: the policy's
    value = trunk_by_hand(x) @ w["value_head.weight"].T + w["value_head.bias"]  # second pass: the value's
    std = w["distribution.std_param"]
    log_prob_ref = (-0.5 * ((actions - mean) / std).square() - std.log() - 0.5 * math.log(2 * math.pi)).sum(-1)
    ratio_ref = torch.exp(log_prob_ref - old_log_prob)
    surrogate_ref = torch.max(-advantages * ratio_ref, -advantages * ratio_ref.clamp(0.8, 1.2)).mean()
    value_loss_ref = (returns - value).pow(2).mean()
    entropy_ref = (0.5 + 0.5 * math.log(2 * math.pi) + std.log()).sum()
    (surrogate_ref + value_loss_ref - 0.01 * entropy_ref).backward()

    torch.testing.assert_close(values, value)
    torch.testing.assert_close(log_prob, log_prob_ref)
    torch.testing.assert_close(surrogate, surrogate_ref)
    torch.testing.assert_close(value_loss, value_loss_ref)
    for name, param in named.items():
        torch.testing.assert_close(param.grad, w[name].grad, msg=name)
    assert named["mlp.0.weight"].grad.abs().sum() > 0 and named["value_head.weight"].grad.abs().sum() > 0


@pytest.mark.parametrize(("device", "capture"), DEVICE_MODES)
def test_updates_with_one_trunk_pass_match_two_passes(device, capture):
    """SyncFreePPO's rollouts and updates against the same learner whose value head always runs the trunk again (the
    two-pass form): same losses, same weights; the trunk runs once per rollout step, once for the bootstrap value and
    once per mini-batch instead of twice (counted where the update is not a replayed graph)."""
    two_pass, one_pass = (build_shared(device=device, capture_update=capture) for _ in range(2))
    two_pass.actor.take_features = lambda obs: None
    counts = count_trunk_passes(two_pass), count_trunk_passes(one_pass)
    two_history, one_history = train(two_pass, 3, data_seed=6), train(one_pass, 3, data_seed=6)
    # One trunk pass sums the two heads' gradients inside the trunk's backward, two passes sum them at the weights: the
    # float sums differ in order, by up to 1.1e-5 relative after 3 updates on a 64-core host's CPU (2026-11-28). A
    # handover that cuts the value loss off the trunk (features detached) fails it by far more than the 1e-4 allowed here.
    for two, one in zip(two_history, one_history, strict=True):
        for key in ("value", "surrogate", "entropy", "lr"):
            assert one[key] == pytest.approx(two[key], rel=1e-4, abs=1e-6), key
    for two, one in zip(parameters(two_pass), parameters(one_pass), strict=True):
        torch.testing.assert_close(one, two, rtol=1e-4, atol=1e-6)
    mini_batches = one_pass.num_learning_epochs * one_pass.num_mini_batches
    if one_pass.capture_update:
        return
    assert counts[1][0] == 3 * (NUM_STEPS + 1 + mini_batches)
    assert counts[0][0] == 3 * (2 * NUM_STEPS + 1 + 2 * mini_batches)


def test_the_value_never_takes_features_of_another_observation():
    """The value head takes the policy's features only for the very observation object that the policy's last
    forward read, unchanged since, once, and in the same grad mode; otherwise it runs the trunk on what it is given."""
    alg = build_shared()
    alg.actor.update_normalization(TensorDict({"policy": torch.randn(64, OBS) * 2.0 + 0.5}, batch_size=[64]))
    passes = count_trunk_passes(alg)
    data = torch.Generator().manual_seed(8)

    def fresh() -> TensorDict:
        return TensorDict({"policy": torch.randn(10, OBS, generator=data)}, batch_size=[10])

    def expected(obs: TensorDict) -> torch.Tensor:
        return by_hand(alg, obs["policy"])[1]

    def value_after_policy(policy_obs: TensorDict, change=None) -> tuple[torch.Tensor, TensorDict, int]:
        """The value asked just after the policy's forward on `policy_obs`, of `change(policy_obs)` if given; the
        observation it was asked for; how many trunk passes the two calls took."""
        before = passes[0]
        alg.actor(policy_obs)
        value_obs = change(policy_obs) if change else policy_obs
        return alg.critic(value_obs), value_obs, passes[0] - before

    with torch.no_grad():
        value, same, used = value_after_policy(fresh())
        torch.testing.assert_close(value, expected(same))
        assert used == 1  # the one case that reuses: the same object, unchanged
        before = passes[0]
        torch.testing.assert_close(alg.critic(same), expected(same))  # asked again: the features were taken already
        assert passes[0] - before == 1

        other = fresh()
        changes = {"another observation": lambda _: other,
                   "another object with equal values": lambda o: o.clone(),
                   "the group's tensor replaced": lambda o: o.set("policy", other["policy"].clone()),
                   "the group's tensor written in place": lambda o: o.apply_(lambda t: t.mul_(-2.0))}
        for case, change in changes.items():
            value, asked, used = value_after_policy(fresh(), change)
            assert used == 2, case
            torch.testing.assert_close(value, expected(asked), msg=case)

    # the policy's forward without gradients, the value with: the value's loss must reach the trunk
    obs = fresh()
    with torch.no_grad():
        alg.actor(obs)
    alg.critic(obs).sum().backward()
    assert alg.actor.mlp[0].weight.grad.abs().sum() > 0

    # the rollout's loop under inference mode: a step's value is the step's own, the bootstrap value runs the trunk
    with torch.inference_mode():
        step = fresh()
        before = passes[0]
        alg.actor(step)
        torch.testing.assert_close(alg.critic(step), expected(step))
        step["policy"].copy_(torch.randn(10, OBS, generator=data))  # the env writes the next observation in place
        torch.testing.assert_close(alg.critic(step), expected(step))
        assert passes[0] - before == 2
