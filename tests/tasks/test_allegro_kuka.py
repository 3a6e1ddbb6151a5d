"""AllegroKuka (IsaacGymEnvs' reorientation task): the arm + hand model against the URDF's kinematics and drive
figures, the task's build, step and reset, each reward term against a formula written here, success counting, the
tolerance curriculum, bad settings, and one training iteration then test mode.

The URDF figures (isaac-sim/IsaacGymEnvs, assets/urdf/kuka_allegro_description/kuka_allegro_touch_sensor.urdf) and
IGE's task constants (tasks/allegro_kuka/allegro_kuka_base.py) are restated here and chained in numpy, independently
of the MJCF and of the task code.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from conftest import train_one_iteration_then_test

from isaacgymenvs_mw import make
from isaacgymenvs_mw.tasks.allegro_kuka import lifting_terms, random_quaternion
from isaacgymenvs_mw.utils.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
XML = REPO / "assets" / "mjcf" / "allegro_kuka.xml"
PI = 3.14159265359
HALF_PI = 1.57079632679
# URDF joint origins (xyz, rpy): base -> link_1 ... link_7, then the fixed ee, mount and palm links.
ARM_ORIGINS = [((0, 0, 0.15), (0, 0, 0)), ((0, 0, 0.19), (HALF_PI, 0, PI)), ((0, 0.21, 0), (HALF_PI, 0, PI)),
               ((0, 0, 0.19), (HALF_PI, 0, 0)), ((0, 0.21, 0), (-HALF_PI, PI, 0)),
               ((0, 0.0607, 0.19), (HALF_PI, 0, 0)), ((0, 0.081, 0.0607), (-HALF_PI, PI, 0))]
EE = ((0, 0, 0.071), (0, 0, 0))
MOUNT_TO_PALM = ((0.008219, -0.02063, 0.08086), (0, -1.5708, 0.785398))
# index finger: palm_link -> link_0 ... link_3
INDEX = [((0.0514302, -0.03632, -0.0113), (3.1415, -1.57075, -0.0872638888889)),
         ((0, 0, 0), (3.1415, -1.57075, 1.57075)), ((0.054, 0, 0), (0, 0, 0)), ((0.0384, 0, 0), (0, 0, 0))]
THUMB = [((-0.0367482, -0.0081281, -0.0295), (-1.57075, -1.57075, 1.48348611111)),
         ((0.005, 0, 0), (1.57075, 0, 0)), ((0, 0, 0.0554), (3.1415, -1.57075, 0)), ((0.0514, 0, 0), (0, 0, 0))]
ARM_LIMITS = [2.96705972839, 2.09439510239, 2.96705972839, 2.09439510239, 2.96705972839, 2.09439510239,
              3.05432619099]
ARM_MASSES = [3.4525, 3.4821, 4.05623, 3.4822, 2.1633, 2.3466, 3.129]
# IGE's task constants
BASE = np.array([0.0, 0.8, 0.0])
ARM_DEFAULT = [-1.571, 1.571, 0.0, 1.376, 0.0, 1.485, 2.358]
PALM_OFFSET = np.array([0.0, -0.02, 0.16])
TIP_OFFSET = np.array([0.05, 0.005, 0.0])


def transform(xyz, rpy) -> np.ndarray:
    r, p, y = rpy
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    t = np.eye(4)
    t[:3, :3] = rz @ ry @ rx
    t[:3, 3] = xyz
    return t


def about_z(q: float) -> np.ndarray:
    return transform((0, 0, 0), (0, 0, q))


def urdf_chain(arm_q, origins=(), finger_q=()) -> np.ndarray:
    """The world transform of link_7 (no ``origins``) or of a finger link below palm_link, base at the origin."""
    t = np.eye(4)
    for (xyz, rpy), q in zip(ARM_ORIGINS, arm_q):
        t = t @ transform(xyz, rpy) @ about_z(q)
    if not origins:
        return t
    t = t @ transform(*EE) @ transform(*MOUNT_TO_PALM)
    for (xyz, rpy), q in zip(origins, finger_q):
        t = t @ transform(xyz, rpy) @ about_z(q)
    return t


def pose_model(arm_q, hand_q):
    m = mujoco.MjModel.from_xml_path(str(XML))
    d = mujoco.MjData(m)
    d.qpos[:7], d.qpos[7:] = arm_q, hand_q
    mujoco.mj_kinematics(m, d)
    return m, d


@pytest.mark.parametrize("arm_q", [[0.0] * 7, [0.3, -0.7, 1.1, 1.5, -0.4, 0.9, -2.0]])
def test_link_7_and_fingertips_follow_the_urdf_chain(arm_q):
    hand_q = np.linspace(-0.2, 0.9, 16)
    m, d = pose_model(arm_q, hand_q)
    expected = urdf_chain(arm_q)
    np.testing.assert_allclose(d.xpos[m.body("iiwa7_link_7").id], expected[:3, 3], atol=1e-6)
    np.testing.assert_allclose(d.xmat[m.body("iiwa7_link_7").id].reshape(3, 3), expected[:3, :3], atol=1e-6)
    for name, origins, q in (("index_link_3", INDEX, hand_q[0:4]), ("thumb_link_3", THUMB, hand_q[12:16])):
        expected = urdf_chain(arm_q, origins, q)
        np.testing.assert_allclose(d.xpos[m.body(name).id], expected[:3, 3], atol=2e-4)  # rpy given to 4 digits
        np.testing.assert_allclose(d.xmat[m.body(name).id].reshape(3, 3), expected[:3, :3], atol=2e-4)


def test_flange_at_the_zero_pose_is_the_sum_of_the_joint_offsets():
    # At q = 0 the chain is straight up: 0.15 + 0.19 + 0.21 + 0.19 + 0.21 + 0.19 + 0.081 (+ the joint-6 offsets
    # 0.0607 along y, which cancel) = 1.221 m above the base.
    m, d = pose_model([0.0] * 7, np.zeros(16))
    np.testing.assert_allclose(d.xpos[m.body("iiwa7_link_7").id], [0.0, 0.0, 1.221], atol=1e-6)


def test_joints_masses_and_drives_are_the_urdfs_and_iges():
    m = mujoco.MjModel.from_xml_path(str(XML))
    assert m.nu == m.njnt == 23
    for i in range(7):
        assert m.jnt_range[i].tolist() == pytest.approx([-ARM_LIMITS[i], ARM_LIMITS[i]])
        assert m.body_mass[m.body(f"iiwa7_link_{i + 1}").id] == pytest.approx(ARM_MASSES[i])
        assert m.actuator_forcerange[i].tolist() == pytest.approx([-300, 300])
    assert m.jnt_range[m.joint("thumb_joint_0").id].tolist() == pytest.approx([0.279244, 1.57075])
    assert np.allclose(m.actuator_forcerange[7:], [-0.35, 0.35])
    # position servo: force = kp (ctrl - q) - kv qdot: gainprm[0] = kp, biasprm = (0, -kp, -kv)
    assert np.allclose(m.actuator_gainprm[:, 0], 40.0) and np.allclose(m.actuator_biasprm[:, 1:3], [-40.0, -5.0])
    assert np.allclose(m.actuator_ctrlrange, m.jnt_range)
    hand = sum(m.body_mass[m.body(f"{f}_link_{k}").id] for f in ("index", "middle", "ring") for k in range(4))
    assert hand == pytest.approx(3 * (0.005 + 0.125164 + 0.131691 + 0.0211922))
    assert all(m.body_gravcomp[2:] == 1.0)  # IGE disables gravity on the robot (body 1, link_0, is fixed)


@pytest.fixture(scope="module")
def env():
    return make("AllegroKuka", num_envs=2, sim_device="cpu", rl_device="cpu")


def test_builds_resets_and_steps(env):
    obs = env.reset()["obs"]
    assert obs.shape == (2, 117) and env.num_actions == 23
    assert env.max_episode_length == 600
    for _ in range(5):
        obs_dict, rew, _, _ = env.step(torch.rand(2, 23) * 2 - 1)
    assert torch.isfinite(obs_dict["obs"]).all() and torch.isfinite(rew).all()
    assert torch.equal(env.sim.mocap_pos[:, env.goal_marker], env.goal_pos)


def set_robot(env, arm_q):
    mask = torch.ones(2, dtype=torch.bool)
    dof = torch.zeros(2, 23)
    dof[:, :7] = torch.tensor(arm_q)
    env.sim.write_state(mask, dof_pos=dof, dof_vel=torch.zeros(2, 23))
    env.sim.refresh_kinematics()


def test_palm_centre_and_fingertips_at_iges_arm_pose(env):
    env.reset()
    set_robot(env, ARM_DEFAULT)
    env._measure()
    t7 = urdf_chain(ARM_DEFAULT)
    palm = BASE + t7[:3, 3] + t7[:3, :3] @ PALM_OFFSET
    assert env.palm_center[0].tolist() == pytest.approx(palm.tolist(), abs=1e-5)
    tip = urdf_chain(ARM_DEFAULT, INDEX, [0.0] * 4)
    assert env.tip_pos[0, 0].tolist() == pytest.approx((BASE + tip[:3, 3] + tip[:3, :3] @ TIP_OFFSET).tolist(),
                                                       abs=3e-4)
    assert 0.53 < palm[2] < 1.2  # above the table top, within the arm's reach


def cube_keypoints(pos, quat):
    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, np.asarray(quat, dtype=float))
    corners = 0.0375 * np.array([[1, 1, 1], [1, 1, -1], [-1, -1, 1], [-1, -1, -1]])  # 0.05 x 1.5 / 2
    return np.asarray(pos) + corners @ r.reshape(3, 3).T


def test_reward_terms_match_iges_formulas_on_a_constructed_state(env):
    env.reset()
    set_robot(env, ARM_DEFAULT)
    quat = np.array([math.cos(0.3), 0.0, math.sin(0.3), 0.0])
    cube = np.array([[0.05, 0.02, 0.60], [0.0, 0.1, 0.80]])  # env 1: lifted 0.17 above its 0.63 start
    env.sim.write_state(torch.ones(2, dtype=torch.bool), root_pos=torch.tensor(cube, dtype=torch.float32),
                        root_quat=torch.tensor(np.stack([quat, quat]), dtype=torch.float32), asset="object")
    env.goal_pos[:] = torch.tensor([[0.1, 0.1, 0.9], [0.0, 0.15, 0.8]])
    env.goal_quat[:] = torch.tensor([[1.0, 0, 0, 0], [1.0, 0, 0, 0]])
    env.lifted[:] = False
    env.closest_fingertip_dist[:] = 0.9
    env.closest_keypoint_max_dist[:] = 0.5
    env.near_goal_steps[:] = 0
    env.successes[:] = 0
    dof_vel = torch.tensor([[0.5, -1.0, 0, 0, 0.2, 0, 0.1] + [0.3] * 16, [0.0] * 7 + [-2.0] * 16])
    env.sim.write_state(torch.ones(2, dtype=torch.bool), dof_vel=dof_vel)
    env.sim.refresh_kinematics()
    # expected, written from IGE's compute_kuka_reward
    m = env.sim.mj_model
    xpos, xquat = env.sim.xpos.numpy(), env.sim.xquat.numpy()
    tips = []
    for k, name in enumerate(("index_link_3", "middle_link_3", "ring_link_3", "thumb_link_3")):
        b = m.body(name).id
        off = np.array([0.06 if k == 3 else 0.05, 0.005, 0.0])
        r = np.zeros(9)
        rows = []
        for e in range(2):
            mujoco.mju_quat2Mat(r, xquat[e, b].astype(float))
            rows.append(xpos[e, b] + r.reshape(3, 3) @ off)
        tips.append(rows)
    tips = np.array(tips).transpose(1, 0, 2)
    env.refresh_state()
    env.compute_reward()
    for e in range(2):
        z_lift = 0.05 + cube[e, 2] - 0.63
        lifted = z_lift > 0.15
        lifting = 0.0 if lifted else min(max(z_lift, 0.0), 0.5)
        dist = np.linalg.norm(tips[e] - cube[e], axis=-1)
        approach = 0.0 if lifted else np.clip(0.9 - dist, 0, 10).sum()
        kp = cube_keypoints(cube[e], quat)
        goal_kp = cube_keypoints(env.goal_pos[e].numpy(), [1.0, 0, 0, 0])
        kp_max = np.linalg.norm(kp - goal_kp, axis=-1).max()
        keypoint = max(0.5 - kp_max, 0.0) if lifted else 0.0
        near = kp_max <= 0.075 * 1.5
        arm_pen = -np.abs(dof_vel[e, :7].numpy()).sum()
        hand_pen = -np.abs(dof_vel[e, 7:].numpy()).sum()
        terms = env.terms
        assert terms["lifting"][e].item() == pytest.approx(lifting, abs=1e-5)
        assert terms["lift_bonus"][e].item() == float(lifted)
        assert terms["fingertip_delta"][e].item() == pytest.approx(approach, abs=2e-4)
        assert terms["keypoint"][e].item() == pytest.approx(keypoint, abs=1e-5)
        assert terms["bonus"][e].item() == float(near)
        total = (20 * lifting + 300 * lifted + 50 * approach + 200 * keypoint + 1000 * near + 0.003 * arm_pen
                 + 0.0003 * hand_pen)
        assert env.rew_buf[e].item() == pytest.approx(total, abs=2e-2)
    assert env.lifted.tolist() == [False, True]
    assert env.terms["keypoint"][1].item() > 0.0 and env.terms["fingertip_delta"][0].item() > 0.0


def test_lifting_terms_pay_once_and_stop_after_the_lift():
    start = 0.63
    z = torch.tensor([0.60, 0.70, 0.75, 0.75])
    before = torch.tensor([False, False, False, True])
    lifting, bonus, lifted = lifting_terms(z, start, before, 0.15)
    assert lifting.tolist() == pytest.approx([0.02, 0.12, 0.0, 0.0], abs=1e-6)
    assert bonus.tolist() == [0.0, 0.0, 1.0, 0.0] and lifted.tolist() == [False, False, True, True]


def test_a_success_counts_pays_the_bonus_and_draws_a_new_goal(env):
    env.reset()
    for _ in range(3):
        env.step(torch.zeros(2, 23))
    env.goal_pos[:] = env.cube.root_pos
    env.goal_quat[:] = env.cube.root_quat
    env.goal_pos[1, 2] += 0.5  # env 1 far from its goal
    env.successes[:] = torch.tensor([4.0, 0.0])
    old_goal = env.goal_pos.clone()
    _, rew, reset, _ = env.step(torch.zeros(2, 23))
    assert env.successes.tolist() == [5.0, 0.0]
    assert rew[0].item() > 900.0 and rew[1].item() < 100.0
    assert not torch.equal(env.goal_pos[0], old_goal[0]) and torch.equal(env.goal_pos[1], old_goal[1])
    assert env.near_goal_steps.tolist() == [0, 0] and reset.tolist() == [0, 0]
    assert torch.equal(env.sim.mocap_quat[:, env.goal_marker], env.goal_quat)


def test_max_consecutive_successes_end_the_episode_as_a_success(env):
    env.reset()
    env.step(torch.zeros(2, 23))
    env.goal_pos[:] = env.cube.root_pos
    env.goal_quat[:] = env.cube.root_quat
    env.successes[:] = torch.tensor([49.0, 10.0])
    _, _, reset, extras = env.step(torch.zeros(2, 23))
    assert reset.tolist() == [1, 0]
    assert extras["successes"].tolist() == [True, False] and extras["time_outs"].tolist() == [True, False]
    assert env.prev_episode_successes[0].item() == 50.0 and env.successes[0].item() == 0.0
    assert env.successes[1].item() == 11.0


def test_a_cube_on_the_ground_ends_the_episode(env):
    env.reset()
    env.sim.write_state(torch.tensor([True, False]), root_pos=torch.tensor([[0.5, 0.0, 0.05]] * 2), asset="object")
    _, _, reset, extras = env.step(torch.zeros(2, 23))
    assert reset.tolist() == [1, 0] and not extras["time_outs"].any()


def test_tolerance_curriculum_tightens_only_when_due_and_good_enough(env):
    env.success_tolerance.fill_(0.075)
    env.frame.fill_(0)
    env.last_curriculum_update.fill_(0)
    env.prev_episode_successes[:] = 3.0
    env.frame.fill_(2998)
    env._curriculum()  # frame 2999: not due
    assert env.success_tolerance.item() == pytest.approx(0.075)
    env._curriculum()  # frame 3000: due, 3 successes on average
    assert env.success_tolerance.item() == pytest.approx(0.0675)
    assert env.last_curriculum_update.item() == 3000
    env.frame.fill_(6500)
    env.prev_episode_successes[:] = torch.tensor([2.0, 3.0])  # 2.5 on average: kept
    env._curriculum()
    assert env.success_tolerance.item() == pytest.approx(0.0675)
    env.success_tolerance.fill_(0.0105)
    env.prev_episode_successes[:] = 5.0
    env._curriculum()
    assert env.success_tolerance.item() == pytest.approx(0.01)  # not below targetSuccessTolerance
    env.success_tolerance.fill_(0.075)


def test_reset_draws_within_iges_ranges(env):
    mask = torch.ones(2, dtype=torch.bool)
    cubes, goals, dofs = [], [], []
    for _ in range(30):
        env.reset_idx(mask)
        cubes.append(env.cube.root_pos.clone())
        goals.append(env.goal_pos.clone())
        dofs.append(env.sim.dof_pos.clone())
    c, g, q = torch.cat(cubes), torch.cat(goals), torch.cat(dofs)
    assert torch.all((c - torch.tensor([0.0, 0.0, 0.63])).abs() <= torch.tensor([0.1, 0.1, 0.02]) + 1e-6)
    assert torch.all((g >= torch.tensor([-0.4, 0.0, 0.68]) - 1e-6) & (g <= torch.tensor([0.4, 0.35, 1.05]) + 1e-6))
    lower, upper = env.dof_lower, env.dof_upper
    default = torch.zeros(23)
    default[:7] = torch.tensor(ARM_DEFAULT)
    bound_lo = torch.maximum(default + 0.1 * (lower - default), lower)
    bound_hi = torch.maximum(torch.minimum(default + 0.1 * (upper - default), upper), lower)  # thumb_joint_0:
    # its default 0 is below its range, so IGE's draw is clamped up to the lower limit
    assert torch.all((q >= bound_lo - 1e-5) & (q <= bound_hi + 1e-5))
    assert torch.equal(env.prev_targets, env.sim.dof_pos)


def test_random_quaternions_are_unit_and_uniform():
    q = random_quaternion(20000, "cpu")
    assert torch.allclose(q.norm(dim=-1), torch.ones(20000), atol=1e-5)
    # uniform over rotations: each component's square averages 1/4, and signs are balanced
    assert torch.allclose((q * q).mean(dim=0), torch.full((4,), 0.25), atol=0.01)
    assert q.mean(dim=0).abs().max().item() < 0.02


def test_arm_targets_move_by_iges_speed_and_hand_targets_span_the_range(env):
    env.reset()
    before = env.prev_targets.clone()
    actions = torch.zeros(2, 23)
    actions[:, :7] = 0.6
    actions[:, 7:] = 1.0
    env.pre_physics_step(actions)
    expected_arm = torch.clamp(before[:, :7] + 10.0 / 60.0 * 0.6, env.dof_lower[:7], env.dof_upper[:7])
    assert torch.allclose(env.sim.ctrl[:, :7], expected_arm, atol=1e-6)
    assert torch.allclose(env.sim.ctrl[:, 7:23], env.dof_upper[7:].expand(2, 16), atol=1e-6)
    env.clear_body_forces()


@pytest.mark.parametrize("override, message", [
    ("task.env.useRelativeControl=True", "env.useRelativeControl=True is not supported"),
    ("task.env.randomizeObjectDimensions=True", "env.randomizeObjectDimensions=True is not supported"),
    ("task.env.objectType=pen", "env.objectType='pen' is invalid"),
    ("task.env.actionsMovingAverage=0", "env.actionsMovingAverage=0.0 is invalid"),
])
def test_bad_settings_are_one_line_errors(override, message):
    with pytest.raises(ConfigError) as err:
        make("AllegroKuka", num_envs=1, sim_device="cpu", rl_device="cpu", overrides=[override])
    assert message in str(err.value) and "\n" not in str(err.value)


def test_one_training_iteration_then_test_mode(tmp_path, run_args):
    train_one_iteration_then_test("AllegroKuka", tmp_path / "runs", run_args, ["task.env.episodeLength_s=0.1"])
