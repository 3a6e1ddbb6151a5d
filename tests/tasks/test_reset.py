"""Partial resets: only the chosen envs change, others stay bit-identical; resets land in the noise ranges."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from cartpole_reference import mj_data_from

N = 8


def snapshot(task) -> dict[str, torch.Tensor]:
    s = task.sim
    return {"qpos": s.qpos.clone(), "qvel": s.qvel.clone(), "ctrl": s.ctrl.clone(), "xpos": s.xpos.clone(),
            "xquat": s.xquat.clone(), "progress": task.progress_buf.clone()}


def prepare(task):
    """A state that no reset can produce: everything outside the noise ranges and distinct per env."""
    task.reset()
    k = torch.arange(N, dtype=torch.float32)
    pos = torch.stack((0.5 + 0.1 * k, -0.4 - 0.05 * k), dim=1)
    vel = torch.stack((1.0 + k, -0.8 - 0.1 * k), dim=1)
    task.sim.write_state(torch.ones(N, dtype=torch.bool), dof_pos=pos, dof_vel=vel)
    task.sim.ctrl[:, 0] = 10.0 + k
    task.progress_buf[:] = torch.arange(1, N + 1)
    return snapshot(task)


def check_partial_reset(task, before, chosen: np.ndarray):
    after = snapshot(task)
    others = ~chosen
    for key in before:
        # bit-identical where not chosen
        assert torch.equal(after[key][torch.from_numpy(others)], before[key][torch.from_numpy(others)]), key
    sel = torch.from_numpy(chosen)
    assert torch.all(after["progress"][sel] == 0)
    pos, vel = after["qpos"][sel].numpy(), after["qvel"][sel].numpy()
    assert np.all(np.abs(pos) <= task.reset_position_noise)
    assert np.all(np.abs(vel) <= task.reset_velocity_noise)
    assert not np.any(pos == before["qpos"][sel].numpy()) and not np.any(vel == before["qvel"][sel].numpy())
    # The reset also cleared what carries over between steps: commands of the chosen worlds.
    assert torch.all(after["ctrl"][sel] == 0)


def test_write_state_refreshes_derived_quantities_of_chosen_worlds_only(make_cartpole):
    """sim.write_state(..., refresh=True): body poses of the written worlds match MuJoCo C kinematics."""
    task = make_cartpole(N)
    before = prepare(task)
    chosen = np.array([0, 1, 1, 0, 0, 0, 1, 0], dtype=bool)
    k = torch.arange(N, dtype=torch.float32)
    pos = torch.stack((-0.3 + 0.05 * k, 0.7 - 0.1 * k), dim=1)
    task.sim.write_state(torch.from_numpy(chosen), dof_pos=pos, dof_vel=torch.zeros_like(pos), refresh=True)
    after = snapshot(task)
    model = task.sim.mj_model
    for i in range(N):
        if chosen[i]:
            np.testing.assert_allclose(after["qpos"][i].numpy(), pos[i].numpy())
            d = mj_data_from(model, after["qpos"][i].numpy(), after["qvel"][i].numpy())
            mujoco.mj_kinematics(model, d)
            np.testing.assert_allclose(after["xpos"][i].numpy(), d.xpos, atol=1e-5)
            np.testing.assert_allclose(after["xquat"][i].numpy(), d.xquat, atol=1e-5)
        else:
            assert torch.equal(after["qpos"][i], before["qpos"][i])


def test_reset_envs_with_boolean_mask(make_cartpole):
    task = make_cartpole(N)
    before = prepare(task)
    chosen = np.array([1, 0, 1, 0, 0, 1, 0, 0], dtype=bool)
    task.reset_envs(torch.from_numpy(chosen))
    check_partial_reset(task, before, chosen)


@pytest.mark.parametrize("dtype", [torch.long, torch.int32])
def test_reset_envs_with_index_tensor(make_cartpole, dtype):
    task = make_cartpole(N)
    before = prepare(task)
    ids = torch.tensor([6, 1, 7], dtype=dtype)
    task.reset_envs(ids)
    chosen = np.zeros(N, dtype=bool)
    chosen[[1, 6, 7]] = True
    check_partial_reset(task, before, chosen)


def test_reset_envs_with_nothing_chosen_changes_nothing(make_cartpole):
    task = make_cartpole(N)
    before = prepare(task)
    task.reset_envs(torch.zeros(N, dtype=torch.bool))
    task.reset_envs(torch.tensor([], dtype=torch.long))
    after = snapshot(task)
    for key in before:
        assert torch.equal(after[key], before[key]), key


def test_reset_noise_covers_the_configured_ranges(make_cartpole):
    n = 16
    task = make_cartpole(n, overrides=["task.env.resetPositionNoise=0.3", "task.env.resetVelocityNoise=0.05"])
    pos, vel = [], []
    for _ in range(4):
        task.reset_envs(torch.ones(n, dtype=torch.bool))
        pos.append(task.sim.dof_pos.numpy().copy())
        vel.append(task.sim.dof_vel.numpy().copy())
    pos, vel = np.concatenate(pos), np.concatenate(vel)  # 64 samples per joint
    assert np.all(np.abs(pos) <= 0.3) and np.all(np.abs(vel) <= 0.05)
    # uniform on [-r, r]: with 64 samples each half-range tail is hit (failure probability ~1e-8 per check)
    for samples, r in ((pos, 0.3), (vel, 0.05)):
        for j in range(2):
            assert samples[:, j].max() > 0.5 * r and samples[:, j].min() < -0.5 * r
    # envs get different draws
    assert len(np.unique(pos[:n, 0])) == n


def test_reset_returns_observations_of_the_reset_state(make_cartpole):
    task = make_cartpole(N)
    prepare(task)
    obs = task.reset()["obs"].numpy()
    q, v = task.sim.dof_pos.numpy(), task.sim.dof_vel.numpy()
    np.testing.assert_array_equal(obs, np.stack([q[:, 0], v[:, 0], q[:, 1], v[:, 1]], axis=1))
    assert np.all(np.abs(obs[:, [0, 2]]) <= 0.1) and np.all(np.abs(obs[:, [1, 3]]) <= 0.25)
    assert torch.all(task.progress_buf == 0)


def test_the_episode_clock_is_vectasks_and_reset_idx_only_places(make_cartpole):
    task = make_cartpole(N)
    before = prepare(task)
    chosen = torch.tensor([0, 1, 1, 0, 0, 0, 1, 0], dtype=torch.bool)
    task.reset_idx(chosen)
    assert torch.equal(task.progress_buf, before["progress"])  # placed, but the clock runs on
    task.reset_envs(chosen)
    assert torch.equal(task.progress_buf, torch.where(chosen, 0, before["progress"]))


@pytest.mark.parametrize("how", ["reset", "reset_done"])
def test_reset_runs_after_reset_as_a_step_reset_does_before_the_observation(make_cartpole, how):
    # A port that draws its targets in after_reset (as IsaacGymEnvs-style tasks do per step) has them from step 0.
    task = make_cartpole(N)
    prepare(task)
    chosen = torch.tensor([1, 0, 1, 1, 0, 0, 0, 1], dtype=torch.bool)
    seen = []

    def after_reset(new_episode):
        seen.append((new_episode.clone(), task.progress_buf.clone()))
        cart = torch.full((N, 2), 0.0)
        cart[:, 0] = 0.07  # a placement the observation must show
        task.sim.write_state(new_episode, dof_pos=cart, dof_vel=torch.zeros(N, 2))

    task.after_reset = after_reset
    if how == "reset":
        obs, expect = task.reset(), torch.ones(N, dtype=torch.bool)
    else:
        task.reset_buf[:] = chosen.long()
        (obs, _), expect = task.reset_done(), chosen
    ((mask, progress),) = seen
    assert torch.equal(mask, expect)
    assert torch.all(progress[expect] == 0)  # after the episode restarted
    np.testing.assert_array_equal(obs["obs"][expect, 0].numpy(), np.float32(0.07))
