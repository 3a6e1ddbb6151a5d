"""The image model's auxiliary head (train YAML ``actor.aux_target``) and SyncFreePPO's ``algorithm.aux_loss_coef``,
on the CPU.

References: the loss against the head's layers and the mean squared error written out here with torch.nn.functional;
the logged mean against that loss of the rollout's observations before the update (one mini-batch, one epoch); the
exported policy against the model's deterministic output; the update with the coefficient against the same update
without it."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
from rsl_rl.algorithms import PPO
from tensordict import TensorDict

from isaacgymenvs_mw.learning.models import ImageCNNModel
from isaacgymenvs_mw.utils.errors import ConfigError

SYNC_FREE = "isaacgymenvs_mw.learning.ppo:SyncFreePPO"
IMAGE_MODEL = "isaacgymenvs_mw.learning.models:ImageCNNModel"
NUM_ENVS, NUM_STEPS, ACTIONS = 16, 4, 2
IMAGE, PROPRIO, STATE = (1, 16, 16), 3, 5  # one channel of 16 x 16 pixels, 3 flat values, a 5-value target
CNN = {"output_channels": [4, 8], "kernel_size": [3, 3], "stride": [2, 2], "activation": "elu"}
GROUPS = {"actor": ["camera", "policy"], "critic": ["policy", "critic"]}
AUX = {"group": "critic", "hidden_dims": [8]}


def observations(n: int, generator: torch.Generator) -> TensorDict:
    camera = torch.randint(0, 256, (n, *IMAGE), dtype=torch.uint8, generator=generator)
    return TensorDict({"camera": camera, "policy": torch.randn(n, PROPRIO, generator=generator),
                       "critic": 0.5 + torch.randn(n, STATE, generator=generator)}, batch_size=[n])


def image_model(aux_target: dict | None = AUX, obs_set: str = "actor") -> ImageCNNModel:
    torch.manual_seed(0)
    obs = observations(2, torch.Generator().manual_seed(0))
    return ImageCNNModel(obs, GROUPS, obs_set, ACTIONS, hidden_dims=[16], cnn_cfg=CNN, obs_normalization=True,
                         aux_target=aux_target,
                         distribution_cfg={"class_name": "isaacgymenvs_mw.learning.distributions:GaussianDistribution",
                                           "init_std": 1.0, "std_type": "scalar"})


def head_by_hand(model: ImageCNNModel, camera: torch.Tensor) -> torch.Tensor:
    """The head's output from the convolutions' and linear layers' weights: conv, elu, conv, elu, flatten; linear,
    elu, linear."""
    convs = [m for m in model.cnns["camera"].cnn if isinstance(m, torch.nn.Conv2d)]
    h = camera.float() / 255.0
    for conv in convs:
        h = F.elu(F.conv2d(h, conv.weight, conv.bias, stride=conv.stride))
    first, last = [m for m in model.aux_head if isinstance(m, torch.nn.Linear)]
    return F.linear(F.elu(F.linear(h.flatten(1), first.weight, first.bias)), last.weight, last.bias)


def mse_by_hand(prediction: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    n, d = target.shape
    return sum(((prediction[i, j] - target[i, j]) ** 2 for i in range(n) for j in range(d))) / (n * d)


# ------------------------------------------------------------------------------------------ the loss (a)

def test_the_aux_loss_is_the_mean_squared_error_of_the_head_against_the_group():
    model = image_model()
    obs = observations(6, torch.Generator().manual_seed(1))
    expected = mse_by_hand(head_by_hand(model, obs["camera"]), obs["critic"])
    assert model.aux_loss(obs).item() == pytest.approx(expected.item(), rel=1e-5)
    # after the forward on the same observation the loss takes its features: the same value and the same gradients
    fresh = gradients(model, lambda: model.aux_loss(obs))
    model(obs)
    assert model.aux_loss(obs).item() == pytest.approx(expected.item(), rel=1e-5)
    reused = gradients(model, lambda: (model(obs), model.aux_loss(obs))[1])
    assert fresh.keys() == reused.keys() and any("cnns" in n for n in fresh)
    for name in fresh:
        torch.testing.assert_close(reused[name], fresh[name], rtol=1e-5, atol=1e-7)
    # the target gets no gradient: it is data
    target = obs["critic"].clone().requires_grad_()
    obs["critic"] = target
    model.aux_loss(obs).backward()
    assert target.grad is None


def gradients(model: ImageCNNModel, loss) -> dict[str, torch.Tensor]:
    model.zero_grad()
    loss().backward()
    return {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}


def test_features_of_an_image_changed_since_the_forward_are_not_reused():
    model = image_model()
    obs = observations(4, torch.Generator().manual_seed(2))
    with torch.no_grad():
        model(obs)
        obs["camera"].copy_(255 - obs["camera"])  # written in place after the forward
        changed = model.aux_loss(obs)
        other = observations(4, torch.Generator().manual_seed(3))
        model(other)
        on_obs = model.aux_loss(obs)  # the forward read another observation
    expected = mse_by_hand(head_by_hand(model, obs["camera"]), obs["critic"])
    assert changed.item() == pytest.approx(expected.item(), rel=1e-5)
    assert on_obs.item() == pytest.approx(expected.item(), rel=1e-5)


# ------------------------------------------------------------------------------------------ export (c)

def test_the_exported_policy_acts_as_the_model_and_holds_no_head():
    model = image_model().eval()
    obs = observations(5, torch.Generator().manual_seed(4))
    with torch.no_grad():
        model.update_normalization(obs)
        expected = model(obs)  # deterministic: the distribution's mean
        jit = torch.jit.script(model.as_jit())
        onnx = model.as_onnx()
        assert torch.equal(jit(obs["policy"], [obs["camera"]]), expected)
        assert torch.equal(onnx(obs["policy"], obs["camera"]), expected)
    head = {id(p) for p in model.aux_head.parameters()}
    size = sum(p.numel() for n, p in model.named_parameters() if not n.startswith("aux_head."))
    for exported in (jit, onnx):
        names = [n for n, _ in exported.named_parameters()]
        assert not any("aux" in n for n in names)
        assert all(id(p) not in head for p in exported.parameters())
        # everything but the head and the action noise (a training parameter, not the deterministic policy's)
        assert sum(p.numel() for p in exported.parameters()) == size - model.distribution.std_param.numel()


# ------------------------------------------------------------------------------------------ PPO (b)

class FakeEnv:
    num_envs, num_actions = NUM_ENVS, ACTIONS


def build(actor_extra: dict | None = None, critic_extra: dict | None = None, groups: dict | None = None,
          **algorithm) -> PPO:
    torch.manual_seed(0)
    actor = {"class_name": IMAGE_MODEL, "hidden_dims": [16], "activation": "elu", "obs_normalization": True,
             "cnn_cfg": CNN, "distribution_cfg": {"class_name": "isaacgymenvs_mw.learning.distributions:"
                                                  "GaussianDistribution", "init_std": 1.0, "std_type": "scalar"}}
    cfg = {"num_steps_per_env": NUM_STEPS, "obs_groups": dict(groups or GROUPS), "multi_gpu": None,
           "algorithm": {"class_name": SYNC_FREE, "learning_rate": 1e-3, "num_learning_epochs": 2,
                         "num_mini_batches": 2, "schedule": "fixed", **algorithm},
           "actor": {**actor, **(actor_extra or {})},
           "critic": {"class_name": "MLPModel", "hidden_dims": [16], "activation": "elu", "obs_normalization": True,
                      **(critic_extra or {})}}
    return PPO.construct_algorithm(observations(NUM_ENVS, torch.Generator().manual_seed(5)), FakeEnv(), cfg, "cpu")


def rollout(alg) -> None:
    """One rollout of synthetic observations and a reward the actions shape, then the returns."""
    data = torch.Generator().manual_seed(6)
    torch.manual_seed(1234)  # action sampling and the shuffle
    obs = observations(NUM_ENVS, data)
    for _ in range(NUM_STEPS):
        with torch.inference_mode():
            actions = alg.act(obs)
            next_obs = observations(NUM_ENVS, data)
            rewards = -(actions - obs["policy"][:, :ACTIONS]).pow(2).sum(dim=1)
            alg.process_env_step(next_obs, rewards, torch.zeros(NUM_ENVS), {})
        obs = next_obs
    with torch.inference_mode():
        alg.compute_returns(obs)


def named(alg, prefix: str) -> dict[str, torch.Tensor]:
    return {n: p.detach().clone() for n, p in alg.actor.named_parameters() if n.startswith(prefix)}


def changed(before: dict[str, torch.Tensor], after: dict[str, torch.Tensor]) -> bool:
    return any(not torch.equal(before[n], after[n]) for n in before)


def test_the_coefficient_trains_the_head_and_reaches_the_encoders():
    runs = {}
    for coef in (0.0, 1.0):
        alg = build({"aux_target": AUX}, aux_loss_coef=coef)
        start = {p: named(alg, p) for p in ("cnns.", "aux_head.")}
        rollout(alg)
        losses = alg.update()
        runs[coef] = {p: named(alg, p) for p in start}, losses
        assert changed(start["cnns."], runs[coef][0]["cnns."])  # PPO's own loss trains the encoders either way
        assert changed(start["aux_head."], runs[coef][0]["aux_head."]) == (coef > 0)  # the head: only with it on
    # with the coefficient the encoders' weights move differently: the gradient reaches them through the head
    assert changed(runs[0.0][0]["cnns."], runs[1.0][0]["cnns."])
    assert "aux" not in runs[0.0][1] and math.isfinite(runs[1.0][1]["aux"]) and runs[1.0][1]["aux"] > 0
    for key in ("value", "surrogate", "entropy"):  # the first mini-batch's losses are computed before any step
        assert math.isfinite(runs[1.0][1][key])


def test_the_logged_aux_loss_is_the_loss_of_the_rollout():
    # One epoch of one mini-batch: the update's only loss is computed on every stored observation before the step.
    alg = build({"aux_target": AUX}, aux_loss_coef=0.5, num_learning_epochs=1, num_mini_batches=1)
    rollout(alg)
    stored = alg.storage.observations.flatten(0, 1)
    expected = mse_by_hand(head_by_hand(alg.actor, stored["camera"]), stored["critic"])
    assert alg.update()["aux"] == pytest.approx(expected.item(), rel=1e-5)


# ------------------------------------------------------------------------------------------ bad input (d)

@pytest.mark.parametrize(("actor", "critic", "algorithm", "message"), [
    ({}, {}, {"aux_loss_coef": 0.1},
     r"^train\.algorithm\.aux_loss_coef=0\.1 needs train\.actor\.aux_target .*ImageCNNModel without one; add it or "
     r"give train\.algorithm\.aux_loss_coef=0$"),
    ({"aux_target": AUX}, {}, {"aux_loss_coef": -1.0},
     r"^train\.algorithm\.aux_loss_coef=-1\.0 is invalid: give a number >= 0$"),
    ({"aux_target": AUX}, {}, {"aux_loss_coef": "big"},
     r"^train\.algorithm\.aux_loss_coef='big' is invalid: give a number >= 0$"),
    ({"aux_target": {"group": "cube"}}, {}, {"aux_loss_coef": 1.0},
     r"^train\.actor\.aux_target\.group='cube' is invalid: choose one of the flat observation groups "
     r"\['policy', 'critic'\]$"),
    ({"aux_target": {"group": "camera"}}, {}, {"aux_loss_coef": 1.0},  # an image is not a flat target
     r"^train\.actor\.aux_target\.group='camera' is invalid: choose one of the flat observation groups"),
    ({"aux_target": {"group": "critic", "hidden_dims": [0]}}, {}, {"aux_loss_coef": 1.0},
     r"^train\.actor\.aux_target\.hidden_dims=0 is invalid: give a whole number >= 1$"),
    ({"aux_target": {"group": "critic", "hidden_dim": [8]}}, {}, {"aux_loss_coef": 1.0},
     r"^train\.actor\.aux_target\.hidden_dim is not a key of train\.actor\.aux_target; valid: "
     r"\['group', 'hidden_dims', 'activation'\]$"),
    ({"aux_target": "critic"}, {}, {"aux_loss_coef": 1.0},
     r"^train\.actor\.aux_target='critic' is invalid: give \{group: <observation group>, hidden_dims: \[64\]\}$"),
    ({"aux_target": AUX}, {"class_name": IMAGE_MODEL, "cnn_cfg": CNN, "aux_target": AUX}, {"aux_loss_coef": 1.0},
     r"^train\.critic\.aux_target is not read: the auxiliary loss trains the actor's head; move it to "
     r"train\.actor\.aux_target or remove it$"),
])
def test_bad_settings_are_one_line_errors_naming_the_key(actor, critic, algorithm, message):
    groups = {**GROUPS, "critic": ["camera", *GROUPS["critic"]]} if critic else GROUPS  # an image critic
    with pytest.raises(ConfigError, match=message):
        build(actor, critic, groups, **algorithm)
