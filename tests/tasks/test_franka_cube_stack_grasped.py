"""FrankaCubeStack's resets with cube A already in the hand (issue 68, ``env.graspedResetFraction``): such a reset is
valid in MuJoCo C (A centred between the finger pads, its faces on them, nothing penetrating by more than 1 mm, A off
the table, B far enough away), A stays in the closed hand for 50 steps with the arm held still, the share of such
resets matches the key within binomial tolerance, bad values are one-line errors, and from such a start a scripted
carry, place and release (osc) reaches the stacked success with every later stage paid in order."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch
from test_franka_cube_stack_staged import (
    STAGE_NAMES,
    scripted_stack,
)

from isaacgymenvs_mw import make
from isaacgymenvs_mw.tasks.base.metrics import OUTCOME
from isaacgymenvs_mw.utils.errors import ConfigError

TABLE_TOP = -0.1     # assets/mjcf/table.xml: the table top 0.1 m below the robot base
HALF_A = 0.025       # cube A's half-width (assets/mjcf/cube_5cm.xml)
LIFT = 0.01          # the grasped start holds A's bottom this far above the table (the task YAML's comment)
MIN_AB = 2 * (0.05 + 0.07) * math.sqrt(2) / 2  # IGE: cubes at least twice their half-diagonals apart in xy
PAD_HALF_X, PAD_LENGTH = 0.0105, 0.054  # finger box (assets/mjcf/franka_panda.xml): half-width, length from its root


def grasped_env(num_envs: int, control: str = "joint_pos", *extra: str):
    env = make("FrankaCubeStack", num_envs=num_envs, sim_device="cpu", rl_device="cpu", headless=True, seed=0,
               overrides=["task.env.graspedResetFraction=1.0", f"task.env.controlType={control}", *extra])
    env.reset()
    return env


def mujoco_state(env, world: int) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """World ``world``'s positions in MuJoCo C, kinematics and contacts computed there."""
    m = env.sim.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = env.sim.qpos[world].double().numpy()
    mujoco.mj_forward(m, d)
    return m, d


def cube_pose(m: mujoco.MjModel, d: mujoco.MjData, cube: str) -> tuple[np.ndarray, np.ndarray]:
    """A cube's centre (3,) and axes (3, 3; columns) from its free joint."""
    adr = m.joint(f"{cube}/root").qposadr[0]
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, d.qpos[adr + 3:adr + 7])
    return d.qpos[adr:adr + 3].copy(), rot.reshape(3, 3)


def check_in_hand(m: mujoco.MjModel, d: mujoco.MjData) -> None:
    """A between the pads: its centre at the grasp point, its faces on the pads' inner faces and normal to the
    fingers' opening direction, its centre within each pad's width and depth."""
    site = m.site("grasp").id
    axes = d.site_xmat[site].reshape(3, 3)  # x, y (the fingers' opening), z (the approach, out of the palm)
    a, a_axes = cube_pose(m, d, "cubeA")
    assert np.linalg.norm(a - d.site_xpos[site]) < 1e-4                  # at the grasp point
    assert np.max(np.abs(a_axes.T @ axes[:, 1])) > 1 - 1e-6              # A's faces normal to the opening
    for finger, side in (("left_finger", 1.0), ("right_finger", -1.0)):
        face = d.xpos[m.body(finger).id]  # the finger body's origin: its pad's inner face, at the pad's root
        gap = side * float(np.dot(face - a, axes[:, 1]))
        assert abs(gap - HALF_A) < 2e-4, (finger, gap)                   # the pad on A's face
        assert abs(float(np.dot(face - a, axes[:, 0]))) < PAD_HALF_X      # A's centre within the pad's width
        depth = float(np.dot(a - face, axes[:, 2]))
        assert 0.0 < depth < PAD_LENGTH, (finger, depth)                 # ... and along the pad


def test_a_grasped_reset_is_valid_and_a_stays_in_the_closed_hand_for_50_steps():
    n = 6
    env = grasped_env(n)  # joint_pos: a zero arm action keeps the servo targets, the arm held where it is
    assert env.grasped_start.all()
    for world in range(n):
        m, d = mujoco_state(env, world)
        check_in_hand(m, d)
        dist = [d.contact[i].dist for i in range(d.ncon)]
        assert min(dist, default=0.0) >= -1e-3, dist  # no penetration beyond 1 mm anywhere in the world
        (a, _), (b, _) = cube_pose(m, d, "cubeA"), cube_pose(m, d, "cubeB")
        assert a[2] - HALF_A - TABLE_TOP == pytest.approx(LIFT, abs=1e-5)        # off the table, just
        assert b[2] == pytest.approx(TABLE_TOP + 0.035, abs=1e-6)               # B rests on the table
        assert np.linalg.norm(a[:2] - b[:2]) >= MIN_AB - 1e-6
        assert abs(a[0] - 0.45) <= 0.25 and abs(a[1]) <= 0.25                  # a start place of A
        grip = m.actuator("gripper").id
        assert d.qpos[m.joint("finger_joint1").qposadr[0]] == pytest.approx(HALF_A, abs=1e-6)
        assert env.sim.ctrl[world, grip].item() == 0.0  # commanded closed
    actions = torch.zeros(n, env.num_actions)
    actions[:, -1] = -1.0  # gripper closed, arm targets kept
    start = env.cube_a.root_pos.clone()
    for _ in range(50):
        env.step(actions)
        a, grasp = env.cube_a.root_pos, env.arm.grasp_pos()
        assert (torch.linalg.norm(a - grasp, dim=1) < 0.005).all()      # still centred in the hand
        assert (env.sim.dof_pos[:, 7] < HALF_A).all()                     # the fingers squeeze it
        assert (a[:, 2] - HALF_A - TABLE_TOP > 0.5 * LIFT).all()          # not dropped onto the table
    assert (torch.linalg.norm(env.cube_a.root_pos - start, dim=1) < 0.005).all()
    assert not env.reset_buf.any()


def test_the_share_of_grasped_resets_matches_the_key():
    fraction, n, rounds = 0.25, 64, 20
    env = make("FrankaCubeStack", num_envs=n, sim_device="cpu", rl_device="cpu", headless=True, seed=1,
               overrides=[f"task.env.graspedResetFraction={fraction}"])
    grasped = 0
    for _ in range(rounds):
        env.reset()
        rest = env.cube_a.root_pos[:, 2] - HALF_A - TABLE_TOP  # 0 on the table, LIFT in the hand
        held = rest > 0.5 * LIFT
        assert torch.equal(held, env.grasped_start)  # the flag says what the geometry shows
        grasped += int(held.sum())
    draws = n * rounds
    assert abs(grasped / draws - fraction) < 4.0 * math.sqrt(fraction * (1 - fraction) / draws), grasped
    for value, expected in (("0", 0), ("1.0", n)):
        env = make("FrankaCubeStack", num_envs=n, sim_device="cpu", rl_device="cpu", headless=True, seed=1,
                   overrides=[f"task.env.graspedResetFraction={value}"])
        env.reset()
        assert int(env.grasped_start.sum()) == expected


@pytest.mark.parametrize("value", ["-0.1", "1.5", "abc", "true", "nan"])
def test_a_bad_grasped_reset_fraction_is_one_line(value):
    shown = {"abc": "'abc'", "true": "True", "nan": "nan"}.get(value, value)
    message = rf"^task\.env\.graspedResetFraction={shown} is invalid: give a number >= 0\.0 and <= 1\.0$"
    with pytest.raises(ConfigError, match=message):
        make("FrankaCubeStack", num_envs=1, sim_device="cpu", rl_device="cpu", headless=True,
             overrides=[f"task.env.graspedResetFraction={value}"])


def test_from_a_grasped_start_a_scripted_carry_and_release_stacks_paying_every_later_stage_in_order():
    """test_franka_cube_stack_staged's script from A in the hand: carry it over B, set it down, let go. Every step's
    reward equals the reference formula; the stages from grasp on are first reached in order."""
    env = grasped_env(1, "osc", "task.env.startRotationNoise=0.0")
    done, stage, reward, first_reached = scripted_stack(env, pick=False)
    assert done and stage == "stacked" and reward == 1.0
    assert first_reached == STAGE_NAMES[1:]  # held from the first step: reach is never the furthest stage
    assert env.metrics.recorded(OUTCOME)["success"].tolist() == [1.0]
    assert env.metrics.recorded(OUTCOME)["furthest_stage"].tolist() == [float(STAGE_NAMES.index("stacked"))]


def test_test_mode_reports_each_episodes_furthest_stage():
    """eval.json's furthest_stage: from A in the hand with the gripper let open (action 0 opens, IGE's rule) every
    episode's furthest stage is the grasp (A held at the first step, dropped after); from IGE's resets, with the hand
    away from A, the reach."""
    from isaacgymenvs_mw.learning.evaluation import evaluate

    for fraction, furthest in ((1.0, "grasp"), (0.0, "reach")):
        env = make("FrankaCubeStack", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True, seed=0,
                   overrides=[f"task.env.graspedResetFraction={fraction}", "task.env.episodeLength_s=0.25"])
        result = evaluate(env, lambda obs: torch.zeros(2, env.num_actions), "cpu")
        assert result["furthest_stage"] == float(STAGE_NAMES.index(furthest)), (fraction, result)
