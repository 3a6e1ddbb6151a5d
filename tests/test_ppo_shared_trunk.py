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
    from isaacgymenvs_mw.learning.launch import check_network_sizes
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
                                          r"\+train\.algorithm\.share_trunk=True$"):
        check_network_sizes(runner(), state, path)


def test_the_value_head_sits_on_the_last_hidden_layer():
    alg = build_shared()
    assert alg.critic.value_head.in_features == alg.actor.mlp[-1].in_features == 16
    assert alg.actor.mlp[-1].out_features == ACTIONS
