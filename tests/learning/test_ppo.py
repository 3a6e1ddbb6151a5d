"""SyncFreePPO against rsl-rl-lib's PPO: same data, same seeds, same result, on one process and on two.

The reference is rsl-rl-lib's own ``PPO.update`` (host-side learning-rate rule, ``.item()`` losses, broadcast of the
rate between ranks). Both algorithms start from the same weights and draw the same random numbers, so after several
updates their parameters, learning rates and losses must agree to float32 rounding.
"""

from __future__ import annotations

import copy
import time

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp
from rsl_rl.algorithms import PPO
from tensordict import TensorDict

from isaacgymenvs_mw.learning.ppo import SyncFreePPO

NUM_ENVS, NUM_STEPS, OBS, ACTIONS = 32, 8, 6, 3
START_LR = 1e-3
SYNC_FREE = "isaacgymenvs_mw.learning.ppo:SyncFreePPO"


class FakeEnv:
    num_envs, num_actions = NUM_ENVS, ACTIONS


def train_cfg(algorithm_class: str, **algorithm) -> dict:
    return {
        "num_steps_per_env": NUM_STEPS, "obs_groups": {"actor": ["policy"], "critic": ["policy"]},
        "multi_gpu": None,
        "algorithm": {"class_name": algorithm_class, "learning_rate": START_LR, "num_learning_epochs": 3,
                      "num_mini_batches": 2, "entropy_coef": 0.01, **algorithm},
        "actor": {"class_name": "MLPModel", "hidden_dims": [16, 16], "activation": "elu", "obs_normalization": True,
                  "distribution_cfg": {"class_name": "isaacgymenvs_mw.learning.distributions:GaussianDistribution",
                                       "init_std": 1.0, "std_type": "scalar"}},
        "critic": {"class_name": "MLPModel", "hidden_dims": [16, 16], "activation": "elu", "obs_normalization": True},
    }


# The CUDA runs (fused Adam reading the device-tensor rate; the update eager, and captured as a CUDA graph) exist
# where a GPU does; CI machines have none.
DEVICE_MODES = [("cpu", "auto")] + ([("cuda", "auto"), ("cuda", False)] if torch.cuda.is_available() else [])


def recurrent(cfg: dict) -> dict:
    """The same networks with a small GRU in front (rsl-rl-lib's RNNModel)."""
    for name in ("actor", "critic"):
        cfg[name].update(class_name="RNNModel", rnn_type="gru", rnn_hidden_dim=8, rnn_num_layers=1)
    return cfg


def observations(generator: torch.Generator, device: str = "cpu") -> TensorDict:
    return TensorDict({"policy": torch.randn(NUM_ENVS, OBS, generator=generator).to(device)}, batch_size=[NUM_ENVS],
                      device=device)


def build(algorithm_class: str, multi_gpu: dict | None = None, device: str = "cpu", rnn: bool = False,
          **algorithm):
    torch.manual_seed(0)  # same initial weights for both algorithms
    cfg = train_cfg(algorithm_class, **algorithm)
    if rnn:
        cfg = recurrent(cfg)
    cfg["multi_gpu"] = multi_gpu
    obs = observations(torch.Generator().manual_seed(1), device)
    return PPO.construct_algorithm(obs, FakeEnv(), cfg, device)  # builds the class that cfg names


def train(alg, updates: int, data_seed: int) -> list[dict]:
    """`updates` rounds of rollout + update on synthetic data; a reward that the policy's actions shape makes the
    losses move, and some dones exercise the bootstrapping."""
    data = torch.Generator().manual_seed(data_seed)
    torch.manual_seed(1234)  # action sampling and mini-batch shuffling (seeds the CUDA generator too)
    device = alg.device
    history = []
    for _ in range(updates):
        obs = observations(data, device)
        for _ in range(NUM_STEPS):
            with torch.inference_mode():
                actions = alg.act(obs)
                next_obs = observations(data, device)
                rewards = -(actions - obs["policy"][:, :ACTIONS]).pow(2).sum(dim=1)
                dones = (torch.rand(NUM_ENVS, generator=data) < 0.1).float().to(device)
                extras = {"time_outs": (torch.rand(NUM_ENVS, generator=data) < 0.5).float().to(device) * dones}
                alg.process_env_step(next_obs, rewards, dones, extras)
            obs = next_obs
        with torch.inference_mode():
            alg.compute_returns(obs)
        losses = alg.update()
        history.append({**losses, "lr": alg.learning_rate})
    return history


def parameters(alg) -> list[torch.Tensor]:
    return [p.detach().cpu().clone() for p in (*alg.actor.parameters(), *alg.critic.parameters())]


def assert_same_training(reference, candidate, ref_history, cand_history) -> None:
    for ref, cand in zip(ref_history, cand_history):
        assert cand["lr"] == pytest.approx(ref["lr"], rel=1e-12)
        for key in ("value", "surrogate", "entropy"):
            assert cand[key] == pytest.approx(ref[key], rel=1e-4, abs=1e-6), key
    for ref, cand in zip(parameters(reference), parameters(candidate), strict=True):
        torch.testing.assert_close(cand, ref, rtol=1e-4, atol=1e-6)
    for name in ("actor", "critic"):  # observation normalisers
        ref_norm, cand_norm = getattr(reference, name).obs_normalizer, getattr(candidate, name).obs_normalizer
        torch.testing.assert_close(cand_norm._mean, ref_norm._mean)
        torch.testing.assert_close(cand_norm._var, ref_norm._var)


@pytest.mark.parametrize(("schedule", "desired_kl", "lr_moves"), [
    ("adaptive", 1e-7, "down"),   # every mini-batch overshoots: the rate falls to its floor
    ("adaptive", 0.01, None),
    ("adaptive", 10.0, "up"),     # every mini-batch undershoots: the rate rises to its ceiling
    ("fixed", 0.01, "stays"),
])
@pytest.mark.parametrize(("device", "capture"), DEVICE_MODES)
def test_update_matches_rsl_rl_ppo(schedule, desired_kl, lr_moves, device, capture):
    ref = build("PPO", schedule=schedule, desired_kl=desired_kl, device=device)
    cand = build(SYNC_FREE, schedule=schedule, desired_kl=desired_kl, device=device, capture_update=capture)
    assert isinstance(cand, SyncFreePPO) and type(ref) is PPO
    ref_history, cand_history = train(ref, 4, data_seed=7), train(cand, 4, data_seed=7)
    assert_same_training(ref, cand, ref_history, cand_history)
    # on the GPU with capture on, updates 2-4 replayed a graph (the first one ran eagerly to warm up)
    assert (cand._graph is not None) == (device == "cuda" and capture == "auto")
    final = cand_history[-1]["lr"]
    if lr_moves == "down":
        assert final < START_LR
    elif lr_moves == "up":
        assert final > START_LR
    elif lr_moves == "stays":
        assert final == START_LR


def test_recurrent_update_matches_rsl_rl_ppo():
    ref, cand = build("PPO", rnn=True), build(SYNC_FREE, rnn=True)
    assert cand.actor.is_recurrent and cand.capture_update is False
    assert_same_training(ref, cand, train(ref, 3, data_seed=9), train(cand, 3, data_seed=9))


@pytest.mark.parametrize(("device", "capture"), DEVICE_MODES)
def test_checkpoint_round_trip_and_rsl_rl_can_load_it(device, capture):
    trained = build(SYNC_FREE, desired_kl=1e-7, device=device, capture_update=capture)
    train(trained, 2, data_seed=3)
    saved = copy.deepcopy(trained.save())
    assert all(type(g["lr"]) is float and not g["capturable"] for g in saved["optimizer_state_dict"]["param_groups"])
    assert saved["optimizer_state_dict"]["param_groups"][0]["lr"] == pytest.approx(trained.learning_rate, rel=1e-6)

    # `resumed` has trained (and on the GPU captured its update) before loading: nothing of that may survive
    resumed, plain = build(SYNC_FREE, device=device, capture_update=capture), build("PPO", device=device)
    train(resumed, 2, data_seed=11)
    resumed.load(copy.deepcopy(saved), None, strict=True)
    plain.load(copy.deepcopy(saved), None, strict=True)
    assert resumed.learning_rate == pytest.approx(trained.learning_rate, rel=1e-6)
    # Training on from the checkpoint continues identically in both implementations.
    assert_same_training(plain, resumed, train(plain, 2, data_seed=5), train(resumed, 2, data_seed=5))


@pytest.mark.parametrize(("key", "value", "message"), [
    ("optimizer", "sgd", "train.algorithm.optimizer=sgd is not supported by SyncFreePPO (valid: adam, adamw)"),
    ("symmetry_cfg", {"use_data_augmentation": True, "data_augmentation_func": "torch:clone"},
     "train.algorithm.symmetry_cfg is not supported"),
    ("capture_update", "yes", "train.algorithm.capture_update='yes' is not valid; valid: auto, True, False"),
    ("capture_update", True, "train.algorithm.capture_update=True needs a CUDA rl_device; use auto or False"),
])
def test_unsupported_settings_are_rejected_with_the_key(key, value, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        build(SYNC_FREE, **{key: value})


# gloo on the CPU stands in for NCCL everywhere; with two GPUs the same test runs over NCCL with the update
# captured, all-reduces inside the graph, which must also let the ranks leave the process group and exit.
BACKENDS = ["gloo"] + (["nccl"] if torch.cuda.device_count() >= 2 else [])
EXIT_WITHIN_S = 300


def _two_rank_worker(rank: int, world: int, init_file: str, backend: str, results) -> None:
    device = "cpu"
    if backend == "nccl":
        device = f"cuda:{rank}"
        torch.cuda.set_device(device)
    dist.init_process_group(backend, init_method=f"file://{init_file}", rank=rank, world_size=world)
    algorithms = []
    try:
        torch.set_num_threads(1)
        multi = {"global_rank": rank, "local_rank": rank, "world_size": world}
        out = {}
        for name in ("PPO", SYNC_FREE):
            alg = build(name, multi_gpu=multi, device=device, desired_kl=0.002)
            algorithms.append(alg)
            alg.broadcast_parameters()
            history = train(alg, 3, data_seed=100 + rank)  # each rank its own data, as each GPU its own worlds
            out[name] = (history, parameters(alg), getattr(alg, "_graph", None) is not None)
        results[rank] = out
    finally:
        for alg in algorithms:
            if hasattr(alg, "release_graph"):
                alg.release_graph()
        dist.destroy_process_group()


@pytest.mark.parametrize("backend", BACKENDS)
def test_two_process_update_matches_rsl_rl_distributed_ppo(tmp_path, backend):
    """Gradient and KL averaging over two ranks, then a clean exit."""
    world = 2
    with mp.Manager() as manager:
        results = manager.dict()
        ranks = mp.spawn(_two_rank_worker, args=(world, str(tmp_path / "rendezvous"), backend, results),
                         nprocs=world, join=False)
        deadline = time.monotonic() + EXIT_WITHIN_S
        while not ranks.join(timeout=5):
            if time.monotonic() > deadline:
                for process in ranks.processes:
                    process.kill()
                pytest.fail(f"{backend}: the ranks did not exit within {EXIT_WITHIN_S} s "
                            f"(finished training: ranks {sorted(results.keys())})")
        results = dict(results)
    for rank in range(world):
        ref_history, ref_params, _ = results[rank]["PPO"]
        cand_history, cand_params, captured = results[rank][SYNC_FREE]
        assert captured == (backend == "nccl")
        for ref, cand in zip(ref_history, cand_history):
            # rsl-rl-lib broadcasts the rate as a float32 tensor, rounding it once per mini-batch
            assert cand["lr"] == pytest.approx(ref["lr"], rel=1e-6)
            assert cand["lr"] != START_LR  # the rule did act
            assert cand["value"] == pytest.approx(ref["value"], rel=1e-4, abs=1e-6)
        for ref, cand in zip(ref_params, cand_params, strict=True):
            torch.testing.assert_close(cand, ref, rtol=1e-4, atol=1e-6)
    # The ranks trained on different data yet hold the same weights: gradients were averaged.
    for p0, p1 in zip(results[0][SYNC_FREE][1], results[1][SYNC_FREE][1], strict=True):
        torch.testing.assert_close(p0, p1, rtol=0, atol=0)


def test_bounds_loss_equals_rl_games_formula():
    """rl_games' bounds loss, written here with plain Python on each sample."""
    from isaacgymenvs_mw.learning.ppo import bounds_loss

    mean = torch.randn(64, 5, generator=torch.Generator().manual_seed(3)) * 2.0
    expected = sum(sum(max(m - 1.1, 0.0) ** 2 + min(m + 1.1, 0.0) ** 2 for m in row) for row in mean.tolist()) / 64
    assert bounds_loss(mean).item() == pytest.approx(expected, rel=1e-6)
    assert bounds_loss(torch.full((4, 3), 1.05)).item() == 0.0  # inside the soft bound: nothing


def test_bounds_loss_pulls_action_means_back_inside():
    """Action means pushed to about 3 (beyond the clipped range): with bounds_loss_coef the updates bring them
    back towards +-1.1 faster than the task's reward alone does (Adam bounds each step: 24 steps at lr 1e-3)."""
    def trained_mean(coef: float) -> float:
        alg = build(SYNC_FREE, bounds_loss_coef=coef, entropy_coef=0.0)
        with torch.no_grad():
            alg.actor.mlp[-1].bias.fill_(3.0)
        train(alg, 4, data_seed=7)
        with torch.inference_mode():
            alg.actor(observations(torch.Generator().manual_seed(9)))
            return float(alg.actor.output_distribution_params[0].abs().mean())

    assert trained_mean(1.0) < trained_mean(0.0) - 0.2  # measured 2.36 against 2.68


@pytest.mark.parametrize("value", [-1.0, "abc"])
def test_bad_bounds_loss_coef_names_the_key(value):
    from isaacgymenvs_mw.utils.errors import ConfigError

    with pytest.raises(ConfigError, match=r"^train\.algorithm\.bounds_loss_coef=.* is invalid: give a number >= 0$"):
        build(SYNC_FREE, bounds_loss_coef=value)


# ---------------------------------------------------------------- learning-rate bounds of the adaptive schedule

@pytest.mark.parametrize(("kl", "low", "high"), [
    (1.0, 1.5e-4, 1e-2),   # far above 2 x desired_kl: each step divides by 1.5, stopping at the floor
    (1e-9, 1e-5, 4e-3),    # far below desired_kl / 2 (but > 0): each step multiplies by 1.5, up to the ceiling
])
def test_adaptive_rule_stops_at_the_configured_bounds(kl, low, high):
    """Step by step against the rule written out: lr / 1.5 floored at the minimum, lr * 1.5 capped at the maximum.
    1e-3 / 1.5**5 and 1e-3 * 1.5**4 overshoot the bounds, so a missing or hard-coded clamp gives another rate."""
    alg = build(SYNC_FREE, desired_kl=0.01, learning_rate_min=low, learning_rate_max=high)
    expected = START_LR
    for _ in range(8):
        alg._adapt_learning_rate(torch.tensor(kl, dtype=torch.float64))
        expected = max(low, expected / 1.5) if kl > 0.02 else min(high, expected * 1.5)
        assert alg._lr64.item() == expected
        assert alg._lr.item() == torch.tensor(expected, dtype=torch.float32).item()  # the rate Adam reads
    assert expected == (low if kl > 0.02 else high)


@pytest.mark.parametrize(("desired_kl", "bound"), [(1e-7, "min"), (10.0, "max")])
def test_training_ends_exactly_at_the_bound(desired_kl, bound):
    """Four updates (24 mini-batches) with every KL far outside the band: the rate ends at the bound, never past it."""
    low, high = 1.5e-4, 4e-3
    alg = build(SYNC_FREE, desired_kl=desired_kl, learning_rate_min=low, learning_rate_max=high)
    rates = [h["lr"] for h in train(alg, 4, data_seed=7)]
    assert all(low <= rate <= high for rate in rates)
    assert rates[-1] == (low if bound == "min" else high)


def test_resumed_rate_outside_narrower_bounds_starts_at_the_nearest_bound():
    trained = build(SYNC_FREE, desired_kl=10.0)  # the rate climbs to rsl-rl-lib's ceiling, 1e-2
    train(trained, 2, data_seed=3)
    assert trained.learning_rate == 1e-2
    resumed = build(SYNC_FREE, desired_kl=10.0, learning_rate_max=2e-3)
    resumed.load(copy.deepcopy(trained.save()), None, strict=True)
    assert resumed.learning_rate == 2e-3 and resumed._lr64.item() == 2e-3
    assert resumed.optimizer.param_groups[0]["lr"].item() == torch.tensor(2e-3).item()


@pytest.mark.parametrize(("settings", "message"), [
    ({"learning_rate_min": 0.0}, r"train\.algorithm\.learning_rate_min=0\.0 is invalid: give a number > 0\.0"),
    ({"learning_rate_max": -1e-3}, r"train\.algorithm\.learning_rate_max=-0\.001 is invalid: give a number > 0\.0"),
    ({"learning_rate_min": "abc"}, r"train\.algorithm\.learning_rate_min='abc' is invalid: give a number > 0\.0"),
    ({"learning_rate_min": 2e-3, "learning_rate_max": 1e-3},
     r"train\.algorithm\.learning_rate_min=0\.002 is invalid: give a number <= train\.algorithm\.learning_rate_max "
     r"\(0\.001\)"),
    ({"learning_rate_min": 2e-3},  # above the starting learning_rate, 1e-3
     r"train\.algorithm\.learning_rate=0\.001 is invalid with the adaptive schedule: give a number within "
     r"\[train\.algorithm\.learning_rate_min, train\.algorithm\.learning_rate_max\] = \[0\.002, 0\.01\]"),
    ({"learning_rate_max": 5e-4},
     r"train\.algorithm\.learning_rate=0\.001 is invalid with the adaptive schedule: give a number within "
     r"\[train\.algorithm\.learning_rate_min, train\.algorithm\.learning_rate_max\] = \[1e-05, 0\.0005\]"),
    ({"schedule": "fixed", "learning_rate_max": 5e-3},
     r"train\.algorithm\.learning_rate_max=0\.005 has no effect: the learning rate moves only with "
     r"train\.algorithm\.schedule=adaptive and a train\.algorithm\.desired_kl \(got schedule='fixed', "
     r"desired_kl=0\.01\); remove it or set both"),
    ({"desired_kl": None, "learning_rate_min": 1e-4},
     r"train\.algorithm\.learning_rate_min=0\.0001 has no effect: .* \(got schedule='adaptive', desired_kl=None\); remove it or set both"),
])
def test_bad_learning_rate_bounds_name_the_key(settings, message):
    from isaacgymenvs_mw.utils.errors import ConfigError

    with pytest.raises(ConfigError, match=f"^{message}$"):
        build(SYNC_FREE, **settings)


def test_default_bounds_are_accepted_with_the_fixed_schedule():
    alg = build(SYNC_FREE, schedule="fixed", learning_rate_min=1e-5, learning_rate_max=1e-2)
    assert train(alg, 1, data_seed=7)[-1]["lr"] == START_LR
