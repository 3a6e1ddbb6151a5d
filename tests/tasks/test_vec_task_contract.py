"""VecTask.step()/reset() contract on Cartpole: types, shapes, clipping, reset_buf, time-outs, failures,
controlFrequencyInv (checked against MuJoCo C)."""

from __future__ import annotations


import numpy as np
import pytest
import torch

from cartpole_reference import cartpole_reward_reference, joint_addresses, mj_step_batch

N = 8


def state_obs(task) -> np.ndarray:
    """[cart pos, cart vel, pole angle, pole vel] read from the simulator, ordered by MuJoCo joint addresses."""
    cq, pq, cv, pv = joint_addresses(task.sim.mj_model)
    q, v = task.sim.qpos.numpy(), task.sim.qvel.numpy()
    return np.stack([q[:, cq], v[:, cv], q[:, pq], v[:, pv]], axis=1)


def write_dofs(task, pos, vel, mask=None):
    """Write (num_envs, 2) arrays given in (cart, pole) order through the simulator's masked write."""
    cq, pq, cv, pv = joint_addresses(task.sim.mj_model)
    n = task.num_envs
    qpos = task.sim.dof_pos.clone()
    qvel = task.sim.dof_vel.clone()
    qpos[:, cq], qpos[:, pq] = torch.as_tensor(pos[:, 0]), torch.as_tensor(pos[:, 1])
    qvel[:, cv], qvel[:, pv] = torch.as_tensor(vel[:, 0]), torch.as_tensor(vel[:, 1])
    mask = torch.ones(n, dtype=torch.bool) if mask is None else mask
    task.sim.write_state(mask, dof_pos=qpos, dof_vel=qvel)


def test_reset_buf_starts_at_ones(make_cartpole):
    task = make_cartpole(N)
    assert task.reset_buf.dtype == torch.long
    assert torch.equal(task.reset_buf, torch.ones(N, dtype=torch.long))
    assert torch.equal(task.progress_buf, torch.zeros(N, dtype=torch.long))


def test_step_return_contract(make_cartpole):
    task = make_cartpole(N)
    assert task.num_envs == N and task.num_obs == 4 and task.num_acts == 1
    assert task.observation_space.shape == (4,) and task.action_space.shape == (1,)

    obs0 = task.reset()
    assert isinstance(obs0, dict) and set(obs0) == {"obs"}  # numStates = 0: no "states"
    assert obs0["obs"].shape == (N, 4) and obs0["obs"].dtype == torch.float32
    np.testing.assert_array_equal(obs0["obs"].numpy(), state_obs(task))

    actions = task.zero_actions()
    assert actions.shape == (N, 1) and actions.dtype == torch.float32
    out = task.step(actions)
    assert isinstance(out, tuple) and len(out) == 4
    obs_dict, rew, reset, extras = out
    rl = torch.device(task.rl_device)
    assert isinstance(obs_dict, dict) and "obs" in obs_dict and "states" not in obs_dict
    obs = obs_dict["obs"]
    assert isinstance(obs, torch.Tensor) and obs.shape == (N, 4) and obs.dtype == torch.float32 and obs.device == rl
    assert isinstance(rew, torch.Tensor) and rew.shape == (N,) and rew.dtype == torch.float32 and rew.device == rl
    assert isinstance(reset, torch.Tensor) and reset.shape == (N,) and reset.dtype == torch.long and reset.device == rl
    assert isinstance(extras, dict) and "time_outs" in extras
    to = extras["time_outs"]
    assert isinstance(to, torch.Tensor) and to.shape == (N,) and to.device == rl
    assert not to.is_floating_point()
    assert set(torch.unique(to).tolist()) <= {0, 1} and set(torch.unique(reset).tolist()) <= {0, 1}
    # Observations are the simulator state (no reset happens in the first step from the reset distribution).
    assert not reset.any()
    np.testing.assert_array_equal(obs.numpy(), state_obs(task))
    assert torch.equal(task.progress_buf, torch.ones(N, dtype=torch.long))


def test_actions_are_clipped_at_clip_actions(make_cartpole):
    task = make_cartpole(N)
    task.reset()
    clip, effort = task.clip_actions, task.max_push_effort
    assert clip == 1.0 and effort == 400.0  # the YAML's values
    a = np.array([-3.0, -1.5, -1.0, -0.25, 0.0, 0.6, 1.0, 7.0], dtype=np.float32)
    _, _, reset, _ = task.step(torch.from_numpy(a).view(N, 1))
    assert not reset.any()
    expected = np.clip(a, -clip, clip) * np.float32(effort)
    np.testing.assert_allclose(task.sim.ctrl.numpy()[:, 0], expected, rtol=1e-7, atol=0)


def test_clip_actions_override(make_cartpole):
    task = make_cartpole(4, overrides=["task.env.clipActions=0.5", "task.env.maxEffort=100"])
    task.reset()
    a = np.array([-2.0, -0.3, 0.4, 0.9], dtype=np.float32)
    task.step(torch.from_numpy(a).view(4, 1))
    np.testing.assert_allclose(task.sim.ctrl.numpy()[:, 0], np.clip(a, -0.5, 0.5) * 100.0, rtol=1e-7)


def test_observations_are_clipped_state_is_not(make_cartpole):
    task = make_cartpole(N)
    task.reset()
    clip = task.clip_obs
    assert clip == 5.0
    pos = np.zeros((N, 2), np.float32)
    vel = np.zeros((N, 2), np.float32)
    vel[0, 0], vel[1, 0] = 8.0, -9.0  # cart velocity beyond the clip
    vel[2, 1], vel[3, 1] = 7.0, -6.0  # pole velocity beyond the clip
    vel[4] = [1.0, -2.0]  # inside
    write_dofs(task, pos, vel)
    obs_dict, rew, reset, _ = task.step(task.zero_actions())
    assert not reset.any()
    state = state_obs(task)
    assert abs(state[0, 1]) > clip and abs(state[1, 1]) > clip and abs(state[2, 3]) > clip and abs(state[3, 3]) > clip
    obs = obs_dict["obs"].numpy()
    np.testing.assert_array_equal(obs, np.clip(state, -clip, clip))
    assert obs[0, 1] == clip and obs[1, 1] == -clip and obs[2, 3] == clip and obs[3, 3] == -clip
    # The reward sees the true (unclipped) velocities.
    ref, _, _ = cartpole_reward_reference(state[:, 0], state[:, 1], state[:, 2], state[:, 3], task.reset_dist,
                                          np.ones(N), task.max_episode_length)
    np.testing.assert_allclose(rew.numpy(), ref, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("max_len", [5, 3])
def test_time_outs_fire_at_the_step_limit(make_cartpole, max_len):
    task = make_cartpole(4, overrides=[f"task.env.episodeLength_s={max_len * 0.0166}"])  # max_len policy steps
    assert task.max_episode_length == max_len
    task.reset()
    progress = 0  # the IsaacGymEnvs rule, counted here independently
    fired = []
    for k in range(1, 4 * max_len):
        _, rew, reset, extras = task.step(task.zero_actions())
        progress += 1
        expect = progress >= max_len - 1
        assert torch.equal(reset, torch.full((4,), int(expect))), f"step {k}"
        assert torch.equal(extras["time_outs"], torch.full((4,), int(expect))), f"step {k}"
        assert (rew > 0).all()  # no failure anywhere: all resets are time-outs
        if expect:
            fired.append(k)
            progress = 0
        assert torch.equal(task.progress_buf, torch.full((4,), progress))
    assert fired == list(range(max_len - 1, 4 * max_len, max_len - 1))


def test_failures_reset_without_time_out(make_cartpole):
    task = make_cartpole(N)
    task.reset()
    pos = np.zeros((N, 2), np.float32)
    vel = np.zeros((N, 2), np.float32)
    pos[0, 1], pos[1, 1] = 2.0, -2.0  # pole beyond ±π/2
    pos[2, 0], pos[3, 0] = 3.5, -3.5  # cart beyond ±resetDist (rail limit is ±4)
    pos[4, 0] = 2.8  # close to, not beyond
    pos[5, 1] = 1.3
    write_dofs(task, pos, vel)
    task.progress_buf[:] = torch.tensor([2, 3, 1, 2, 2, 3, 1, 0])
    before = task.progress_buf.clone()

    obs_dict, rew, reset, extras = task.step(task.zero_actions())
    failed = torch.tensor([1, 1, 1, 1, 0, 0, 0, 0])
    assert torch.equal(reset, failed)
    assert torch.equal(extras["time_outs"], torch.zeros(N, dtype=torch.long))
    assert torch.all(rew[:4] == -2.0)
    assert torch.all(rew[4:] > -2.0)
    assert torch.equal(task.progress_buf, torch.where(failed.bool(), 0, before + 1))
    # Failed envs were re-initialised within the reset noise and observe their new state.
    state = state_obs(task)
    assert np.all(np.abs(state[:4, [0, 2]]) <= task.reset_position_noise)
    assert np.all(np.abs(state[:4, [1, 3]]) <= task.reset_velocity_noise)
    np.testing.assert_array_equal(obs_dict["obs"].numpy(), np.clip(state, -5, 5))


@pytest.mark.parametrize("cfi", [1, 3])
def test_control_frequency_inv_physics_steps_match_mujoco_c(make_cartpole, cfi):
    task = make_cartpole(N, overrides=[f"task.env.controlFrequencyInv={cfi}"])
    model = task.sim.mj_model
    assert task.control_dt == pytest.approx(cfi * model.opt.timestep)
    task.reset()
    rng = np.random.default_rng(cfi)
    pos = (rng.uniform(-1, 1, (N, 2)) * [1.0, 0.2]).astype(np.float32)
    vel = (rng.uniform(-1, 1, (N, 2)) * [1.0, 0.5]).astype(np.float32)
    write_dofs(task, pos, vel)
    for k in range(2):
        q0, v0 = task.sim.qpos.numpy().copy(), task.sim.qvel.numpy().copy()
        a = rng.uniform(-0.2, 0.2, (N, 1)).astype(np.float32)
        steps_before = task.sim.physics_steps
        _, _, reset, _ = task.step(torch.from_numpy(a))
        assert not reset.any()
        assert task.sim.physics_steps - steps_before == cfi
        ctrl = np.clip(a, -1, 1) * np.float32(task.max_push_effort)
        q_ref, v_ref = mj_step_batch(model, q0, v0, ctrl, nsteps=cfi)
        np.testing.assert_allclose(task.sim.qpos.numpy(), q_ref, atol=1e-5, rtol=0, err_msg=f"step {k}")
        np.testing.assert_allclose(task.sim.qvel.numpy(), v_ref, atol=1e-4, rtol=0, err_msg=f"step {k}")
        # ...and not the state after a different number of physics steps.
        q_wrong, _ = mj_step_batch(model, q0, v0, ctrl, nsteps=cfi + 1)
        assert np.abs(task.sim.qpos.numpy() - q_wrong).max() > 1e-3


# ------------------------------------------------------------------------------------------- episode length
@pytest.mark.parametrize("task_name, steps", [("Cartpole", 500), ("Ant", 1000)])
def test_shipped_episode_lengths_in_seconds_keep_their_step_counts(task_name, steps):
    # The counts the YAMLs gave in policy steps before env.episodeLength_s (maxEpisodeLength, episodeLength).
    import isaacgymenvs_mw
    task = isaacgymenvs_mw.make(task_name, num_envs=1, sim_device="cpu", rl_device="cpu")
    assert task.max_episode_length == steps
    assert task.max_episode_length_s == pytest.approx(steps * task.control_dt)


@pytest.mark.parametrize("task_name, old, seconds", [("Cartpole", "maxEpisodeLength=500", "8.3"),
                                                     ("Ant", "episodeLength=1000", "16.66")])
def test_an_old_episode_length_key_is_refused_naming_the_new_one(task_name, old, seconds):
    import isaacgymenvs_mw
    key, steps = old.split("=")
    with pytest.raises(ValueError, match=rf"^task\.env\.{key}={steps} is no longer read: give the episode length in "
                                         rf"seconds, task\.env\.episodeLength_s: {seconds} \({steps} policy steps"):
        isaacgymenvs_mw.make(task_name, num_envs=1, sim_device="cpu", rl_device="cpu", overrides=[f"+task.env.{old}"])


def test_episode_length_rounds_up_to_whole_policy_steps(make_cartpole):
    # 0.1 s of 0.0166 s steps is 6.02 steps: the episode is not cut short, so the cap is 7.
    assert make_cartpole(2, overrides=["task.env.episodeLength_s=0.1"]).max_episode_length == 7
