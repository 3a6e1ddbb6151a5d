"""rl_games' value normalisation in SyncFreePPO (``algorithm.normalize_value``), against references written here.

The references: numpy's weighted mean and variance over everything the statistics were fed (rl_games' RunningMeanStd
starts from mean 0, variance 1, count 1, i.e. the points -1 and +1 at weight 1/2 each); the value loss written out
from the stored batch; GAE written out in real units; and, with the option off, rsl-rl-lib's own PPO.
"""

from __future__ import annotations

import copy
import time

import numpy as np
import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

from isaacgymenvs_mw.learning.ppo import VALUE_NORMALIZER_KEY, SyncFreePPO, ValueNormalizer
from isaacgymenvs_mw.utils.errors import ConfigError
from test_ppo import (ACTIONS, NUM_ENVS, NUM_STEPS, SYNC_FREE, assert_same_training, build, observations, parameters,
                      train)

EPS, CLAMP = 1e-5, 5.0  # rl_games' RunningMeanStd epsilon and clamp
# conftest's CPU_ARGS, repeated: importing conftest here would make every spawned rank import Warp and the simulator
CPU_ARGS = ["sim_device=cpu", "rl_device=cpu", "headless=True"]


def numpy_stats(*fed: np.ndarray) -> tuple[float, float]:
    """Mean and (population) variance of everything fed, plus rl_games' prior (count 1, mean 0, variance 1)."""
    data = np.concatenate([np.asarray(x, dtype=np.float64).ravel() for x in fed])
    points = np.concatenate([[-1.0, 1.0], data])
    weights = np.concatenate([[0.5, 0.5], np.ones_like(data)])
    mean = np.average(points, weights=weights)
    return float(mean), float(np.average((points - mean) ** 2, weights=weights))


def normalised(x: np.ndarray, mean: float, var: float) -> np.ndarray:
    return np.clip((x - mean) / np.sqrt(var + EPS), -CLAMP, CLAMP)


def recorded_updates(alg) -> list[dict]:
    """Make ``alg.update`` record the rollout it is about to learn from (real units) and the critic before it."""
    records: list[dict] = []
    update = alg.update

    def recording_update():
        st = alg.storage
        records.append({"values": st.values.double().numpy().copy(), "returns": st.returns.double().numpy().copy(),
                        "observations": st.observations.flatten(0, 1).clone(),
                        "critic": copy.deepcopy(alg.critic)})
        records[-1]["losses"] = update()
        return records[-1]["losses"]

    alg.update = recording_update
    return records


def rollout(alg, data: torch.Generator, reward: float | None = None, time_out_rate: float = 0.0) -> None:
    """One rollout on synthetic data: a constant ``reward``, or test_ppo's reward shaped by the actions scaled up,
    so that returns are far from the critic's unit scale."""
    obs = observations(data)
    for _ in range(NUM_STEPS):
        with torch.inference_mode():
            actions = alg.act(obs)
            next_obs = observations(data)
            if reward is None:
                rewards = 50.0 - 5.0 * (actions - obs["policy"][:, :ACTIONS]).pow(2).sum(dim=1)
            else:
                rewards = torch.full((NUM_ENVS,), reward)
            time_outs = (torch.rand(NUM_ENVS, generator=data) < time_out_rate).float()
            alg.process_env_step(next_obs, rewards, time_outs, {"time_outs": time_outs})
        obs = next_obs
    with torch.inference_mode():
        alg.compute_returns(obs)


# ---------------------------------------------------------------------------------------------------- statistics


def test_running_statistics_equal_numpy_over_everything_fed():
    """Chan's parallel merge, batch by batch, equals numpy over all batches at once (rl_games' RunningMeanStd)."""
    rng = np.random.default_rng(0)
    norm = ValueNormalizer("cpu")
    fed = []
    for scale, shift in ((1.0, 0.0), (30.0, 200.0), (0.1, -5.0), (500.0, 1e3)):
        values, returns = rng.normal(shift, scale, (8, 16, 1)), rng.normal(shift * 1.1, scale * 2, (8, 16, 1))
        norm.update(torch.tensor(values, dtype=torch.float32), torch.tensor(returns, dtype=torch.float32))
        fed += [values.astype(np.float32), returns.astype(np.float32)]
        mean, var = numpy_stats(*fed)
        assert norm.running_mean.item() == pytest.approx(mean, rel=1e-6, abs=1e-9)
        assert norm.running_var.item() == pytest.approx(var, rel=1e-6)
        assert norm.count.item() == 1 + sum(x.size for x in fed)
    assert norm.running_mean.dtype == torch.float64  # rl_games keeps its running statistics in float64


def test_normalised_values_and_the_critics_output_are_clamped_to_five_standard_deviations():
    """rl_games' RunningMeanStd clamps a normalised value to +-5, and the critic's output to +-5 before it is
    un-normalised."""
    norm = ValueNormalizer("cpu")
    with torch.no_grad():
        norm.running_mean.fill_(10.0)
        norm.running_var.fill_(4.0)
    std = np.sqrt(4.0 + EPS)
    real = torch.tensor([10.0, 10.0 + 3 * std, 10.0 + 20 * std, -1000.0])
    np.testing.assert_allclose(norm.normalize(real).numpy(), [0.0, 3.0, 5.0, -5.0], rtol=1e-6, atol=1e-6)
    raw = torch.tensor([0.0, -2.0, 7.0, -9.0])
    np.testing.assert_allclose(norm.denormalize(raw).numpy(), 10.0 + std * np.array([0.0, -2.0, 5.0, -5.0]),
                               rtol=1e-6)


def test_a_nonfinite_batch_leaves_the_statistics_as_they_were():
    norm = ValueNormalizer("cpu")
    norm.update(torch.arange(10.0), torch.arange(10.0) * 2)
    before = [t.clone() for t in norm.buffers()]
    bad = torch.arange(10.0)
    bad[3] = float("nan")
    norm.update(bad)
    assert all(torch.equal(a, b) for a, b in zip(before, norm.buffers()))


@pytest.mark.parametrize("rnn", [False, True])
def test_ppo_feeds_the_rollouts_real_values_and_returns_to_the_statistics(rnn):
    alg = build(SYNC_FREE, normalize_value=True, rnn=rnn)
    records = recorded_updates(alg)
    data = torch.Generator().manual_seed(4)
    torch.manual_seed(5)
    buffers = [id(t) for t in alg.value_normalizer.buffers()]
    for _ in range(3):
        rollout(alg, data, time_out_rate=0.05)
        alg.update()
    mean, var = numpy_stats(*[r[key] for r in records for key in ("values", "returns")])
    assert alg.value_normalizer.running_mean.item() == pytest.approx(mean, rel=1e-6)
    assert alg.value_normalizer.running_var.item() == pytest.approx(var, rel=1e-6)
    assert mean > 50  # real units (rewards of about 20 a step), far from the critic's scale
    # updated in place: a captured update keeps reading the same tensors
    assert [id(t) for t in alg.value_normalizer.buffers()] == buffers
    assert all(np.isfinite(list(r["losses"].values())).all() for r in records)


# ---------------------------------------------------------------------------------------------------- the loss


@pytest.mark.parametrize("clipped", [True, False])
def test_value_loss_is_computed_on_the_normalised_scale(clipped):
    """One update of one mini-batch: the reported value loss is the critic's output against the returns normalised
    with the statistics after this rollout (clip around the normalised old values), written out here."""
    alg = build(SYNC_FREE, normalize_value=True, num_learning_epochs=1, num_mini_batches=1,
                use_clipped_value_loss=clipped)
    records = recorded_updates(alg)
    data = torch.Generator().manual_seed(8)
    torch.manual_seed(9)
    for _ in range(2):  # the second update starts from statistics that the first one moved
        rollout(alg, data, time_out_rate=0.05)
        alg.update()
    fed = []
    for record in records:
        fed += [record["values"], record["returns"]]
        mean, var = numpy_stats(*fed)
        with torch.no_grad():
            predicted = record["critic"](record["observations"]).double().numpy()
        returns = normalised(record["returns"].reshape(-1, 1), mean, var)
        old_values = normalised(record["values"].reshape(-1, 1), mean, var)
        if clipped:
            moved = old_values + np.clip(predicted - old_values, -0.2, 0.2)
            expected = np.maximum((predicted - returns) ** 2, (moved - returns) ** 2).mean()
        else:
            expected = ((predicted - returns) ** 2).mean()
        assert record["losses"]["value"] == pytest.approx(expected, rel=1e-5)
        # what the loss would be in real units is orders of magnitude larger: the scale did change
        assert ((predicted - record["returns"].reshape(-1, 1)) ** 2).mean() > 100 * expected


# ---------------------------------------------------------------------------------------------------- real units


def test_constant_reward_returns_approach_r_over_one_minus_gamma_while_the_critic_stays_near_one():
    """Reward 10 every step, gamma 0.9, no episode ends: the true value is 100. The stored values and returns go
    there (real units) while the critic's own output stays within a few units (normalised)."""
    alg = build(SYNC_FREE, normalize_value=True, gamma=0.9, learning_rate=3e-3, schedule="fixed", entropy_coef=0.0)
    records = recorded_updates(alg)
    data = torch.Generator().manual_seed(2)
    torch.manual_seed(3)
    for _ in range(60):
        rollout(alg, data, reward=10.0)
        alg.update()
    last = records[-1]
    assert last["returns"].mean() == pytest.approx(100.0, rel=0.05)
    assert last["values"].mean() == pytest.approx(100.0, rel=0.05)
    with torch.no_grad():
        raw = alg.critic(observations(torch.Generator().manual_seed(0)))
    assert raw.abs().max() < 3.0
    assert alg.value_normalizer.running_mean.item() > 50.0


def test_rollout_stores_real_values_and_gae_and_time_out_bootstrap_use_them():
    """Values stored by act, the time-out bootstrap of the reward and GAE's last value are the critic's output
    un-normalised: sqrt(var + eps) * clamp(output, +-5) + mean. GAE written out here over the stored rollout."""
    alg = build(SYNC_FREE, normalize_value=True, gamma=0.95, lam=0.9)
    with torch.no_grad():  # statistics far from the prior, so that units matter
        alg.value_normalizer.running_mean.fill_(40.0)
        alg.value_normalizer.running_var.fill_(81.0)
    scale = np.sqrt(81.0 + EPS)
    data = torch.Generator().manual_seed(6)
    torch.manual_seed(7)
    obs = observations(data)
    rewards, dones = [], []
    for _ in range(NUM_STEPS):
        with torch.inference_mode():
            actions = alg.act(obs)
            real = np.clip(alg.critic(obs).double().numpy()[:, 0], -5, 5) * scale + 40.0
            np.testing.assert_allclose(alg.transition.values.double().numpy()[:, 0], real, rtol=1e-6)
            next_obs = observations(data)
            reward = 3.0 - actions.pow(2).sum(dim=1)
            done = (torch.rand(NUM_ENVS, generator=data) < 0.2).float()
            time_out = done * (torch.rand(NUM_ENVS, generator=data) < 0.5).float()
            rewards.append(reward.double().numpy() + 0.95 * time_out.double().numpy() * real)  # bootstrapped
            dones.append(done.double().numpy())
            alg.process_env_step(next_obs, reward, done, {"time_outs": time_out})
        obs = next_obs
    with torch.inference_mode():
        last = np.clip(alg.critic(obs).double().numpy()[:, 0], -5, 5) * scale + 40.0
        alg.compute_returns(obs)
    st = alg.storage
    np.testing.assert_allclose(st.rewards.double().numpy()[..., 0], np.stack(rewards), rtol=1e-5, atol=1e-4)
    values = st.values.double().numpy()[..., 0]
    expected, advantage = np.zeros_like(values), np.zeros(NUM_ENVS)
    for t in reversed(range(NUM_STEPS)):
        following = last if t == NUM_STEPS - 1 else values[t + 1]
        delta = np.stack(rewards)[t] + 0.95 * (1 - dones[t]) * following - values[t]
        advantage = delta + 0.95 * 0.9 * (1 - dones[t]) * advantage
        expected[t] = advantage + values[t]
    np.testing.assert_allclose(st.returns.double().numpy()[..., 0], expected, rtol=1e-5, atol=1e-3)


def test_cartpole_training_with_value_normalization(make_cartpole):
    """The real runner on Cartpole (16 envs): the stored values are the critic's output un-normalised with the
    statistics of the rollout, and a few iterations train to finite losses."""
    from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
    from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
    from isaacgymenvs_mw.utils.config import compose_config, to_dict

    cfg = compose_config(["task=Cartpole", *CPU_ARGS, "+train.algorithm.normalize_value=True"])
    runner = Runner(RslRlVecEnv(make_cartpole(16)), rsl_rl_config(to_dict(cfg.train)), log_dir=None, device="cpu")
    alg = runner.alg
    assert isinstance(alg, SyncFreePPO) and alg.value_normalizer is not None
    records = recorded_updates(alg)
    runner.learn(3)
    fed = []
    for record in records:
        with torch.no_grad():
            raw = record["critic"](record["observations"]).double().numpy()
        mean, var = numpy_stats(*fed) if fed else (0.0, 1.0)  # the statistics during this rollout
        stored = record["values"].reshape(-1, 1)
        np.testing.assert_allclose(stored, np.clip(raw, -5, 5) * np.sqrt(var + EPS) + mean, rtol=1e-5, atol=1e-5)
        fed += [record["values"], record["returns"]]
    assert all(np.isfinite(list(r["losses"].values())).all() for r in records)


# ---------------------------------------------------------------------------------------------------- checkpoints


def test_checkpoint_round_trip_restores_the_statistics_in_place():
    trained = build(SYNC_FREE, normalize_value=True)
    data = torch.Generator().manual_seed(1)
    for _ in range(2):
        rollout(trained, data)
        trained.update()
    saved = copy.deepcopy(trained.save())
    assert set(saved[VALUE_NORMALIZER_KEY]) == {"running_mean", "running_var", "count"}

    resumed = build(SYNC_FREE, normalize_value=True)
    rollout(resumed, torch.Generator().manual_seed(2), reward=-3.0)
    resumed.update()
    buffers = [id(t) for t in resumed.value_normalizer.buffers()]
    resumed.load(copy.deepcopy(saved), None, strict=True)
    for name, tensor in trained.value_normalizer.state_dict().items():
        assert torch.equal(resumed.value_normalizer.state_dict()[name], tensor), name
    assert [id(t) for t in resumed.value_normalizer.buffers()] == buffers
    # Training on continues identically.
    for alg in (trained, resumed):
        torch.manual_seed(11)
        rollout(alg, torch.Generator().manual_seed(3))
        alg.update()
    for a, b in zip(parameters(trained), parameters(resumed), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)

    # The statistics belong to the critic: a load that skips the critic skips them; rsl-rl-lib's PPO ignores them.
    fresh = build(SYNC_FREE, normalize_value=True)
    fresh.load(copy.deepcopy(saved), {"actor": True, "critic": False, "optimizer": True}, strict=True)
    assert fresh.value_normalizer.running_mean.item() == 0.0 and fresh.value_normalizer.count.item() == 1.0
    build("PPO").load(copy.deepcopy(saved), None, strict=True)


# ---------------------------------------------------------------------------------------------------- off


def test_off_by_default_and_off_is_todays_update():
    """normalize_value False: no statistics, nothing saved, and training equals both the default (bit for bit) and
    rsl-rl-lib's PPO (test_ppo's reference)."""
    ref, default, off = build("PPO"), build(SYNC_FREE), build(SYNC_FREE, normalize_value=False)
    assert default.value_normalizer is None and off.value_normalizer is None
    histories = [train(alg, 3, data_seed=7) for alg in (ref, default, off)]
    assert histories[1] == histories[2]
    for a, b in zip(parameters(default), parameters(off), strict=True):
        assert torch.equal(a, b)
    assert_same_training(ref, off, histories[0], histories[2])
    assert VALUE_NORMALIZER_KEY not in off.save()


# ---------------------------------------------------------------------------------------------------- bad values


@pytest.mark.parametrize("value", ["yes", 1, 0, None, "True", 1.0])
def test_bad_normalize_value_names_the_key_the_value_and_what_is_valid(value):
    with pytest.raises(ConfigError) as caught:
        build(SYNC_FREE, normalize_value=value)
    message = str(caught.value)
    assert message == f"train.algorithm.normalize_value={value!r} is invalid: give True or False"
    assert "\n" not in message


def test_bad_normalize_value_from_the_command_line_is_the_same_one_line_error(make_cartpole):
    from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
    from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
    from isaacgymenvs_mw.utils.config import compose_config, to_dict

    cfg = compose_config(["task=Cartpole", *CPU_ARGS, "+train.algorithm.normalize_value=yes"])
    with pytest.raises(ConfigError, match=r"^train\.algorithm\.normalize_value='yes' is invalid: give True or False$"):
        Runner(RslRlVecEnv(make_cartpole(8)), rsl_rl_config(to_dict(cfg.train)), log_dir=None, device="cpu")


# ---------------------------------------------------------------------------------------------------- two ranks


def _two_rank_worker(rank: int, world: int, init_file: str, results) -> None:
    dist.init_process_group("gloo", init_method=f"file://{init_file}", rank=rank, world_size=world)
    try:
        torch.set_num_threads(1)
        rng = np.random.default_rng(rank)
        norm = ValueNormalizer("cpu")
        fed = [rng.normal(10.0 * (rank + 1), 3.0 + rank, (8, 4, 1)) for _ in range(2)]
        norm.update(*(torch.tensor(x) for x in fed))
        alg = build(SYNC_FREE, multi_gpu={"global_rank": rank, "local_rank": rank, "world_size": world},
                    normalize_value=True)
        alg.broadcast_parameters()
        data = torch.Generator().manual_seed(100 + rank)  # each rank its own data, as each GPU its own worlds
        for _ in range(2):
            rollout(alg, data)
            alg.update()
        results[rank] = (fed, norm.state_dict(), alg.value_normalizer.state_dict(), parameters(alg))
    finally:
        dist.destroy_process_group()


def test_two_ranks_keep_the_statistics_of_both_ranks_data(tmp_path):
    world = 2
    with mp.Manager() as manager:
        results = manager.dict()
        ranks = mp.spawn(_two_rank_worker, args=(world, str(tmp_path / "rendezvous"), results), nprocs=world,
                         join=False)
        deadline = time.monotonic() + 300
        while not ranks.join(timeout=5):
            if time.monotonic() > deadline:
                for process in ranks.processes:
                    process.kill()
                pytest.fail("the ranks did not finish within 300 s")
        results = dict(results)
    # the first batch of each rank merged together, then the second of each: the same as numpy over all four
    mean, var = numpy_stats(*results[0][0], *results[1][0])
    for rank in range(world):
        stats = results[rank][1]
        assert stats["running_mean"].item() == pytest.approx(mean, rel=1e-9)
        assert stats["running_var"].item() == pytest.approx(var, rel=1e-9)
        assert stats["count"].item() == 1 + 4 * 32
    for name in ("running_mean", "running_var", "count"):  # the learners' statistics: identical on both ranks
        assert torch.equal(results[0][2][name], results[1][2][name])
    for p0, p1 in zip(results[0][3], results[1][3], strict=True):
        torch.testing.assert_close(p0, p1, rtol=0, atol=0)
