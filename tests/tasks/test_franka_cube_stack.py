"""FrankaCubeStack (issue 32): IsaacGymEnvs' reward (task FrankaCubeStackIGE, ``env.reward.kind: isaacgymenvs``)
against a numpy transcription of its formula written here, its stack success on placed cubes (stacked and released,
stacked but held, 3 cm off), resets (cubes on the table, far enough apart, within the noise), the two control types
(targets and torques), the gripper, the observation against MuJoCo C, env.contact in the model, one-line errors, and one training iteration
plus test mode on the CPU. The staged reward, the default: tests/tasks/test_franka_cube_stack_staged.py."""

from __future__ import annotations

import json
import math

import mujoco
import numpy as np
import pytest
import torch

from isaacgymenvs_mw import make
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.tasks.arm_control import osc_torques
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, OUTCOME
from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.tasks.franka_cube_stack import (
    cube_stack_terms,
    grasp_terms,
    sample_cubes,
)
from isaacgymenvs_mw.utils.config import compose_config, to_dict
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import quat_from_matrix

TABLE_TOP = -0.1  # assets/mjcf/table.xml: 0.1 m below the robot base
Q0 = np.array([0.0, 0.1963, 0.0, -2.6180, 0.0, 2.9416, 0.7854, 0.035, 0.035])  # IGE's start pose
SCALES = {"dist": 0.1, "lift": 1.5, "align": 2.0, "stack": 16.0}  # IGE's FrankaCubeStack.yaml


def reference_reward(a, b, eef, tip_l, tip_r):
    """IsaacGymEnvs' compute_franka_reward, one env at a time in plain Python (table top at TABLE_TOP)."""
    def norm(v):
        return math.sqrt(sum(x * x for x in v))

    h = a[2] - TABLE_TOP
    d, dl, dr = norm(a - eef), norm(a - tip_l), norm(a - tip_r)
    dist = 1 - math.tanh(10.0 * (d + dl + dr) / 3)
    lifted = 1.0 if h - 0.05 > 0.04 else 0.0
    goal = b + np.array([0.0, 0.0, 0.06]) - a
    align = (1 - math.tanh(10.0 * norm(goal))) * lifted
    dist = max(dist, align)
    stacked = norm(goal[:2]) < 0.02 and abs(h - 0.07 - 0.025) < 0.02 and d > 0.04
    reward = 16.0 if stacked else 0.1 * dist + 1.5 * lifted + 2.0 * align
    return reward, stacked, {"dist": dist, "lifted": lifted, "align": align}


def compute_cube_stack_reward(terms: dict[str, torch.Tensor], dist_scale: float = 0.1, lift_scale: float = 1.5,
                              align_scale: float = 2.0, stack_scale: float = 16.0) -> torch.Tensor:
    """IsaacGymEnvs' reward in torch on the task's terms: ``stack_scale`` when stacked, else the weighted dist, lift and
    align terms (checked below against the plain-Python reference)."""
    shaped = dist_scale * terms["dist"] + lift_scale * terms["lifted"] + align_scale * terms["align"]
    return torch.where(terms["stacked"], torch.full_like(shaped, stack_scale), shaped)


def test_reward_terms_equal_the_reference_formula_on_constructed_states():
    rng = np.random.default_rng(0)
    n = 400
    b = np.column_stack([0.45 + rng.uniform(-0.25, 0.25, n), rng.uniform(-0.25, 0.25, n), np.full(n, -0.065)])
    # A: a quarter resting on the table, a quarter lifted, a quarter near its stacked place, a quarter stacked
    a = b + rng.normal(0.0, 0.1, (n, 3))
    a[: n // 4, 2] = TABLE_TOP + 0.025
    a[n // 4: n // 2, 2] = rng.uniform(0.0, 0.2, n // 4)
    a[n // 2: 3 * n // 4] = b[n // 2: 3 * n // 4] + [0, 0, 0.06] + rng.normal(0, 0.02, (n // 4, 3))
    a[3 * n // 4:] = b[3 * n // 4:] + [0, 0, 0.06] + rng.uniform(-0.01, 0.01, (n // 4, 3))
    eef = a + rng.normal(0.0, 0.05, (n, 3)) * rng.choice([0.1, 1.0], (n, 1))
    tip_l, tip_r = eef + rng.normal(0, 0.02, (n, 3)), eef + rng.normal(0, 0.02, (n, 3))
    t = lambda x: torch.tensor(x, dtype=torch.float64)
    terms = cube_stack_terms(t(a), t(b), t(eef), t(tip_l), t(tip_r))
    reward = compute_cube_stack_reward(terms)
    ref = [reference_reward(*v) for v in zip(a, b, eef, tip_l, tip_r)]
    np.testing.assert_allclose(reward.numpy(), [r for r, _, _ in ref], atol=1e-12)
    assert terms["stacked"].tolist() == [s for _, s, _ in ref]
    for key in ("dist", "lifted", "align"):
        np.testing.assert_allclose(terms[key].numpy(), [p[key] for _, _, p in ref], atol=1e-12)
    stacked = terms["stacked"].numpy()
    assert 20 < stacked.sum() < n - 20 and terms["lifted"].numpy().sum() > 50  # each branch is exercised


@pytest.fixture(scope="module")
def env():
    # IsaacGymEnvs' reward, whose success and 16 these tests check (the staged default: test_franka_cube_stack_staged),
    # with joint_pos control, whose 9-joint observation and 8 actions they read (osc's: test_osc_... below)
    return make("FrankaCubeStackIGE", num_envs=3, sim_device="cpu", rl_device="cpu", headless=True,
                overrides=["task.env.controlType=joint_pos"])


def test_the_isaacgymenvs_reward_is_a_task_of_its_own_that_differs_only_in_it():
    from isaacgymenvs_mw.tasks import get_task_class
    from isaacgymenvs_mw.tasks.franka_cube_stack import FrankaCubeStack

    assert get_task_class("FrankaCubeStackIGE") is FrankaCubeStack
    ige = to_dict(compose_config(["task=FrankaCubeStackIGE"]).task)
    stack = to_dict(compose_config(["task=FrankaCubeStack"]).task)
    assert ige.pop("name") == "FrankaCubeStackIGE" and stack.pop("name") == "FrankaCubeStack"
    assert ige["env"].pop("reward")["kind"] == "isaacgymenvs" and stack["env"].pop("reward")["kind"] == "staged"
    assert ige["env"].pop("graspedResetFraction") == 0.0 and stack["env"].pop("graspedResetFraction") > 0.0
    assert ige == stack
    # the reward key still selects it in FrankaCubeStack
    env = make("FrankaCubeStack", num_envs=1, sim_device="cpu", rl_device="cpu", headless=True,
               overrides=["task.env.reward.kind=isaacgymenvs"])
    assert env.reward_kind == "isaacgymenvs" and set(env.rewards.names) >= set(SCALES)


def place(env, a, b, q_arm=None):
    """Write cube A / B positions (yaw 0, at rest) and the arm's joints into every env, then refresh the state."""
    mask = torch.ones(env.num_envs, dtype=torch.bool)
    quat = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(env.num_envs, 1)
    zero = torch.zeros(env.num_envs, 3)
    for name, pos in (("cubeA", a), ("cubeB", b)):
        env.sim.write_state(mask, root_pos=torch.tensor(pos, dtype=torch.float32), root_quat=quat,
                            root_lin_vel=zero, root_ang_vel=zero, asset=name, refresh=False)
    if q_arm is not None:
        q = torch.tensor(q_arm, dtype=torch.float32)
        env.arm.reset(mask, q)
    env.sim.refresh_kinematics()
    env.refresh_state()


def grasp_joints(env, target):
    """Arm joints putting the grasp site at ``target``, fingers down, via the grasp test's IK (MuJoCo C)."""
    from test_franka_grasp import ik

    m = env.sim.mj_model
    return ik(m, m.site("grasp").id, np.asarray(target, dtype=float), Q0[:7])


def test_stack_success_only_when_aligned_on_b_and_released(env):
    b = np.array([0.45, 0.0, TABLE_TOP + 0.035])
    on_b = b + [0.0, 0.0, 0.06]
    held = np.concatenate([grasp_joints(env, on_b), [0.025, 0.025]])  # grasp point at A's centre
    away = Q0  # grasp point 10 cm above A
    cases = {"stacked and released": (on_b, away, True), "stacked but held": (on_b, held, False),
             "3 cm off in x, released": (on_b + [0.03, 0.0, 0.0], away, False)}
    a = np.stack([c[0] for c in cases.values()])
    q = np.stack([c[1] for c in cases.values()])
    place(env, a, np.tile(b, (3, 1)), q)
    grasp = env.arm.grasp_pos().numpy()
    np.testing.assert_allclose(grasp[1], on_b, atol=2e-5)  # the IK pose is what the sim has
    assert np.linalg.norm(grasp[0] - on_b) > 0.04
    assert env.check_success().tolist() == [c[2] for c in cases.values()]
    env.compute_reward()
    assert env.rew_buf[0].item() == pytest.approx(16.0)
    assert env.rew_buf[1].item() < 16.0


def test_an_episode_ends_on_stacking_and_counts_as_a_success(env):
    env.reset()
    b = np.array([0.45, 0.0, TABLE_TOP + 0.035])
    a = np.stack([b + [0, 0, 0.06], b + [0, 0.2, -0.01], b + [0, -0.2, -0.01]])  # env 0 stacked, 1-2 on the table
    place(env, a, np.tile(b, (3, 1)), np.tile(Q0, (3, 1)))
    _, rew, done, _extras = env.step(torch.tensor([[0.0] * 7 + [1.0]] * 3))  # hold still, gripper open
    assert done.tolist() == [1, 0, 0]
    assert rew[0].item() == pytest.approx(16.0)
    assert env.metrics.recorded(OUTCOME)["success"].tolist() == [1.0, 0.0, 0.0]
    assert env.metrics.recorded(EPISODE_SUM)["success"].item() == 1.0
    assert not torch.allclose(env.cube_a.root_pos[0], torch.tensor(a[0], dtype=torch.float32))  # reset


def test_cube_draws_rest_on_the_table_apart_and_within_the_noise():
    n = 20000
    centre = torch.tensor([0.45, 0.0])
    pos_a, pos_b, quat_a, quat_b = sample_cubes(n, centre, 0.25, 0.785, "cpu")
    apart = torch.linalg.norm(pos_a[:, :2] - pos_b[:, :2], dim=1)
    assert torch.all(apart >= 0.1697)  # IGE: 2 (0.05 + 0.07) sqrt(2) / 2
    for pos, half in ((pos_a, 0.025), (pos_b, 0.035)):
        assert torch.all((pos[:, :2] - centre).abs() <= 0.25)
        np.testing.assert_allclose(pos[:, 2].numpy(), TABLE_TOP + half, atol=1e-7)  # both on the table, B too
        # uniform in the square: each quarter of it gets about a quarter of the draws
        quarter = ((pos[:, 0] > 0.45).int() * 2 + (pos[:, 1] > 0).int()).bincount(minlength=4) / n
        assert torch.all((quarter - 0.25).abs() < 0.03)
    for quat in (quat_a, quat_b):
        np.testing.assert_allclose(torch.linalg.norm(quat, dim=1).numpy(), 1.0, atol=1e-6)
        assert torch.all(quat[:, 1:3] == 0.0)  # yaw only
        yaw = 2 * torch.atan2(quat[:, 3], quat[:, 0])
        assert torch.all(yaw.abs() <= 0.785 + 1e-6) and yaw.abs().max() > 0.78


def test_reset_places_arm_and_cubes_as_ige(env):
    for _ in range(3):
        env.reset()
        q = env.sim.dof_pos.numpy()
        assert np.all(np.abs(q[:, :7] - Q0[:7]) <= 0.25 + 1e-6)
        np.testing.assert_allclose(q[:, 7:], 0.035, atol=1e-7)  # fingers stay at the start opening
        lo, hi = env.arm.dof_lower.numpy(), env.arm.dof_upper.numpy()
        assert np.all((q >= lo - 1e-6) & (q <= hi + 1e-6))
        a, b = env.cube_a.root_pos.numpy(), env.cube_b.root_pos.numpy()
        np.testing.assert_allclose(a[:, 2], TABLE_TOP + 0.025, atol=1e-6)
        np.testing.assert_allclose(b[:, 2], TABLE_TOP + 0.035, atol=1e-6)
        assert np.all(np.linalg.norm(a[:, :2] - b[:, :2], axis=1) >= 0.1697)
        assert np.all(np.abs(a[:, :2] - [0.45, 0.0]) <= 0.25) and np.all(np.abs(b[:, :2] - [0.45, 0.0]) <= 0.25)
        np.testing.assert_array_equal(env.cube_a.root_lin_vel.numpy(), 0.0)


def test_observation_equals_mujoco_c_on_the_same_state(env):
    obs = env.reset()["obs"].numpy()
    assert env.observations.obs_layout.names == ["cube_a_quat", "cube_a_pos", "cube_a_to_b", "grasp_pos", "grasp_quat", "dof_pos"]
    m = env.sim.mj_model
    d = mujoco.MjData(m)
    for i in range(env.num_envs):
        d.qpos[:] = env.sim.qpos[i].numpy()
        mujoco.mj_kinematics(m, d)
        site_quat = np.zeros(4)
        mujoco.mju_mat2Quat(site_quat, d.site("grasp").xmat)
        site_quat *= np.sign(site_quat[0])
        expected = np.concatenate([d.body("cubeA/cube").xquat, d.body("cubeA/cube").xpos,
                                   d.body("cubeB/cube").xpos - d.body("cubeA/cube").xpos, d.site("grasp").xpos,
                                   site_quat, d.qpos[:9]])
        np.testing.assert_allclose(obs[i], np.clip(expected, -5, 5), atol=2e-5)


def test_quat_from_matrix_inverts_mujocos_quat_to_matrix():
    rng = np.random.default_rng(1)
    quats = rng.normal(size=(200, 4))
    quats[:4] = [[0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0, 0.6, 0.8, 0]]  # 180-degree turns: w = 0
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    quats *= np.where(quats[:, :1] < 0, -1, 1)
    mats = np.zeros((200, 9))
    for q, mat in zip(quats, mats):
        mujoco.mju_quat2Mat(mat, q)
    got = quat_from_matrix(torch.tensor(mats.reshape(-1, 3, 3)))
    same = np.minimum(np.abs(got.numpy() - quats).max(1), np.abs(got.numpy() + quats).max(1))  # w = 0: either sign
    assert same.max() < 1e-9


def test_joint_pos_moves_arm_targets_and_the_gripper_opens_or_closes(env):
    env.reset()
    start = env.arm.targets.clone()
    a = torch.tensor([[0.5, -1.0, 0.2, 0.0, 1.0, -0.3, 0.7, -0.2],
                      [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                      [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.3]])
    env.pre_physics_step(a)
    step = 2.0 / 60.0  # actionScale x control dt (rad)
    expected = np.clip(start.numpy()[:, :7] + a.numpy()[:, :7] * step, env.arm.target_lower.numpy()[:7],
                       env.arm.target_upper.numpy()[:7])
    np.testing.assert_allclose(env.sim.ctrl[:, :7].numpy(), expected, atol=1e-6)
    np.testing.assert_allclose(env.sim.ctrl[:, 7].numpy(), [0.0, 0.04, 0.04])  # a < 0 closes, a >= 0 opens (IGE)


def test_joint_tor_drives_the_arm_with_torques_at_the_limits():
    env = make("FrankaCubeStack", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True,
               overrides=["task.env.controlType=joint_tor"])
    m = env.sim.mj_model
    assert [m.actuator(f"actuator{i}").biastype[0] for i in range(1, 8)] == [0] * 7  # motors, no position bias
    assert m.actuator("gripper").biastype[0] == int(mujoco.mjtBias.mjBIAS_AFFINE)  # the gripper stays a servo
    env.reset()
    a = torch.tensor([[0.5, -1.0, 0.2, 0.0, 1.0, -0.3, 0.7, 1.0], [-1.0, 1.0, -0.5, 0.5, -1.0, 1.0, 0.0, -1.0]])
    env.step(a)
    limits = np.array([87.0] * 4 + [12.0] * 3)  # N m, franka_ros / FCI
    np.testing.assert_allclose(env.sim.ctrl[:, :7].numpy(), a[:, :7].numpy() * limits, rtol=1e-6)
    np.testing.assert_allclose(env.sim.actuator_force[:, :7].numpy(), a[:, :7].numpy() * limits, rtol=1e-5)
    assert env.num_obs == 26  # IGE's joint_tor observation: all 9 joint positions (26 values)


def test_env_contact_reaches_the_model(env):
    m = env.sim.mj_model
    for geom in ("left_finger_collision", "right_finger_collision", "cubeA/box", "cubeB/box"):
        assert m.geom(geom).condim[0] == 4
        np.testing.assert_allclose(m.geom(geom).friction, [1.0, 0.005, 0.0001])
    assert m.geom("link1_collision").condim[0] == 3  # not selected: the MJCF's own
    cfg = compose_config(["task=FrankaCubeStack", "num_envs=1", "sim_device=cpu", "rl_device=cpu", "headless=True"])
    cfg.task.env.contact = {"cube[AB]/box": {"condim": 6, "friction": [1.5, 0.02, 0.001]}}
    m = build_task(cfg).sim.mj_model
    assert m.geom("cubeA/box").condim[0] == m.geom("cubeB/box").condim[0] == 6
    np.testing.assert_allclose(m.geom("cubeB/box").friction, [1.5, 0.02, 0.001])
    assert m.geom("left_finger_collision").condim[0] == 3  # the new env.contact no longer selects the fingers


@pytest.mark.parametrize("value, message", [
    ("foo", r"^task\.env\.controlType='foo' is invalid: choose one of \['joint_pos', 'joint_tor', 'osc'\]$"),
    ("OSC", r"^task\.env\.controlType='OSC' is invalid: choose one of \['joint_pos', 'joint_tor', 'osc'\]$"),
])
def test_control_type_errors_are_one_line_naming_the_key(value, message):
    with pytest.raises(ConfigError, match=message):
        make("FrankaCubeStack", num_envs=1, sim_device="cpu", rl_device="cpu", headless=True,
             overrides=[f"task.env.controlType={value}"])


@pytest.mark.parametrize("control, actions", [("osc", 8), ("joint_pos", 7)])
def test_an_action_count_that_does_not_fit_the_control_type_is_one_line(control, actions):
    with pytest.raises(ConfigError, match=rf"numActions={actions} "):
        make("FrankaCubeStack", num_envs=1, sim_device="cpu", rl_device="cpu", headless=True,
             overrides=[f"task.env.controlType={control}", f"task.env.numActions={actions}"])


def test_training_one_iteration_then_test_mode_reports_a_success_rate(tmp_path, run_args):
    cfg = compose_config(["task=FrankaCubeStack", "num_envs=4", "max_iterations=1", "task.env.episodeLength_s=0.1",
                          "train.runner.num_steps_per_env=8", *run_args])
    summary = run(cfg)
    assert summary["iterations"] == 1 and summary["success"] == 0.0  # 6-step episodes ended, none stacked
    run_dir = next(p for p in (tmp_path / "runs" / "FrankaCubeStack").iterdir() if p.is_dir())
    eval_cfg = compose_config(["task=FrankaCubeStack", "num_envs=4", "test=True",
                               f"checkpoint={run_dir / 'model_1.pt'}", "task.env.episodeLength_s=0.1", *run_args])
    result = run(eval_cfg)
    written = json.loads((run_dir / "eval.json").read_text())
    assert written["success"] == result["success"] == 0.0 and written["episodes"] == 4


# ------------------------------------------------------------------------------------- osc
def test_osc_law_equals_the_formula_written_with_numpy():
    rng = np.random.default_rng(5)
    n, k = 4, 7
    a = rng.normal(size=(n, k, k))
    mass = a @ a.transpose(0, 2, 1) + k * np.eye(k)  # symmetric positive definite
    jac = rng.normal(size=(n, 6, k))
    q, qd, rest = rng.normal(size=(n, k)), rng.normal(size=(n, k)), rng.normal(size=k)
    err = rng.normal(size=(n, 6)) * 0.1
    kp, kp_null = 150.0, 10.0
    expected = []
    for i in range(n):
        m_inv = np.linalg.inv(mass[i])
        lam = np.linalg.inv(jac[i] @ m_inv @ jac[i].T)
        tau = jac[i].T @ lam @ (kp * err[i] - 2 * np.sqrt(kp) * jac[i] @ qd[i])
        wrapped = np.mod(rest - q[i] + np.pi, 2 * np.pi) - np.pi
        null = mass[i] @ (kp_null * wrapped - 2 * np.sqrt(kp_null) * qd[i])
        tau += (np.eye(k) - jac[i].T @ lam @ jac[i] @ m_inv) @ null
        expected.append(tau)
    t = lambda x: torch.as_tensor(x, dtype=torch.float64)
    got = osc_torques(t(err), t(q), t(qd), t(rest), t(mass), t(jac), kp, kp_null).numpy()
    np.testing.assert_allclose(got, np.array(expected), rtol=1e-9, atol=1e-9)


def test_osc_moves_the_grasp_point_along_the_commanded_axis():
    env = make("FrankaCubeStack", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True, seed=0,
               overrides=["task.env.controlType=osc", "task.env.frankaDofNoise=0.0"])
    assert env.num_obs == 19 and env.num_actions == 7  # IGE's osc observation and actions (numActions follows)
    env.reset()
    env.step(torch.zeros(2, 7))
    start = env.arm.grasp_pos().clone()
    action = torch.zeros(2, 7)
    action[0, 0] = 1.0   # world 0: +x
    action[1, 2] = -1.0  # world 1: -z
    for _ in range(30):  # half a second
        env.step(action)
    moved = env.arm.grasp_pos() - start
    # The commanded axis dominates. The law holds no orientation (a zero rotation command only damps the hand's
    # spin, as IGE's), so going down the hand tilts and the grasp point, 10 cm from the wrist, drifts along x.
    assert moved[0, 0] > 0.03 and abs(moved[0, 1]) < 0.3 * moved[0, 0] and abs(moved[0, 2]) < 0.3 * moved[0, 0]
    assert moved[1, 2] < -0.03 and abs(moved[1, 0]) < 0.7 * -moved[1, 2] and abs(moved[1, 1]) < 0.3 * -moved[1, 2]


def test_grasp_shaping_terms_equal_their_formula():
    rng = np.random.default_rng(11)
    n = 300
    cube = np.column_stack([rng.uniform(0.2, 0.7, n), rng.uniform(-0.3, 0.3, n), rng.uniform(-0.08, 0.05, n)])
    grasp = cube + rng.normal(scale=0.02, size=(n, 3))
    opening = rng.uniform(0.0, 0.04, n)
    held = (np.linalg.norm(cube - grasp, axis=1) < 0.03) & (opening < 0.03)
    # A rests with its centre 0.025 m above the table top (-0.1 m); "lifted" is 0.09 m: a 0.065 m rise
    rise = np.clip((cube[:, 2] - (-0.1) - 0.025) / 0.065, 0.0, 1.0)
    t = lambda x: torch.as_tensor(x, dtype=torch.float32)
    got = grasp_terms(t(cube), t(grasp), t(opening))
    np.testing.assert_array_equal(got["held"].numpy(), held.astype(np.float32))
    np.testing.assert_allclose(got["lift_height"].numpy(), held * rise, atol=1e-6)
    assert 0 < held.sum() < n and ((rise > 0) & (rise < 1) & held).any()  # both cases and a partial rise occur

