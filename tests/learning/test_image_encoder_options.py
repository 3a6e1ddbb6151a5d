"""The image model's speed options (train YAML ``actor.cnn_precision``, ``actor.cnn_channels_last``) and its uint8
rollout storage, on the CPU.

References: bfloat16 against float32 within a rounding bound derived below from the network run on absolute values;
channels-last against contiguous within float32's summation-order bound; uint8 storage against float32 storage
holding the same pixel values (two PPO iterations, parameters compared bitwise); CartpoleCamera training with both
options on."""

from __future__ import annotations

import json

import torch
import torch.nn.functional as F
from rsl_rl.algorithms import PPO
from tensordict import TensorDict

from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.learning.models import ImageCNNModel
from isaacgymenvs_mw.learning.runner import rsl_rl_config
from isaacgymenvs_mw.utils.config import compose_config, to_dict

SHAPE = (9, 16, 32)  # CartpoleCamera's three stacked RGB frames, at the small test resolution
CNN = {"output_channels": [16, 32], "kernel_size": [5, 3], "stride": [2, 2], "activation": "elu"}  # its CNN
GROUPS = {"actor": ["camera"]}


def images(n: int, seed: int = 0) -> torch.Tensor:
    return torch.randint(0, 256, (n, *SHAPE), dtype=torch.uint8, generator=torch.Generator().manual_seed(seed))


def image_model(**options) -> ImageCNNModel:
    torch.manual_seed(0)
    obs = TensorDict({"camera": images(2)}, batch_size=[2])
    return ImageCNNModel(obs, GROUPS, "actor", 1, hidden_dims=[8], cnn_cfg=CNN, **options)


def absolute_features(model: ImageCNNModel, x: torch.Tensor) -> torch.Tensor:
    """The CNN's convolutions with |weights| and |biases| on the (non-negative) scaled pixels, no activation: an upper
    bound on every intermediate |value| (ELU never grows a magnitude), computed without the model's forward."""
    convs = [m for m in model.cnns["camera"].cnn if isinstance(m, torch.nn.Conv2d)]
    h = x.double() / 255.0
    for conv in convs:
        h = F.conv2d(h, conv.weight.double().abs(), conv.bias.double().abs(), stride=conv.stride)
    return h.flatten(1)


def test_bfloat16_convolutions_stay_within_their_rounding_bound_of_float32():
    # Rounding to bfloat16 errs by at most u = 2^-9 relative; take u = 2^-8 for margin. Layer 1: pixels, weights and
    # the sum are each rounded once (float32 accumulation adds ~K * 2^-24, negligible): |dz1| <= 3u A1, with A1 the
    # absolute network's value; ELU is 1-Lipschitz and its output is rounded again: <= 4u A1. Layer 2 carries that
    # error through |W2| and adds its weights' and its sum's rounding: <= 6u A2, ELU's rounding: <= 7u A2. So every
    # output is within 8u A2 = 8 * 2^-8 * A2 of float32's.
    fp32, bf16 = image_model(), image_model(cnn_precision="bfloat16")
    x = images(64, seed=1)
    exact = fp32.cnns["camera"](x)
    rounded = bf16.cnns["camera"](x)
    bound = 8 * 2.0**-8 * absolute_features(fp32, x)
    assert rounded.dtype == torch.float32 and rounded.shape == exact.shape
    assert ((rounded.double() - exact.double()).abs() <= bound).all()
    assert not torch.equal(rounded, exact)  # the option did compute in bfloat16
    # and the policy's output (the MLP after the CNN is float32 in both)
    obs = TensorDict({"camera": x}, batch_size=[64])
    assert torch.isfinite(bf16(obs)).all()


def test_bfloat16_backward_reaches_every_parameter_in_float32():
    model = image_model(cnn_precision="bfloat16")
    obs = TensorDict({"camera": images(16, seed=2)}, batch_size=[16])
    model(obs).square().sum().backward()
    for name, p in model.named_parameters():
        if p.requires_grad and "distribution" not in name:
            assert p.grad is not None and p.grad.dtype == torch.float32 and torch.isfinite(p.grad).all(), name


def test_channels_last_matches_contiguous_to_float32_summation_order():
    # Both orders sum the same products in float32, in a different order: each result errs by at most K * 2^-24 of
    # the sum of |products| (K terms), so two orders differ by at most 2 K 2^-24 A per layer; through both layers
    # (K1 = 9 * 25, K2 = 16 * 9) at most 2 (K1 + K2) 2^-24 A2. A factor 4 of margin covers the libraries' blocking.
    plain, nhwc = image_model(), image_model(cnn_channels_last=True)
    seen = []
    first_conv = nhwc.cnns["camera"].cnn[0]
    first_conv.register_forward_pre_hook(lambda m, args: seen.append(
        args[0].is_contiguous(memory_format=torch.channels_last)))
    x = images(64, seed=3)
    reference, reordered = plain.cnns["camera"](x), nhwc.cnns["camera"](x)
    bound = 4 * 2 * (9 * 25 + 16 * 9) * 2.0**-24 * absolute_features(plain, x)
    assert seen == [True]  # the convolution did read NHWC
    assert ((reordered.double() - reference.double()).abs() <= bound).all()
    assert first_conv.weight.is_contiguous()  # weights keep their layout: the optimiser's flat buffer is unchanged


def test_exports_run_the_cnn_in_float32_whatever_the_options():
    model = image_model(cnn_precision="bfloat16", cnn_channels_last=True)
    reference = image_model()  # same seed: same weights
    x = images(4, seed=4)
    obs = TensorDict({"camera": x}, batch_size=[4])
    scripted = torch.jit.script(model.as_jit())  # what rsl_rl's TorchScript export does
    onnx_module = model.as_onnx()
    empty = torch.zeros(4, 0)
    expected = reference(obs)
    torch.testing.assert_close(scripted(empty, [x]), expected, rtol=0, atol=0)
    torch.testing.assert_close(onnx_module(empty, x), expected, rtol=0, atol=0)


class _SizedEnv:
    num_envs, num_actions = 8, 1


def two_iterations(camera_dtype: torch.dtype) -> PPO:
    """Two PPO iterations of CartpoleCamera's learner (its train YAML) on 8 envs on the CPU, fed the same pixel values
    stored as ``camera_dtype``; rewards are a fixed function of the observations and actions."""
    cfg = compose_config(["task=CartpoleCamera", "num_envs=8"])
    train_cfg = rsl_rl_config(to_dict(cfg.train))
    train_cfg["multi_gpu"] = None
    pixels = torch.Generator().manual_seed(5)
    states = torch.Generator().manual_seed(6)

    def observe() -> TensorDict:
        camera = torch.randint(0, 256, (8, *SHAPE), dtype=torch.uint8, generator=pixels).to(camera_dtype)
        return TensorDict({"camera": camera, "policy": torch.randn(8, 4, generator=states)}, batch_size=[8])

    torch.manual_seed(7)
    alg = PPO.construct_algorithm(observe(), _SizedEnv(), train_cfg, "cpu")
    for _ in range(2):
        obs = observe()
        with torch.inference_mode():
            for step in range(train_cfg["num_steps_per_env"]):
                actions = alg.act(obs)
                obs = observe()
                rewards = obs["policy"][:, 1].cos() - 0.01 * actions.square().sum(dim=1)
                dones = torch.zeros(8)
                dones[step % 8] = float(step % 5 == 4)
                alg.process_env_step(obs, rewards, dones, {"time_outs": torch.zeros(8)})
            alg.compute_returns(obs)
        stored = alg.storage.observations["camera"]
        assert stored.dtype == camera_dtype
        alg.update()
    return alg


def test_uint8_rollout_storage_updates_exactly_like_float_storage():
    as_bytes, as_floats = two_iterations(torch.uint8), two_iterations(torch.float32)
    # a quarter of the memory for the images, and bit for bit the same learner afterwards
    assert as_bytes.storage.observations["camera"].element_size() * 4 == \
        as_floats.storage.observations["camera"].element_size()
    for model in ("actor", "critic"):
        trained_b, trained_f = getattr(as_bytes, model).state_dict(), getattr(as_floats, model).state_dict()
        assert trained_b.keys() == trained_f.keys()
        for key in trained_b:
            assert torch.equal(trained_b[key], trained_f[key]), (model, key)
    # the updates did move the policy from its start
    assert not torch.equal(as_bytes.actor.state_dict()["mlp.0.weight"], image_start_weights())
    assert as_bytes.learning_rate == as_floats.learning_rate


def image_start_weights() -> torch.Tensor:
    cfg = compose_config(["task=CartpoleCamera", "num_envs=8"])
    train_cfg = rsl_rl_config(to_dict(cfg.train))
    train_cfg["multi_gpu"] = None
    torch.manual_seed(7)
    obs = TensorDict({"camera": images(8), "policy": torch.zeros(8, 4)}, batch_size=[8])
    return PPO.construct_algorithm(obs, _SizedEnv(), train_cfg, "cpu").actor.state_dict()["mlp.0.weight"]


def test_cartpole_camera_trains_two_iterations_with_both_options_on_the_cpu(tmp_path, run_args):
    small = ["task.env.cameras.front.width=32", "task.env.cameras.front.height=16"]
    options = ["train.actor.cnn_precision=bfloat16", "train.actor.cnn_channels_last=True"]
    summary = run(compose_config(["task=CartpoleCamera", "num_envs=4", "max_iterations=2", *small, *options,
                                  *run_args]))
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 4 * 16
    (stamp,) = (tmp_path / "runs" / "CartpoleCamera").iterdir()
    saved = json.loads((stamp / "summary.json").read_text())
    rewards = [r["mean_episode_reward"] for r in saved["history"] if "mean_episode_reward" in r]
    assert all(torch.isfinite(torch.tensor(rewards)))
    checkpoint = torch.load(stamp / "model_2.pt", map_location="cpu", weights_only=False)
    assert all(torch.isfinite(v).all() for v in checkpoint["actor_state_dict"].values() if v.is_floating_point())
