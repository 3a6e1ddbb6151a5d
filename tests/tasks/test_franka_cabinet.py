"""FrankaCabinet (issue 32): IsaacGymEnvs' reward terms against numpy formulas written here from IGE's published
task (reference: IsaacGymEnvs tasks/franka_cabinet.py, compute_franka_reward), the observation against MuJoCo C's
kinematics of the same state, the delta-target actions against their formula, the drawer's end condition at
0.39 m, the success rate in test mode, and the one-line errors for bad input."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest
import torch

from isaacgymenvs_mw import make
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, OUTCOME
from isaacgymenvs_mw.tasks import franka_cabinet as fc
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError

RNG = np.random.default_rng(7)


@pytest.fixture(scope="module")
def env():
    return make("FrankaCabinet", num_envs=2, sim_device="cpu", rl_device="cpu", seed=0)


def t(x: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x, dtype=np.float32))


# ------------------------------------------------------------------------------------- reward terms vs numpy
def test_handle_distance_reward_equals_the_formula():
    d = np.concatenate([RNG.uniform(0.0, 1.0, 50), [0.0, 0.02, 0.0201]])
    expected = np.where(d <= 0.02, 2.0, 1.0) * (1.0 / (1.0 + d * d)) ** 2
    np.testing.assert_allclose(fc.handle_distance_reward(t(d)).numpy(), expected, rtol=1e-6)


def test_alignment_reward_equals_the_formula():
    vecs = [RNG.normal(size=(64, 3)) for _ in range(4)]
    fwd, up, inward, dup = [v / np.linalg.norm(v, axis=1, keepdims=True) for v in vecs]
    c1, c2 = np.einsum("ij,ij->i", fwd, inward), np.einsum("ij,ij->i", up, dup)
    expected = 0.5 * (np.sign(c1) * c1 ** 2 + np.sign(c2) * c2 ** 2)
    got = fc.alignment_reward(t(fwd), t(up), t(inward), t(dup)).numpy()
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-7)
    # aligned: 1; opposed: -1
    e = np.eye(3)
    assert fc.alignment_reward(t(e[[0]]), t(e[[2]]), t(e[[0]]), t(e[[2]])).item() == pytest.approx(1.0)
    assert fc.alignment_reward(t(e[[0]]), t(e[[2]]), t(-e[[0]]), t(-e[[2]])).item() == pytest.approx(-1.0)


def test_around_handle_finger_distance_open_and_bonus_equal_the_formulas():
    zh = RNG.uniform(0.6, 0.8, 200)
    zl = zh + RNG.uniform(-0.05, 0.05, 200)
    zr = zh + RNG.uniform(-0.05, 0.05, 200)
    qd = RNG.uniform(0.0, 0.4, 200)
    around = np.where((zl > zh) & (zr < zh), 0.5, 0.0)
    finger = np.where(around > 0, (0.04 - np.abs(zl - zh)) + (0.04 - np.abs(zr - zh)), 0.0)
    opened = qd * around + qd
    bonus = 0.5 * (qd > 0.01) + around * (qd > 0.2) + 2.0 * around * (qd > 0.39)
    np.testing.assert_array_equal(fc.around_handle(t(zl), t(zr), t(zh)).numpy(), around)
    np.testing.assert_allclose(fc.finger_distance_reward(t(zl), t(zr), t(zh)).numpy(), finger, atol=1e-6)
    np.testing.assert_allclose(fc.open_reward(t(qd), t(around)).numpy(), opened, rtol=1e-6)
    np.testing.assert_allclose(fc.open_bonus(t(qd), t(around)).numpy(), bonus, atol=1e-6)
    assert around.min() == 0.0 and around.max() == 0.5  # both cases were constructed


def test_a_finger_4cm_behind_the_handle_along_the_opening_axis_is_past_it():
    axis = np.array([-1.0, 0.0, 0.0])  # the drawer opens toward -x (toward the robot at the origin)
    handle = np.array([[0.64, 0.0, 0.73]] * 4)
    ahead = handle + [[-0.05, 0, 0.01]] * 4  # on the robot's side
    left = ahead.copy()
    right = ahead.copy()
    left[1] = handle[1] + [0.041, 0, 0]  # 4.1 cm behind (into the cabinet)
    right[2] = handle[2] + [0.039, 0, 0]  # 3.9 cm: not yet
    got = fc.fingers_past_handle(t(left), t(right), t(handle), t(axis)).numpy()
    np.testing.assert_array_equal(got, [False, True, False, False])


# ------------------------------------------------------------------------------------- the task in the framework
def test_observation_is_23_values_and_matches_mujoco_c(env):
    env.reset()
    for _ in range(5):
        obs, *_ = env.step(torch.rand(2, 8) * 2 - 1)
    assert obs["obs"].shape == (2, 23) and env.observations.obs_layout.names == ["dof_pos", "dof_vel", "to_handle", "drawer_pos",
                                                                    "drawer_vel"]
    # Body and site poses are those the last physics substep started from (MuJoCo computes them before it
    # integrates); recompute them from the current state so that both sides see one state.
    env.sim.refresh_kinematics()
    env.compute_observations()
    obs = {"obs": env.obs_buf.clone()}
    # MuJoCo C on world 0's state
    m = env.sim.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = env.sim.qpos[0].numpy()
    d.qvel[:] = env.sim.qvel[0].numpy()
    mujoco.mj_forward(m, d)
    joints = [m.joint(n) for n in env.sim.dof_names]
    lo = np.array([j.range[0] for j in joints])
    hi = np.array([j.range[1] for j in joints])
    q = np.array([d.qpos[j.qposadr[0]] for j in joints])
    qd = np.array([d.qvel[j.dofadr[0]] for j in joints])
    drawer = m.joint("cabinet/drawer_top_joint")
    expected = np.concatenate([2 * (q - lo) / (hi - lo) - 1, 0.1 * qd,
                               d.site("cabinet/drawer_handle").xpos - d.site("grasp").xpos,
                               [d.qpos[drawer.qposadr[0]]], [d.qvel[drawer.dofadr[0]]]])
    np.testing.assert_allclose(obs["obs"][0].numpy(), np.clip(expected, -5, 5), atol=2e-5)


def test_actions_move_the_servo_targets_by_action_scale_times_dt(env):
    env.reset()
    start = env.arm.targets.clone()
    a = torch.tensor([[0.5, -1.0, 0.2, 0.0, 1.0, -0.3, 0.7, -1.0]] * 2)
    env.step(a)
    step = 7.5 / 60.0 * np.array([1, 1, 1, 1, 1, 1, 1, 0.1])  # rad (arm), m (gripper)
    expected = np.clip(start.numpy() + a.numpy() * step, env.arm.target_lower.numpy(), env.arm.target_upper.numpy())
    np.testing.assert_allclose(env.arm.targets.numpy(), expected, atol=1e-5)
    np.testing.assert_allclose(env.sim.ctrl[:, :8].numpy(), expected, atol=1e-5)


def test_the_episode_ends_with_success_once_the_drawer_is_past_039m(env):
    env.reset()
    drawer = env.cabinet.dof_pos.clone()
    drawer[:, 0] = torch.tensor([0.395, 0.385])
    env.sim.write_state(torch.ones(2, dtype=torch.bool), dof_pos=drawer, dof_vel=torch.zeros_like(drawer),
                        asset="cabinet")
    _, _, done, extras = env.step(torch.zeros(2, 8))
    assert done.tolist() == [1, 0]
    assert env.metrics.recorded(OUTCOME)["success"].tolist() == [1.0, 0.0]
    assert env.metrics.recorded(EPISODE_SUM)["success"].item() == 1.0
    # the learner bootstraps a success like a time-out (VecTask.check_success); the statistics keep them apart
    assert extras["successes"].tolist() == [True, False] and extras["time_outs"].tolist() == [1, 0]
    assert env.cabinet.dof_pos[0, 0].item() == 0.0  # reset: closed again
    assert env.cabinet.dof_pos[1, 0].item() > 0.3  # not reset (the arm may nudge the drawer: no exact value)


def test_reset_draws_joints_around_the_start_pose_within_their_ranges(env):
    env.reset()
    q = env.sim.dof_pos.numpy()
    start = np.array([1.157, -1.066, -0.155, -2.239, -1.841, 1.003, 0.469, 0.035, 0.035])
    assert np.all(np.abs(q[:, :7] - start[:7]) <= 0.125 + 1e-6)
    assert np.all((q[:, 7:] >= 0.0) & (q[:, 7:] <= 0.04 + 1e-6))
    np.testing.assert_array_equal(q[:, 7], q[:, 8])  # the coupled fingers open alike
    np.testing.assert_allclose(env.arm.targets.numpy(), q[:, :8], atol=1e-6)


def test_training_one_iteration_then_test_mode_reports_a_success_rate(tmp_path, run_args):
    cfg = compose_config(["task=FrankaCabinet", "num_envs=4", "max_iterations=1", "task.env.episodeLength_s=0.1",
                          *run_args])
    summary = run(cfg)
    assert summary["iterations"] == 1 and summary["success"] == 0.0  # episodes of 6 steps ended, none opened it
    run_dir = [p for p in (tmp_path / "runs" / "FrankaCabinet").iterdir() if p.is_dir()][0]
    eval_cfg = compose_config(["task=FrankaCabinet", "num_envs=4", "test=True", f"checkpoint={run_dir / 'model_1.pt'}",
                               "task.env.episodeLength_s=0.2", *run_args])
    result = run(eval_cfg)
    written = json.loads((run_dir / "eval.json").read_text())
    assert written["success"] == result["success"] == 0.0  # an untrained arm does not open the drawer in 12 steps
    assert written["episodes"] == 4


# ------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("override, message", [
    ("task.env.drawer.joint=drawer_bottom_joint",
     r"^task\.env\.drawer\.joint='drawer_bottom_joint': the asset 'cabinet' has no such joint; its joints: "
     r"\['drawer_top_joint'\]$"),
    ("task.env.startDofPos=[1.157,-1.066,-0.155,-2.239,-1.841,1.003,0.469,0.05,0.05]",
     r"^task\.env\.startDofPos\[7\]=0\.05 is outside the range of joint finger_joint1 \[0, 0\.04\]"),
    ("task.env.drawer.asset=drawer",
     r"^task\.env\.drawer\.asset='drawer' is not an asset of the scene: give one of \['cabinet'\]"),
])
def test_bad_drawer_and_start_pose_are_one_line_errors_naming_the_key(override, message):
    with pytest.raises(ConfigError, match=message) as err:
        make("FrankaCabinet", num_envs=1, sim_device="cpu", rl_device="cpu", overrides=[override])
    assert "\n" not in str(err.value)


def test_the_success_term_pays_its_scale_once_on_the_step_the_drawer_passes_the_open_distance():
    env = make("FrankaCabinet", num_envs=2, sim_device="cpu", rl_device="cpu", seed=0,
               overrides=("task.env.successRewardScale=100",))
    env.reset()
    drawer = env.cabinet.dof_pos.clone()
    drawer[:, 0] = torch.tensor([0.395, 0.385])  # past openDistance (0.39 m) in env 0 only
    env.sim.write_state(torch.ones(2, dtype=torch.bool), dof_pos=drawer, dof_vel=torch.zeros_like(drawer),
                        asset="cabinet")
    _, _, done, extras = env.step(torch.zeros(2, 8))
    assert done.tolist() == [1, 0]
    # env 0's ended episode earned the term's scale x 1 once; env 1's running episode has earned nothing from it
    assert extras["episode_terms"]["success"].item() == pytest.approx(100.0)
    assert env.rewards.episode_sums[1, env.rewards.names.index("success")].item() == 0.0
    # shipped: IGE's reward, without the term
    assert "success" not in make("FrankaCabinet", num_envs=1, sim_device="cpu", rl_device="cpu").rewards.names
