"""Trifinger (IsaacGymEnvs' task): the model against the URDF's kinematics, the actions, observations, reward terms,
resets, goals and success against IGE's formulas restated here, and train.py training then evaluating it.

IGE's facts (isaacgymenvs/tasks/trifinger.py, cfg/task/Trifinger.yaml, assets/trifinger/robot_properties_fingers/
urdf/pro/trifingerpro.urdf) are restated below and the expected values computed from them with numpy or plain Python,
independently of the task code.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
import yaml
from conftest import train_py_two_iterations_then_test

from isaacgymenvs_mw import make
from isaacgymenvs_mw.tasks.trifinger import keypoints_kernel, sample_goals
from isaacgymenvs_mw.utils.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
XML = REPO / "assets" / "mjcf" / "trifinger.xml"
TASK_YAML = REPO / "cfg" / "task" / "Trifinger.yaml"
# URDF facts: the holder height, joint origins (parent frame), tip offset, ranges, masses
HOLDER_Z = 0.29
J2, J3, TIP = np.array([0.01685, 0.0505, 0.0]), np.array([0.05015, 0.0, -0.16]), np.array([0.019, 0.0, -0.16])
RANGES = [(-0.33, 1.0), (0.0, 1.57), (-2.7, 0.0)]
MASSES = [0.26689, 0.27163, 0.05569, 0.031]
FINGER_YAW = {"0": 0.0, "120": -2 * math.pi / 3, "240": -4 * math.pi / 3}
POLICY_DT = 0.02


def rot(axis: str, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def tip_by_hand(finger: str, q: tuple[float, float, float]) -> np.ndarray:
    """Forward kinematics from the URDF: joint 1 about y, joints 2 and 3 about x."""
    r0 = rot("z", FINGER_YAW[finger])
    r1 = r0 @ rot("y", q[0])
    r2 = r1 @ rot("x", q[1])
    r3 = r2 @ rot("x", q[2])
    return np.array([0, 0, HOLDER_Z]) + r1 @ J2 + r2 @ J3 + r3 @ TIP


def test_model_kinematics_limits_and_masses_match_the_urdf():
    m = mujoco.MjModel.from_xml_path(str(XML))
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    # zero pose, finger 0, by hand: x 0.01685 + 0.05015 + 0.019, y 0.0505, z 0.29 - 0.16 - 0.16
    np.testing.assert_allclose(d.xpos[m.body("finger_tip_link_0").id], [0.086, 0.0505, -0.03], atol=1e-9)
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = [lo + (hi - lo) * rng.random() for lo, hi in RANGES] * 3
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        for k, finger in enumerate(FINGER_YAW):
            np.testing.assert_allclose(d.xpos[m.body(f"finger_tip_link_{finger}").id],
                                       tip_by_hand(finger, tuple(q[3 * k:3 * k + 3])), atol=1e-9)
    for finger in FINGER_YAW:
        names = [f"finger_base_to_upper_joint_{finger}", f"finger_upper_to_middle_joint_{finger}",
                 f"finger_middle_to_lower_joint_{finger}"]
        for name, (lo, hi), axis in zip(names, RANGES, ([0, 1, 0], [1, 0, 0], [1, 0, 0])):
            j = m.joint(name)
            assert j.range.tolist() == pytest.approx([lo, hi]) and j.axis.tolist() == axis
        bodies = [f"finger_{p}_link_{finger}" for p in ("upper", "middle", "lower", "tip")]
        assert [m.body(b).mass[0] for b in bodies] == pytest.approx(MASSES)
        tip_geom = m.geom(f"finger_tip_{finger}")
        assert tip_geom.type[0] == mujoco.mjtGeom.mjGEOM_SPHERE and tip_geom.size[0] == pytest.approx(0.01)
    assert m.nu == 9 and np.allclose(m.actuator_ctrlrange, [[-0.36, 0.36]] * 9)
    # the table top at z = 0, the wall's inner faces 0.195 m from the centre
    table = m.geom("table")
    assert table.pos[2] + table.size[2] == pytest.approx(0.0)
    wall = m.geom("wall_00")
    assert wall.pos[0] - wall.size[0] == pytest.approx(0.195)


@pytest.fixture(scope="module")
def env():
    return make("Trifinger", num_envs=2)


def test_builds_resets_and_steps_with_iges_sizes(env):
    declared = yaml.safe_load(TASK_YAML.read_text())["env"]
    obs = env.reset()
    # IGE: obs 9 + 9 + 7 + 7 + 9; states obs + 6 + 3 x 13 + 9 + 3 x 6
    assert obs["obs"].shape == (2, 41) and obs["states"].shape == (2, 113)
    assert env.num_actions == declared["numActions"] == 9
    assert env.max_episode_length == 750 and env.control_dt == pytest.approx(POLICY_DT)
    for _ in range(3):
        obs, rew, _, _ = env.step(torch.rand(2, 9) * 2 - 1)
    assert torch.isfinite(obs["obs"]).all() and torch.isfinite(obs["states"]).all() and torch.isfinite(rew).all()
    sim, cube = env.sim, env.cube
    # IGE's scale_transform onto [-1, 1] over its limits
    low = torch.tensor([-0.33, 0.0, -2.7] * 3)
    high = torch.tensor([1.0, 1.57, 0.0] * 3)
    expected = torch.cat([(2 * sim.dof_pos - low - high) / (high - low), sim.dof_vel / 10.0,
                          cube.root_pos[:, :2] / 0.3, (cube.root_pos[:, 2:] - 0.15) / 0.15, cube.root_quat,
                          env.goal_pos[:, :2] / 0.3, (env.goal_pos[:, 2:] - 0.15) / 0.15, env.goal_quat,
                          env.actions], dim=1)
    assert torch.allclose(obs["obs"], expected.clamp(-5, 5), atol=1e-5)
    raw = torch.cat([sim.dof_pos, sim.dof_vel, cube.root_pos, cube.root_quat, env.goal_pos, env.goal_quat,
                     env.actions], dim=1)
    assert torch.allclose(obs["states"][:, :41], raw.clamp(-5, 5), atol=1e-6)
    assert torch.allclose(obs["states"][:, 47:50], sim.xpos[:, env.tip_ids[0]], atol=1e-6)  # first fingertip


def test_torque_command_follows_iges_scaling_clamp_and_safety_damping(env):
    env.reset()
    qd = torch.tensor([[2.0, -1.0, 5.0, 0.0, 0.5, -3.0, 10.0, -10.0, 1.0]] * 2)
    env.sim.dof_vel[:] = qd
    actions = torch.tensor([[1.0, -1.0, 0.5, 0.0, 0.2, -0.7, 0.9, 0.9, -0.1]] * 2)
    got = env.joint_torques(actions)
    kd = [0.08, 0.08, 0.04] * 3
    for i in range(9):
        tau = min(max(0.36 * actions[0, i].item(), -0.36), 0.36)
        tau = min(max(tau - kd[i] * qd[0, i].item(), -0.36), 0.36)
        assert got[0, i].item() == pytest.approx(tau, abs=1e-6)
    env.pre_physics_step(actions)  # what the step writes to the motors
    assert torch.equal(env.sim.ctrl[:, :9], got)


def lgsk(x: float, scale: float) -> float:
    return 1.0 / (math.exp(scale * x) + 2.0 + math.exp(-scale * x))


def quat_wxyz(axis: np.ndarray, angle: float) -> list[float]:
    axis = axis / np.linalg.norm(axis)
    return [math.cos(angle / 2), *(math.sin(angle / 2) * axis)]


def rotmat(q: list[float]) -> np.ndarray:
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def test_keypoint_kernel_against_corners_by_hand():
    pos = [np.array([0.01, -0.02, 0.05]), np.array([0.0, 0.0, 0.0325])]
    quat = [quat_wxyz(np.array([1.0, 2.0, 0.5]), 0.7), [1.0, 0.0, 0.0, 0.0]]
    goal_pos, goal_quat = [np.array([0.05, 0.0, 0.08]), np.array([0.0, 0.0, 0.0325])], [quat_wxyz(np.array([0, 0, 1.0]), 1.2)] * 2
    got = keypoints_kernel(torch.tensor(np.array(pos), dtype=torch.float32), torch.tensor(quat, dtype=torch.float32),
                           torch.tensor(np.array(goal_pos), dtype=torch.float32),
                           torch.tensor(goal_quat, dtype=torch.float32))
    for k in range(2):
        total = 0.0
        for corner in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3) * 0.0325:
            a = pos[k] + rotmat(quat[k]) @ corner
            b = goal_pos[k] + rotmat(goal_quat[k]) @ corner
            total += lgsk(float(np.linalg.norm(a - b)), 30.0)
        assert got[k].item() == pytest.approx(total / 8, rel=1e-5)
    # at the goal pose every corner pays 1 / 4
    assert keypoints_kernel(*(torch.tensor(np.array(goal_pos), dtype=torch.float32),
                              torch.tensor(goal_quat, dtype=torch.float32)) * 2)[0].item() == pytest.approx(0.25)


def place(env, tips_shift: float = 0.0):
    """A constructed state: cube and goal poses set, fingertips read; returns what the reward terms read."""
    mask = torch.ones(2, dtype=torch.bool)
    cube_pos = torch.tensor([[0.02, -0.01, 0.0325], [-0.05, 0.04, 0.06]])
    cube_quat = torch.tensor([quat_wxyz(np.array([0, 0, 1.0]), 0.3), quat_wxyz(np.array([1.0, 1.0, 0]), 0.9)],
                             dtype=torch.float32)
    env.sim.write_state(mask, root_pos=cube_pos, root_quat=cube_quat, root_lin_vel=torch.zeros(2, 3),
                        root_ang_vel=torch.zeros(2, 3), asset="object")
    env.goal_pos[:] = torch.tensor([[0.03, 0.0, 0.07], [-0.05, 0.04, 0.06]])
    env.goal_quat[:] = torch.tensor([[1.0, 0, 0, 0], quat_wxyz(np.array([0, 1.0, 0]), 2.0)], dtype=torch.float32)
    env.refresh_state()
    return cube_pos, cube_quat


def test_each_reward_term_against_iges_formula(env):
    env.reset()
    cube_pos, cube_quat = place(env)
    tips = env.sim.xpos[:, env.tip_ids].clone()
    env.prev_tip_pos[:] = tips - torch.tensor([0.001, -0.002, 0.003])
    env.prev_object_pos[:] = cube_pos + torch.tensor([0.0, 0.01, 0.0])
    terms = {name: fn() for name, fn in zip(env.rewards.names, env.rewards.fns)}
    assert env.rewards.names == ["finger_move_penalty", "finger_reach_object_rate", "keypoints_dist"]  # YAML's active
    assert env.rewards.weights.tolist() == pytest.approx([-0.5, -250.0, 2000.0])
    for k in range(2):
        speed2 = 3 * (0.001 ** 2 + 0.002 ** 2 + 0.003 ** 2) / POLICY_DT ** 2
        assert terms["finger_move_penalty"][k].item() == pytest.approx(speed2, rel=1e-4)
        now = sum(float(np.linalg.norm(tips[k, i] - cube_pos[k])) for i in range(3))
        before = sum(float(np.linalg.norm(env.prev_tip_pos[k, i] - env.prev_object_pos[k])) for i in range(3))
        assert terms["finger_reach_object_rate"][k].item() == pytest.approx(now - before, abs=1e-6)
    # the inactive IGE terms, through their methods: object_dist and object_rot
    dist = torch.linalg.norm(cube_pos - env.goal_pos, dim=-1)
    for k in range(2):
        assert env._reward_object_dist()[k].item() == pytest.approx(POLICY_DT * lgsk(dist[k].item(), 50.0), rel=1e-5)
    # cube 1: goal about y by 2.0 rad, cube about (1, 1, 0) by 0.9: the angle between them from the rotation matrices
    r = rotmat(env.goal_quat[1].tolist()).T @ rotmat(cube_quat[1].tolist())
    angle = math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2)))
    assert env._reward_object_rot()[1].item() == pytest.approx(POLICY_DT / (3 * angle + 0.01), rel=1e-4)
    # the schedule: no reach term once the run has passed 5e7 env steps
    env.episode.run_steps.fill_(5e7 / 2 + 4)  # per env (a float32 count: steps of 2 here), 2 envs
    assert torch.all(env._reward_finger_reach_object_rate() == 0)
    env.episode.run_steps.fill_(0)


def test_success_needs_position_and_orientation_at_difficulty_4(env):
    env.reset()
    place(env)
    assert env.success_pos.tolist() == [False, True]   # cube 0 is 3.9 cm from its goal; cube 1 at its position
    assert env.success_quat.tolist() == [True, False]  # cube 0 turned 0.3 rad from its goal (tolerance 0.4)
    assert env.success.tolist() == [False, False]
    env.goal_quat[1] = env.cube.root_quat[1]
    env.refresh_state()
    assert env.success.tolist() == [False, True]


def test_episodes_last_750_steps_and_report_success_at_their_end(env):
    env.reset()
    env.progress_buf[:] = 748
    env.goal_pos[1] = env.cube.root_pos[1]
    env.goal_quat[1] = env.cube.root_quat[1]
    _, _, reset, extras = env.step(torch.zeros(2, 9))
    assert reset.tolist() == [1, 1] and extras["time_outs"].all()
    outcome = env.metrics.recorded("outcome")["consecutive_successes"]
    assert outcome.tolist() == [0.0, 1.0]
    assert env.metrics.recorded("episode_sum")["consecutive_successes"].item() == 1.0


def test_test_mode_outcomes_are_the_cube_to_goal_distance_and_angle_at_the_episode_end(env):
    env.reset()
    cube_pos, cube_quat = place(env)
    goal_quat = env.goal_quat[0].tolist()  # before the reset draws a new goal
    env.reset_idx(torch.tensor([True, False]))  # only cube 0's episode ends
    outcome = env.metrics.recorded("outcome")
    gap = float(np.linalg.norm(np.array([0.03, 0.0, 0.07]) - cube_pos[0].numpy()))
    assert outcome["final_goal_distance"].tolist() == pytest.approx([gap, 0.0], abs=1e-6)
    r = rotmat(goal_quat).T @ rotmat(cube_quat[0].tolist())  # the goal is upright: 0.3 rad about z
    angle = math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2)))
    assert outcome["final_goal_angle"].tolist() == pytest.approx([angle, 0.0], abs=1e-4)
    assert angle == pytest.approx(0.3, abs=1e-4)
    assert outcome["consecutive_successes_pos"].tolist() == [0.0, 0.0]  # 4 cm is outside 2 cm; cube 1 did not end
    env.reset_idx(torch.tensor([False, True]))  # cube 1 sits at its goal position, turned away
    place(env)
    env.reset_idx(torch.tensor([False, True]))
    outcome = env.metrics.recorded("outcome")
    assert outcome["consecutive_successes_pos"].tolist() == [0.0, 1.0]
    assert outcome["consecutive_successes"].tolist() == [0.0, 0.0]


def test_resets_place_robot_cube_and_goal_as_ige(env):
    mask = torch.ones(2, dtype=torch.bool)
    cubes, goals = [], []
    for _ in range(30):
        env.reset_idx(mask)
        assert torch.allclose(env.sim.dof_pos, torch.tensor([0.0, 0.9, -2.0] * 3).expand(2, 9))
        assert torch.all(env.sim.dof_vel == 0)
        assert torch.allclose(env.prev_tip_pos, env.sim.xpos[:, env.tip_ids])  # the first step compares with these
        cubes.append(env.cube.root_pos.clone())
        goals.append(env.goal_pos.clone())
        assert torch.equal(env.sim.mocap_pos[:, env.goal_marker], env.goal_pos)
        assert torch.equal(env.sim.mocap_quat[:, env.goal_marker], env.goal_quat)
    c, g = torch.cat(cubes), torch.cat(goals)
    max_r = 0.195 - 0.065 * math.sqrt(3) / 2
    assert torch.all(torch.linalg.norm(c[:, :2], dim=-1) <= max_r + 1e-6)
    assert torch.allclose(c[:, 2], torch.full((60,), 0.0325 + 0.0015))
    assert torch.all(torch.linalg.norm(g[:, :2], dim=-1) <= max_r + 1e-6)
    assert torch.all((g[:, 2] >= 0.065 * math.sqrt(3) / 2 - 1e-6) & (g[:, 2] <= 0.1 + 1e-6))


@pytest.mark.parametrize("difficulty", [-1, 1, 2, 3])
def test_goal_draws_of_the_other_difficulties(difficulty):
    pos, quat = sample_goals(difficulty, 200, "cpu")
    z_axis = pos[:, 2]
    if difficulty in (-1, 1):
        assert torch.allclose(z_axis, torch.full((200,), 0.0325))
    elif difficulty == 2:
        assert torch.allclose(pos, torch.tensor([0.0, 0.0, 0.0825]).expand(200, 3))
    else:
        assert torch.all((z_axis >= 0.0325) & (z_axis <= 0.1)) and z_axis.std() > 0.01
    yaw_only = quat[:, 1].abs().max() + quat[:, 2].abs().max()
    assert yaw_only == 0
    assert (quat[:, 3].abs().max() > 0.5) == (difficulty == -1)


def test_bad_settings_are_one_line_errors():
    with pytest.raises(ConfigError, match=r"env\.command_mode='velocity' is invalid: choose one of"):
        make("Trifinger", num_envs=1, overrides=["task.env.command_mode=velocity"])
    with pytest.raises(ConfigError, match=r"env\.reward_terms\.nope: unknown reward term"):
        make("Trifinger", num_envs=1, overrides=["+task.env.reward_terms.nope={weight: 1}"])


def test_train_py_trains_two_iterations_and_test_mode_evaluates(tmp_path):
    # test mode, with 0.2 s episodes so that every env finishes one quickly
    summary, result = train_py_two_iterations_then_test("Trifinger", tmp_path, 8, ("task.env.episodeLength_s=0.2",))
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 8 * 8
    assert result["episodes"] == 8
    assert 0.0 <= result["consecutive_successes"] <= result["consecutive_successes_pos"] <= 1.0
    assert 0.0 < result["final_goal_distance"] < 0.5 and 0.0 <= result["final_goal_angle"] <= math.pi


def tip_jacobian_policy(env, targets: np.ndarray, kp: float = 60.0, kd: float = 1.0) -> torch.Tensor:
    """A scripted policy: each fingertip pulled to its target by J^T (kp error - kd velocity) plus the fingers'
    gravity torques, from MuJoCo C's Jacobians at the fingers' current joint state; normalised torque actions."""
    m = env.sim.mj_model
    d = mujoco.MjData(m)
    joints = [m.joint(f"finger_{part}_{finger}") for finger in FINGER_YAW
              for part in ("base_to_upper_joint", "upper_to_middle_joint", "middle_to_lower_joint")]
    qadr, vadr = [j.qposadr[0] for j in joints], [j.dofadr[0] for j in joints]
    actions = np.zeros((env.num_envs, 9))
    for e in range(env.num_envs):
        d.qpos[:], d.qvel[:] = 0.0, 0.0
        d.qpos[qadr] = env.sim.dof_pos[e].numpy()
        mujoco.mj_forward(m, d)
        tau = d.qfrc_bias[vadr].copy()
        qd = env.sim.dof_vel[e].numpy()
        for k, finger in enumerate(FINGER_YAW):
            body = m.body(f"finger_tip_link_{finger}").id
            jac = np.zeros((3, m.nv))
            mujoco.mj_jacBody(m, d, jac, None, body)
            j = jac[:, vadr]
            tau += j.T @ (kp * (targets[e, k] - d.xpos[body]) - kd * (j @ qd))
        actions[e] = np.clip(tau / 0.36, -1.0, 1.0)
    return torch.tensor(actions, dtype=torch.float32)


def test_scripted_grasp_lifts_the_cube_to_a_goal_in_the_air_with_success_and_iges_reward(env):
    """The fingers squeeze the cube from their three sides and lift it 5.5 cm onto a goal at the same orientation:
    the cube reaches it (IGE's position and orientation tolerances, computed here), and the step's reward is IGE's sum
    of the three active terms, restated over the fingertip, cube and goal states."""
    env.reset()
    mask = torch.ones(2, dtype=torch.bool)
    centre = np.array([0.0, 0.0, 0.0325])
    env.sim.write_state(mask, root_pos=torch.tensor(np.stack([centre] * 2), dtype=torch.float32),
                        root_quat=torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2), root_lin_vel=torch.zeros(2, 3),
                        root_ang_vel=torch.zeros(2, 3), asset="object")
    goal = centre + [0.0, 0.0, 0.055]
    env.goal_pos[:] = torch.tensor(goal, dtype=torch.float32)
    env.goal_quat[:] = torch.tensor([1.0, 0.0, 0.0, 0.0])
    tips = env.sim.xpos[:, env.tip_ids].numpy()
    sides = tips[:, :, :2] / np.linalg.norm(tips[:, :, :2], axis=-1, keepdims=True)  # each finger's side of the cube

    def targets(radius: float, lift: float) -> np.ndarray:
        out = np.zeros((2, 3, 3))
        out[:, :, :2] = radius * sides
        out[:, :, 2] = centre[2] + lift
        return out

    for radius, lift, steps in ((0.08, 0.0, 50), (0.035, 0.0, 30), (0.015, 0.0, 30), (0.015, 0.06, 100)):
        for _ in range(steps):
            before_tips, before_cube = env.sim.xpos[:, env.tip_ids].clone(), env.cube.root_pos.clone()
            _, rew, _, _ = env.step(tip_jacobian_policy(env, targets(radius, lift)))
    cube_pos, cube_quat = env.cube.root_pos.numpy(), env.cube.root_quat.numpy()
    after_tips = env.sim.xpos[:, env.tip_ids].numpy()
    for k in range(2):
        assert cube_pos[k, 2] > centre[2] + 0.04  # lifted off the table
        angle = math.acos(max(-1.0, min(1.0, (np.trace(rotmat(cube_quat[k].tolist())) - 1) / 2)))
        reached = np.linalg.norm(cube_pos[k] - goal) <= 0.02 and angle <= 0.4
        assert reached and env.success_pos[k] and env.success[k]
        speed2 = (((after_tips[k] - before_tips[k].numpy()) / POLICY_DT) ** 2).sum()
        reach = sum(np.linalg.norm(after_tips[k, i] - cube_pos[k]) - np.linalg.norm(before_tips[k, i].numpy()
                                                                                     - before_cube[k].numpy())
                    for i in range(3))
        corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3) * 0.0325
        kernel = np.mean([lgsk(float(np.linalg.norm(cube_pos[k] + rotmat(cube_quat[k].tolist()) @ c - goal - c)), 30.0)
                          for c in corners])
        expected = -0.5 * speed2 - 250.0 * reach + 2000.0 * POLICY_DT * kernel
        assert rew[k].item() == pytest.approx(expected, rel=1e-3, abs=1e-3)
