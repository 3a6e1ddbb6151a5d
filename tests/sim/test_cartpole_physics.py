"""Cartpole trajectories of the MuJoCo Warp batch against MuJoCo C (mujoco.mj_step on task.sim.mj_model)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from cartpole_reference import joint_addresses, mj_data_from

N = 8
T = 50


def stabilised_action_sequence(model, q0, v0, rng, effort):
    """A fixed (T, N, 1) action sequence: a PD pole balancer plus noise, computed open loop in MuJoCo C.

    Replayed open loop in both simulators it keeps every pole well inside ±π/2 for T steps, so no episode
    resets during the comparison; the sequence depends on nothing computed by the package.
    """
    cq, pq, cv, pv = joint_addresses(model)
    actions = np.zeros((T, len(q0), 1), np.float32)
    for i in range(len(q0)):
        d = mj_data_from(model, q0[i], v0[i])
        for t in range(T):
            a = -(0.6 * d.qpos[pq] + 0.12 * d.qvel[pv]) + rng.uniform(-0.05, 0.05)
            actions[t, i, 0] = np.float32(a)
            d.ctrl[0] = float(actions[t, i, 0]) * effort
            mujoco.mj_step(model, d)
    return actions


@pytest.mark.parametrize("seed", [0, 1])
def test_trajectories_match_mujoco_c(make_cartpole, seed):
    task = make_cartpole(N)
    model = task.sim.mj_model
    effort = task.max_push_effort
    assert model.nq == 2 and model.nv == 2 and model.nu == 1
    task.reset()

    rng = np.random.default_rng(seed)
    q0 = (rng.uniform(-1, 1, (N, 2)) * [0.5, 0.1]).astype(np.float32)  # model qpos order
    v0 = (rng.uniform(-1, 1, (N, 2)) * [0.5, 0.3]).astype(np.float32)
    actions = stabilised_action_sequence(model, q0, v0, rng, effort)
    assert 0.02 < np.abs(actions).max() < 1.0  # moderate forces, never clipped

    mask = torch.ones(N, dtype=torch.bool)
    task.sim.write_state(mask, dof_pos=torch.from_numpy(q0), dof_vel=torch.from_numpy(v0))
    task.progress_buf.zero_()
    refs = [mj_data_from(model, q0[i], v0[i]) for i in range(N)]

    cq, pq, cv, pv = joint_addresses(model)
    q_err = v_err = 0.0
    for t in range(T):
        obs_dict, _, reset, _ = task.step(torch.from_numpy(actions[t]))
        assert not reset.any(), f"an episode ended at step {t}: the comparison assumes none does"
        for i, d in enumerate(refs):
            d.ctrl[0] = float(actions[t, i, 0]) * effort
            mujoco.mj_step(model, d)
        q_ref = np.stack([d.qpos for d in refs])
        v_ref = np.stack([d.qvel for d in refs])
        q, v = task.sim.qpos.numpy(), task.sim.qvel.numpy()
        q_err, v_err = max(q_err, np.abs(q - q_ref).max()), max(v_err, np.abs(v - v_ref).max())
        # Observations are the same state in IsaacGymEnvs' order.
        expected_obs = np.stack([q_ref[:, cq], v_ref[:, cv], q_ref[:, pq], v_ref[:, pv]], axis=1)
        np.testing.assert_allclose(obs_dict["obs"].numpy(), expected_obs, atol=1e-3, rtol=0)
    # float32 Warp vs float64 C: measured ~1e-6 after 50 steps; the bounds leave two orders of magnitude.
    assert q_err < 1e-4, q_err
    assert v_err < 5e-4, v_err
    # The envs really went different ways (a batch that stepped one world for all would fail above).
    assert np.ptp(q_ref[:, pq]) > 1e-3 and np.ptp(q_ref[:, cq]) > 1e-2


def test_uncontrolled_pole_falls_like_mujoco_c(make_cartpole):
    """Without control the pole falls over; the Warp state tracks MuJoCo C until the failure reset."""
    task = make_cartpole(2)
    model = task.sim.mj_model
    task.reset()
    q0 = np.array([[0.0, 0.05], [0.2, -0.05]], np.float32)
    v0 = np.zeros((2, 2), np.float32)
    task.sim.write_state(torch.ones(2, dtype=torch.bool), dof_pos=torch.from_numpy(q0), dof_vel=torch.from_numpy(v0))
    task.progress_buf.zero_()
    refs = [mj_data_from(model, q0[i], v0[i]) for i in range(2)]
    _, pq, _, _ = joint_addresses(model)
    for t in range(200):
        _, rew, reset, _ = task.step(task.zero_actions())
        for d in refs:
            mujoco.mj_step(model, d)
        ref_angle = np.array([d.qpos[pq] for d in refs])
        if np.any(np.abs(ref_angle) > np.pi / 2):
            # MuJoCo C says the pole is past horizontal: the task must fail both envs in this very step.
            assert torch.equal(reset, torch.ones(2, dtype=torch.long)), t
            assert torch.all(rew == -2.0)
            break
        assert not reset.any(), t
        np.testing.assert_allclose(task.sim.qpos.numpy(), np.stack([d.qpos for d in refs]), atol=1e-3)
    else:
        pytest.fail("the pole never fell in MuJoCo C")
    assert np.sign(ref_angle[0]) == 1 and np.sign(ref_angle[1]) == -1
