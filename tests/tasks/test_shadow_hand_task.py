"""ShadowHand (issue 47): the wiring of the in-hand reward (shared with AllegroHand, whose tests check its logic)
against the plain-Python IsaacGymEnvs formula, the four observation types' sizes and entries against their
definitions (fingertips against MuJoCo C's kinematics, the force-torque columns against the sensors), the 20
actions over the servo ranges with the distal joints coupled, reset draws that respect the coupling, MuJoCo Warp
against MuJoCo C over 40 policy steps, IGE's random pushes on the cube, the OpenAI_FF variant, the one-line error for
an unknown observation type, the randomisation block, and one training iteration plus test mode on the CPU."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest
import torch

from in_hand_reference import assert_reward_is_the_reference
from isaacgymenvs_mw import make
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError

CPU = dict(sim_device="cpu", rl_device="cpu", headless=True)
FINGERTIPS = ("ffdistal", "mfdistal", "rfdistal", "lfdistal", "thdistal")
COUPLED = (("FFJ1", "FFJ2"), ("MFJ1", "MFJ2"), ("RFJ1", "RFJ2"), ("LFJ1", "LFJ2"))


@pytest.fixture(scope="module")
def env():
    return make("ShadowHand", num_envs=3, seed=0, **CPU, overrides=["task.env.fallPenalty=-7.0"])


def columns(env, layout, name: str) -> list[int]:
    return getattr(env.observations, layout).columns([name], "test")


def dof(env, joint: str) -> int:
    return env.sim.dof_names.index(joint)


@pytest.mark.parametrize("kind, size", [("openai", 42), ("full_no_vel", 77), ("full", 157), ("full_state", 211)])
def test_observation_types_have_ige_sizes(kind, size):
    task = make("ShadowHand", num_envs=1, seed=0, **CPU, overrides=[f"task.env.observationType={kind}"])
    assert task.num_obs == size and task.num_states == 0 and task.num_actions == 20
    assert task.reset()["obs"].shape == (1, size)


def test_full_state_entries_equal_their_definitions(env):
    """After a few steps from a reset: the joints over their ranges, joint forces, fingertip poses (MuJoCo C's
    kinematics of the same state) and force-torque sensors, the cube and goal, the actions."""
    env.reset()
    for _ in range(3):
        env.step(torch.rand(3, 20) * 2 - 1)
    # the fingertip frames and sensors are those of the forward pass of the last physics step's start state
    env.sim.forward()
    env.compute_observations()
    obs, m = env.obs_buf, env.sim.mj_model
    lo, hi = env.dof_lower, env.dof_upper
    q = env.sim.dof_pos
    np.testing.assert_allclose(obs[:, columns(env, "obs_layout", "dof_pos")].numpy(),
                               ((2 * q - hi - lo) / (hi - lo)).numpy(), atol=1e-6)
    np.testing.assert_allclose(obs[:, columns(env, "obs_layout", "dof_vel")].numpy(),
                               (0.2 * env.sim.dof_vel).numpy(), atol=1e-6)
    d = mujoco.MjData(m)
    for world in range(3):
        d.qpos[:], d.qvel[:], d.ctrl[:] = (env.sim.qpos[world].numpy(), env.sim.qvel[world].numpy(),
                                           env.sim.ctrl[world].numpy())
        mujoco.mj_forward(m, d)
        state = obs[world, columns(env, "obs_layout", "fingertip_state")].numpy().reshape(5, 13)
        ft = obs[world, columns(env, "obs_layout", "fingertip_force_torque")].numpy().reshape(5, 6)
        force = obs[world, columns(env, "obs_layout", "dof_force")].numpy()
        np.testing.assert_allclose(force, 10 * d.qfrc_actuator[:24], atol=1e-4)
        for k, body in enumerate(FINGERTIPS):
            np.testing.assert_allclose(state[k, :3], d.body(body).xpos, atol=1e-5)
            np.testing.assert_allclose(state[k, 3:7], d.body(body).xquat, atol=1e-5)
            vel = np.zeros(6)  # (angular, linear) of the body frame's origin, world axes
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_XBODY, m.body(body).id, vel, 0)
            np.testing.assert_allclose(state[k, 7:10], vel[3:], atol=1e-4)
            np.testing.assert_allclose(state[k, 10:13], vel[:3], atol=1e-3)
            sensed = np.concatenate([d.sensor(f"{body}_force").data, d.sensor(f"{body}_torque").data])
            np.testing.assert_allclose(ft[k], 10 * sensed, atol=1e-3)
    cube = env.cube
    np.testing.assert_allclose(obs[:, columns(env, "obs_layout", "object_pos")].numpy(), cube.root_pos.numpy(),
                               atol=1e-6)
    np.testing.assert_allclose(obs[:, columns(env, "obs_layout", "goal_quat")].numpy(), env.goal_quat.numpy(),
                               atol=1e-6)
    np.testing.assert_allclose(obs[:, columns(env, "obs_layout", "actions")].numpy(), env.actions.numpy(),
                               atol=1e-6)


def test_openai_observation_is_fingertip_positions_cube_position_relative_rotation_actions():
    task = make("ShadowHand", num_envs=2, seed=1, **CPU, overrides=["task.env.observationType=openai"])
    task.reset()
    task.step(torch.rand(2, 20) * 2 - 1)
    task.compute_observations()
    obs = task.obs_buf
    names = [t.name for t in task.observations.obs_layout.terms]
    assert names == ["fingertip_pos", "object_pos", "object_to_goal_quat", "actions"]
    tips = torch.stack([task.sim.xpos[:, task.sim.body_id(b)] for b in FINGERTIPS], dim=1).reshape(2, 15)
    np.testing.assert_allclose(obs[:, :15].numpy(), tips.numpy(), atol=1e-6)
    np.testing.assert_allclose(obs[:, 15:18].numpy(), task.cube.root_pos.numpy(), atol=1e-6)
    rel = np.zeros((2, 4))
    for i in range(2):
        goal = task.goal_quat[i].double().numpy() * [1, -1, -1, -1]
        mujoco.mju_mulQuat(rel[i], task.cube.root_quat[i].double().numpy(), goal)
    np.testing.assert_allclose(obs[:, 18:22].numpy(), rel, atol=1e-6)
    np.testing.assert_allclose(obs[:, 22:42].numpy(), task.actions.numpy(), atol=1e-6)


def test_reward_is_the_ige_formula(env):
    env.reset()
    rng = np.random.default_rng(4)
    start = env.object_start_pos.numpy()
    pos = start + rng.normal(0.0, 0.1, (3, 3))  # some beyond the fall distance
    quat = rng.normal(size=(3, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    quat[0] = env.goal_quat[0].numpy()  # one success
    assert_reward_is_the_reference(env, pos, quat, rng.uniform(-1, 1, (3, 20)), fall_penalty=-7.0)
    assert env.terms["reached"][0] and set(env.rewards.names) == {"dist", "rot", "action_penalty", "reach_goal",
                                                                  "fall"}
    # IGE's goal: the cube's start 4 cm lower; the cube starts at IGE's hand root + (0, -0.39, 0.10)
    np.testing.assert_allclose(start, [0.0, -0.39, 0.6], atol=1e-6)
    np.testing.assert_allclose(env.goal_pos[0].numpy(), [0.0, -0.39, 0.56], atol=1e-6)


def test_actions_span_the_servo_ranges_and_j0_commands_ige_j2_target(env):
    env.reset()
    m = env.sim.mj_model
    env.pre_physics_step(torch.stack([-torch.ones(20), torch.ones(20), torch.zeros(20)]))
    ctrl = env.sim.ctrl[:, :20].numpy()
    np.testing.assert_allclose(ctrl[0], m.actuator_ctrlrange[:20, 0], atol=1e-6)
    np.testing.assert_allclose(ctrl[1], m.actuator_ctrlrange[:20, 1], atol=1e-6)
    j2 = m.joint("FFJ2").range
    a = env.sim.actuator_names.index("A_FFJ0")
    # IGE scales the action over J2's range (J1 coupled): action 0 -> mid-range of J2, for each of J1 and J2
    assert ctrl[2, a] / 2 == pytest.approx(j2.mean(), abs=1e-6)

    rel = make("ShadowHand", num_envs=1, seed=0, **CPU, overrides=["task.env.useRelativeControl=True"])
    rel.reset()
    before = rel.prev_targets.clone()
    rel.pre_physics_step(torch.full((1, 20), 0.25))
    step = torch.full((20,), 20.0 / 60.0 * 0.25)  # IGE: dofSpeedScale x its sim dt 1/60 x action, per joint
    step[[rel.sim.actuator_names.index(f"A_{f}J0") for f in ("FF", "MF", "RF", "LF")]] *= 2  # J1 + J2 both move
    expected = torch.clamp(before[0] + step, rel.target_lower, rel.target_upper)
    np.testing.assert_allclose(rel.sim.ctrl[0, :20].numpy(), expected.numpy(), atol=1e-6)


def test_reset_draws_coupled_joints_together_and_targets_the_drawn_pose():
    task = make("ShadowHand", num_envs=64, seed=2, **CPU)
    task.reset()
    q = task.sim.dof_pos
    assert bool(((q >= task.dof_lower - 1e-6) & (q <= task.dof_upper + 1e-6)).all())
    assert bool((q <= 0.2 * task.dof_upper + 1e-6).all()) and float(q.std()) > 0.01
    for follower, leader in COUPLED:
        assert torch.equal(q[:, dof(task, follower)], q[:, dof(task, leader)])
    names = task.sim.actuator_names
    for a, name in enumerate(names):
        joint = name[2:]
        if joint.endswith("J0"):
            f = joint[:2]
            expected = q[:, dof(task, f"{f}J1")] + q[:, dof(task, f"{f}J2")]
        else:
            expected = q[:, dof(task, joint)]
        np.testing.assert_allclose(task.prev_targets[:, a].numpy(), expected.numpy(), atol=1e-6, err_msg=name)
    np.testing.assert_allclose(task.sim.ctrl[:, :20].numpy(), task.prev_targets.numpy())


def test_mujoco_warp_and_mujoco_c_agree_and_the_distal_joints_follow():
    """40 policy steps (2/3 s) of one action sequence in the task and in MuJoCo C from the same reset state, the
    cube put 0.3 m aside (contacts with it would make the two diverge chaotically): the joints and the fingertip
    sensors agree; J1 stays with J2 in every step."""
    task = make("ShadowHand", num_envs=1, seed=3, **CPU,
                overrides=["task.env.assets.object.pos=[0.3,-0.39,0.6]", "task.env.fallDistance=10.0"])
    task.reset()
    m = task.sim.mj_model
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = task.sim.qpos[0].numpy(), task.sim.qvel[0].numpy()
    rng = np.random.default_rng(0)
    actions = np.repeat(rng.uniform(-1, 1, (4, 20)), 10, axis=0)
    for action in actions:
        _, _, done, _ = task.step(torch.tensor(action, dtype=torch.float32).unsqueeze(0))
        assert done.item() == 0
        d.ctrl[:20] = task.sim.ctrl[0, :20].numpy()
        for _ in range(task.control_freq_inv):
            mujoco.mj_step(m, d)
        for follower, leader in COUPLED:
            assert abs(d.joint(follower).qpos[0] - d.joint(leader).qpos[0]) < 0.05
            assert abs(task.sim.dof_pos[0, dof(task, follower)] - task.sim.dof_pos[0, dof(task, leader)]) < 0.05
    np.testing.assert_allclose(task.sim.dof_pos[0].numpy(), d.qpos[:24], atol=2e-3)
    task.sim.forward()
    mujoco.mj_forward(m, d)
    np.testing.assert_allclose(task.sim.sensordata[0].numpy(), d.sensordata, atol=2e-2)


def cube_velocity_gain(task, force_body: np.ndarray) -> np.ndarray:
    """(N, 3) velocity a free cube at rest gains over one policy step from gravity and a constant force given in its
    frame at its centre of mass (it does not turn: no torque)."""
    mass = task.sim.mj_model.body("object/cube").mass[0]
    world = np.zeros_like(force_body)
    for i, (f, q) in enumerate(zip(force_body, task.cube.root_quat.double().numpy())):
        mujoco.mju_rotVecQuat(world[i], f, q)
    return (world / mass + [0.0, 0.0, -9.81]) * task.control_dt


def test_random_pushes_are_ige_draw_and_decay_and_move_the_cube():
    """forceScale 2 with a new push every step (forceProbRange [1, 1]), the cube set aside from the hand, free: a push
    is forceScale x mass x N(0, 1) per axis of the cube's frame and gives the cube its velocity in one step; with
    (almost) no new pushes the last one shrinks by forceDecay^((1/60) / forceDecayInterval) per step."""
    aside = ["task.env.assets.object.pos=[0.3,-0.39,0.6]", "task.env.fallDistance=10.0",
             "task.env.resetPositionNoise=0.0", "task.env.forceScale=2.0"]
    task = make("ShadowHand", num_envs=4, seed=0, **CPU, overrides=[*aside, "task.env.forceProbRange=[1.0,1.0]"])
    task.reset()
    assert torch.equal(task.push_forces, torch.zeros(4, 1, 3)) and torch.equal(task.push_prob, torch.ones(4))
    task.step(torch.zeros(4, 20))
    push = task.push_forces[:, 0].double().numpy()
    mass = task.sim.mj_model.body("object/cube").mass[0]
    assert 0.05 < np.abs(push / (2.0 * mass)).mean() < 3.0 and len(np.unique(push)) == 12  # drawn, per env and axis
    np.testing.assert_allclose(task.cube.root_lin_vel.numpy(), cube_velocity_gain(task, push), atol=2e-4)

    rare = make("ShadowHand", num_envs=2, seed=0, **CPU, overrides=[*aside, "task.env.forceProbRange=[1e-9,1e-9]"])
    rare.reset()
    rare.push_forces[:, 0] = torch.tensor([[0.5, 0.0, 0.0], [0.0, -0.3, 0.2]])
    start = rare.push_forces.clone()
    rare.step(torch.zeros(2, 20))
    decayed = start * 0.99 ** ((1 / 60) / 0.08)
    np.testing.assert_allclose(rare.push_forces.numpy(), decayed.numpy(), rtol=1e-6)
    np.testing.assert_allclose(rare.cube.root_lin_vel.numpy(), cube_velocity_gain(rare, decayed[:, 0].double().numpy()),
                               atol=2e-4)
    bad = r"^task\.env\.forceProbRange=\[0\.0, 0\.1\] is invalid: give \[low, high\] with 0 < low <= high <= 1"
    with pytest.raises(ConfigError, match=bad):
        make("ShadowHand", num_envs=1, **CPU,
             overrides=["task.env.forceScale=1.0", "task.env.forceProbRange=[0.0,0.1]"])


def test_openai_ff_variant_is_ige_setting_with_an_asymmetric_critic():
    task = make("ShadowHandOpenAI_FF", num_envs=2, seed=0, **CPU)
    out = task.reset()
    assert out["obs"].shape == (2, 42) and out["states"].shape == (2, 211)
    assert task.control_freq_inv == 6 and task.max_episode_length == 160  # 20 Hz, IGE's resetTime 8 s
    assert task.env_numbers["successTolerance"] == 0.4 and task.env_numbers["actionsMovingAverage"] == 0.3
    assert task.max_consecutive_successes == 50 and task.force_scale == 1.0
    assert task.rewards.weights[task.rewards.names.index("fall")].item() == -50.0
    force = task.observations.state_layout.columns(["dof_force"], "test")
    task.step(torch.ones(2, 20))
    task.compute_observations()  # unclipped
    np.testing.assert_allclose(task.states_buf[:, force].numpy(), (10.0 * task.sim.qfrc_actuator[:, :24]).numpy(),
                               atol=1e-5)


def test_an_unknown_observation_type_is_a_one_line_error_naming_the_key():
    message = (r"^task\.env\.observationType='openAI' is invalid: choose one of "
               r"\['openai', 'full_no_vel', 'full', 'full_state'\]$")
    with pytest.raises(ConfigError, match=message):
        make("ShadowHand", num_envs=1, **CPU, overrides=["task.env.observationType=openAI"])


def test_the_shipped_randomisation_block_applies_when_turned_on():
    task = make("ShadowHand", num_envs=4, seed=0, **CPU, overrides=["task.task.randomize=True"])
    task.reset()
    mass = task.sim.model_field("body_mass")
    for body in ("object/cube", "wrist", "palm", "lfmetacarpal", "thhub", "ffdistal"):
        nominal = task.sim.mj_model.body(body).mass[0]
        drawn = mass[:, task.sim.body_id(body)]
        assert bool(((drawn >= 0.5 * nominal - 1e-6) & (drawn <= 1.5 * nominal + 1e-6)).all()), body
        assert float(drawn.max() - drawn.min()) > 1e-4, body
    kp = task.sim.model_field("actuator_gainprm")[:, :20, 0]
    nominal_kp = torch.tensor(task.sim.mj_model.actuator_gainprm[:20, 0], dtype=torch.float32)
    ratio = kp / nominal_kp
    assert bool(((ratio >= 0.75 - 1e-6) & (ratio <= 1.5 + 1e-6)).all()) and float(ratio.std()) > 1e-3
    _, rew, _, _ = task.step(torch.zeros(4, 20))
    assert bool(torch.isfinite(rew).all())


@pytest.mark.parametrize("task, seconds", [("ShadowHand", 0.1), ("ShadowHandOpenAI_FF", 0.3)])  # 6 steps each
def test_training_one_iteration_then_test_mode_reports_consecutive_successes(tmp_path, run_args, task, seconds):
    overrides = [f"task={task}", "num_envs=4", f"task.env.episodeLength_s={seconds}", *run_args]
    summary = run(compose_config([*overrides, "max_iterations=1", "train.runner.num_steps_per_env=8"]))
    assert summary["iterations"] == 1
    assert "consecutive_successes" in summary and "successes" in summary
    run_dir = [p for p in (tmp_path / "runs" / task).iterdir() if p.is_dir()][0]
    result = run(compose_config([*overrides, "test=True", f"checkpoint={run_dir / 'model_1.pt'}"]))
    written = json.loads((run_dir / "eval.json").read_text())
    assert written["consecutive_successes"] == result["consecutive_successes"] and written["episodes"] == 4
    assert 0.0 <= written["consecutive_successes"] <= 6.0  # at most one success a step
