"""Cartpole reward and reset against an independent numpy version of IsaacGymEnvs' formulas (the task's failure
test and reward function, with VecTask's time limit: an episode ends when progress reaches the cap - 1)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from cartpole_reference import cartpole_reward_reference, joint_addresses, mj_step_batch
from isaacgymenvs_mw.tasks.cartpole import cartpole_failed, compute_cartpole_reward


def call_package(x, xd, th, thd, reset_dist, progress, max_len):
    f = lambda a: torch.tensor(np.asarray(a, np.float32))  # noqa: E731
    failed = cartpole_failed(f(x), f(th), reset_dist)
    rew = compute_cartpole_reward(cart_vel=f(xd), pole_angle=f(th), pole_vel=f(thd), failed=failed)
    reset = failed | (torch.tensor(np.asarray(progress, np.int64)) >= max_len - 1)
    return rew, reset.long()


@pytest.mark.parametrize("reset_dist,max_len", [(3.0, 500), (2.4, 10)])
def test_compute_cartpole_reward_random_inputs(reset_dist, max_len):
    rng = np.random.default_rng(7)
    n = 4000
    x = rng.uniform(-4, 4, n).astype(np.float32)
    xd = rng.uniform(-10, 10, n).astype(np.float32)
    th = rng.uniform(-3.2, 3.2, n).astype(np.float32)
    thd = rng.uniform(-12, 12, n).astype(np.float32)
    progress = rng.integers(0, max_len + 5, n)
    rew, reset = call_package(x, xd, th, thd, reset_dist, progress, max_len)
    ref_rew, ref_reset, failed = cartpole_reward_reference(x, xd, th, thd, reset_dist, progress, max_len)
    assert rew.dtype == torch.float32 and rew.shape == (n,)
    assert reset.dtype == torch.long and reset.shape == (n,)
    # the random draw covers every branch
    assert failed.any() and (~failed).any() and (ref_reset & ~failed).any() and (~ref_reset).any()
    np.testing.assert_array_equal(reset.numpy(), ref_reset.astype(np.int64))
    np.testing.assert_allclose(rew.numpy(), ref_rew, rtol=1e-5, atol=1e-5)


def test_compute_cartpole_reward_boundaries():
    half_pi = math.pi / 2
    eps = 1e-3
    #            x        xd    θ                 θ̇     progress
    rows = [
        (3.0,      0.5,  0.1,              0.2,   0),    # |x| == resetDist: not a failure (strict >)
        (-3.0,    -0.5,  -0.1,             -0.2,  0),
        (3.0001,   0.0,  0.0,              0.0,   0),    # just beyond: failure
        (-3.0001,  0.0,  0.0,              0.0,   0),
        (0.0,      0.0,  half_pi - eps,    0.0,   0),    # just below π/2: no failure, reward 1 - θ²
        (0.0,      0.0,  -(half_pi - eps), 0.0,   0),
        (0.0,      0.0,  half_pi + eps,    0.0,   0),    # just above: failure
        (0.0,      0.0,  -(half_pi + eps), 0.0,   0),
        (0.0,      0.0,  0.0,              0.0,   497),  # progress L-3: running
        (0.0,      0.0,  0.0,              0.0,   498),  # progress L-2: running
        (0.0,      0.0,  0.0,              0.0,   499),  # progress L-1: reset (time limit), reward unchanged
        (0.0,      0.0,  0.0,              0.0,   650),  # beyond: reset
        (1.0,      -4.0, 0.3,              -2.0,  499),  # time limit with a normal reward
        (3.5,      0.0,  2.0,              0.0,   499),  # failure at the time limit: -2 and reset
        (0.0,      0.0,  0.0,              0.0,   0),    # upright and still: the maximum reward 1
    ]
    x, xd, th, thd, progress = (np.array(c) for c in zip(*rows))
    rew, reset = call_package(x, xd, th, thd, 3.0, progress, 500)
    # values worked out by hand from the formula
    expected_reset = [0, 0, 1, 1, 0, 0, 1, 1, 0, 0, 1, 1, 1, 1, 0]
    assert reset.tolist() == expected_reset
    assert rew[14].item() == 1.0 and rew[8].item() == 1.0 and rew[10].item() == 1.0
    assert torch.all(rew[[2, 3, 6, 7, 13]] == -2.0)
    np.testing.assert_allclose(rew[0].item(), 1 - 0.1**2 - 0.01 * 0.5 - 0.005 * 0.2, rtol=1e-6)
    np.testing.assert_allclose(rew[4].item(), 1 - (half_pi - eps) ** 2, rtol=1e-5)
    np.testing.assert_allclose(rew[12].item(), 1 - 0.09 - 0.04 - 0.01, rtol=1e-6)
    ref_rew, ref_reset, _ = cartpole_reward_reference(
        x.astype(np.float32), xd.astype(np.float32), th.astype(np.float32), thd.astype(np.float32), 3.0, progress, 500
    )
    np.testing.assert_array_equal(reset.numpy(), ref_reset.astype(np.int64))
    np.testing.assert_allclose(rew.numpy(), ref_rew, rtol=1e-5, atol=1e-6)


def test_task_reward_and_resets_on_written_states(make_cartpole):
    """End to end: written states + actions -> one env step; reference = MuJoCo C step + numpy formulas."""
    n = 16
    max_len = 20
    task = make_cartpole(n, overrides=[f"task.env.episodeLength_s={max_len * 0.0166}"])  # max_len policy steps
    assert task.max_episode_length == max_len
    model = task.sim.mj_model
    cq, pq, cv, pv = joint_addresses(model)
    task.reset()
    rng = np.random.default_rng(3)
    x = rng.uniform(-2.5, 2.5, n)
    th = rng.uniform(-1.0, 1.0, n)
    x[[0, 5]] = [3.4, -3.6]          # cart beyond resetDist
    th[[1, 9]] = [2.2, -1.9]         # pole past horizontal
    x[2], th[2] = 3.7, -2.5          # both
    xd = rng.uniform(-1.0, 1.0, n)
    thd = rng.uniform(-1.0, 1.0, n)
    q0 = np.zeros((n, 2), np.float32)
    v0 = np.zeros((n, 2), np.float32)
    q0[:, cq], q0[:, pq], v0[:, cv], v0[:, pv] = x, th, xd, thd
    task.sim.write_state(torch.ones(n, dtype=torch.bool), dof_pos=torch.from_numpy(q0), dof_vel=torch.from_numpy(v0))
    progress = rng.integers(0, max_len - 3, n)
    progress[[3, 11, 14]] = max_len - 2  # these reach the limit in this step
    task.progress_buf[:] = torch.from_numpy(progress)
    a = rng.uniform(-0.3, 0.3, (n, 1)).astype(np.float32)

    _, rew, reset, extras = task.step(torch.from_numpy(a))

    q1, v1 = mj_step_batch(model, q0, v0, a * np.float32(task.max_push_effort))
    ref_rew, ref_reset, failed = cartpole_reward_reference(
        q1[:, cq], v1[:, cv], q1[:, pq], v1[:, pv], task.reset_dist, progress + 1, max_len
    )
    assert failed.sum() == 5 and ref_reset.sum() == 8  # the scenario is what it is meant to be
    np.testing.assert_array_equal(reset.numpy(), ref_reset.astype(np.int64))
    np.testing.assert_allclose(rew.numpy(), ref_rew, atol=1e-4, rtol=0)
    np.testing.assert_array_equal(extras["time_outs"].numpy(), (ref_reset & ~failed).astype(np.int64))
    np.testing.assert_array_equal(task.progress_buf.numpy(), np.where(ref_reset, 0, progress + 1))
