"""Quadcopter (IsaacGymEnvs' task): the model against IGE's figures, thrust physics, reward, termination, training.

IGE's figures (isaacgymenvs/tasks/quadcopter.py, _create_quadcopter_asset) are restated here, and the masses and rotor
positions are computed from them independently of the MJCF.
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
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, OUTCOME, PER_STEP
from isaacgymenvs_mw.tasks.quadcopter import compute_quadcopter_reward, quadcopter_failed
from isaacgymenvs_mw.utils.errors import ConfigError

XML = Path(__file__).resolve().parents[2] / "assets" / "mjcf" / "quadcopter.xml"
# IGE's figures
CHASSIS_R, CHASSIS_T, CHASSIS_RHO = 0.1, 0.03, 50.0
ROTOR_R, ROTOR_T, ROTOR_RHO = 0.04, 0.01, 1000.0
ARM_R, ARM_RHO = 0.01, 200.0
ANGLES = [0.25 * math.pi, 0.75 * math.pi, 1.25 * math.pi, 1.75 * math.pi]
G = 9.81


def ige_mass() -> float:
    chassis = math.pi * CHASSIS_R ** 2 * CHASSIS_T * CHASSIS_RHO
    arm = 4.0 / 3.0 * math.pi * ARM_R ** 3 * ARM_RHO
    rotor = math.pi * ROTOR_R ** 2 * ROTOR_T * ROTOR_RHO
    return chassis + 4 * (arm + rotor)


def test_model_mass_and_rotor_positions_match_ige_figures():
    m = mujoco.MjModel.from_xml_path(str(XML))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert m.body_subtreemass[m.body("chassis").id] == pytest.approx(ige_mass(), rel=1e-6)
    assert m.body_mass[m.body("rotor0").id] == pytest.approx(math.pi * ROTOR_R ** 2 * ROTOR_T * ROTOR_RHO, rel=1e-6)
    reach = (CHASSIS_R + 0.25 * ARM_R) + (ROTOR_R + 0.25 * ARM_R)  # arm offset + rotor offset along the arm
    for i, angle in enumerate(ANGLES):
        expected = [reach * math.cos(angle), reach * math.sin(angle), 1.0]
        np.testing.assert_allclose(d.xpos[m.body(f"rotor{i}").id], expected, atol=1e-5)
        np.testing.assert_allclose(d.site_xpos[m.site(f"rotor{i}_thrust").id], expected, atol=1e-5)
    assert np.allclose(np.degrees(m.jnt_range[1:]), [-30, 30])  # IGE's +-30 degree rotor joints
    assert [m.joint(j).name for j in range(1, 9)] == [f"rotor_{k}{i}" for i in range(4) for k in ("pitch", "roll")]


@pytest.fixture(scope="module")
def env():
    return make("Quadcopter", num_envs=2)


def place_level(env, z=1.0):
    n = env.num_envs
    mask = torch.ones(n, dtype=torch.bool)
    env.sim.write_state(mask, dof_pos=torch.zeros(n, 8), dof_vel=torch.zeros(n, 8),
                        root_pos=torch.tensor([[0.0, 0.0, z]] * n), root_quat=torch.tensor([[1.0, 0, 0, 0]] * n),
                        root_lin_vel=torch.zeros(n, 3), root_ang_vel=torch.zeros(n, 3))
    env.dof_position_targets.zero_()
    env.fresh.zero_()


def hold(env, thrust_per_rotor: float, steps: int):
    env.thrusts.fill_(thrust_per_rotor)
    for _ in range(steps):  # zero actions: thrusts and joint targets hold (IGE integrates the actions)
        env.step(torch.zeros(env.num_envs, 12))


def test_hover_thrust_holds_the_craft_in_mujoco_c(env):
    """MuJoCo C, the task's compiled model: m g shared by the 4 rotors, along each rotor's z axis, for 1 s."""
    m = env.sim.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    mass = m.body_subtreemass[m.body("chassis").id]
    rotors = [m.body(f"rotor{i}").id for i in range(4)]
    for _ in range(int(round(1.0 / m.opt.timestep))):
        for b in rotors:
            d.xfrc_applied[b, :3] = d.xmat[b].reshape(3, 3) @ [0.0, 0.0, mass * G / 4]
        mujoco.mj_step(m, d)
    assert abs(d.qpos[2] - 1.0) < 0.01 and np.abs(d.qpos[0:2]).max() < 0.01
    assert np.abs(d.qvel[0:3]).max() < 0.02


def test_task_thrust_hovers_and_accelerates_at_t_minus_mg_over_m(env):
    mass = ige_mass()
    place_level(env)
    hold(env, mass * G / 4, 100)  # 1 s at the task's policy rate
    assert torch.all((env.sim.root_pos[:, 2] - 1.0).abs() < 0.01), env.sim.root_pos
    assert torch.all(env.sim.root_pos[:, :2].abs() < 0.01)
    place_level(env)
    thrust = 1.5 * mass * G
    hold(env, thrust / 4, 20)  # 0.2 s
    expected_vz = (thrust - mass * G) / mass * 0.2
    assert torch.allclose(env.sim.root_lin_vel[:, 2], torch.full((2,), expected_vz), rtol=0.03), env.sim.root_lin_vel


def quat_about_x(theta: float) -> list[float]:
    return [math.cos(theta / 2), math.sin(theta / 2), 0.0, 0.0]


def test_reward_matches_ige_formula_on_constructed_states():
    target = torch.tensor([0.0, 0.0, 1.0])
    cases = [((0.0, 0.0, 1.0), 0.0, 0.0), ((1.0, -0.5, 2.0), 0.3, 1.5), ((-2.0, 0.0, 0.5), 1.2, -4.0)]
    pos = torch.tensor([c[0] for c in cases])
    quat = torch.tensor([quat_about_x(c[1]) for c in cases])
    angvel = torch.tensor([[0.3, -0.2, c[2]] for c in cases])
    got = compute_quadcopter_reward(pos, quat, angvel, target)
    for k, (p, tilt, spin) in enumerate(cases):
        d2 = p[0] ** 2 + p[1] ** 2 + (1.0 - p[2]) ** 2
        pos_r = 1 / (1 + d2)
        up_r = 1 / (1 + (1 - math.cos(tilt)) ** 2)  # body z axis tilted by `tilt`: its world z is cos(tilt)
        spin_r = 1 / (1 + spin ** 2)
        assert got[k].item() == pytest.approx(pos_r + pos_r * (up_r + spin_r), rel=1e-5)
    assert got[0].item() == pytest.approx(3.0)


def test_termination_rule_is_iges():
    target = torch.tensor([0.0, 0.0, 1.0])
    pos = torch.tensor([[0.0, 0.0, 1.0], [2.9, 0.0, 1.0], [3.1, 0.0, 1.0], [0.0, 0.0, 0.31], [0.0, 0.0, 0.29],
                        [0.0, 0.0, 3.9], [0.0, 0.0, 4.1]])
    assert quadcopter_failed(pos, target).tolist() == [False, False, True, False, True, False, True]


def test_reset_ranges_are_iges(env):
    env.reset_idx(torch.ones(2, dtype=torch.bool))
    for _ in range(30):
        env.reset_idx(torch.ones(2, dtype=torch.bool))
        p, q = env.sim.root_pos, env.sim.dof_pos
        assert torch.all(p[:, :2].abs() <= 1.5) and torch.all((p[:, 2] >= 0.8) & (p[:, 2] <= 2.5))
        assert torch.all(q.abs() <= 0.2)
    assert torch.all(env.thrusts == 0) and torch.all(env.fresh)


def test_one_training_iteration_then_test_mode(tmp_path, run_args):
    train_one_iteration_then_test("Quadcopter", tmp_path / "runs", run_args, ["task.env.episodeLength_s=0.1"])


def test_missing_rotor_bodies_is_a_one_line_error_naming_the_key():
    with pytest.raises(ConfigError, match=r"^task\.env\.rotorBodies=\['rotor0', 'rotor1', 'rotor2', 'prop3'\] is "
                                          r"invalid: .*not in the model: \['prop3'\][^\n]*$"):
        make("Quadcopter", num_envs=1, overrides=("task.env.rotorBodies=[rotor0,rotor1,rotor2,prop3]",))


def test_test_mode_reports_distance_and_reached_target_by_the_distance_at_the_episode_end(env):
    env.metrics.evaluate()  # as evaluate() does
    env.metrics.begin_step()
    target = torch.tensor([0.0, 0.0, 1.0])
    mask = torch.tensor([True, True])
    env.reset_idx(mask)
    env.sim.write_state(mask, root_pos=torch.tensor([[0.0, 0.05, 1.0], [0.3, 0.0, 1.0]]))
    env.compute_reward()
    assert env.metrics.recorded(PER_STEP)["target_distance"].tolist() == pytest.approx([0.05, 0.3], abs=1e-5)
    env.reset_idx(torch.tensor([True, False]))  # only the first episode ends: the second reports nothing
    assert env.metrics.recorded(OUTCOME)["reached_target"].tolist() == [1.0, 0.0]
    env.sim.write_state(mask, root_pos=torch.stack([target + torch.tensor([0.2, 0.0, 0.0]), target]))
    env.reset_idx(mask)
    assert env.metrics.recorded(OUTCOME)["reached_target"].tolist() == [0.0, 1.0]
    env.metrics.evaluate(False)


def test_training_counts_the_episodes_that_end_at_the_target_as_its_success(env):
    # Training (no test mode): the sum over the ending episodes of those within 0.1 m, logged as the rate
    # Episode/reached_target that save_best follows; no per-env outcome.
    env.metrics.begin_step()
    target = torch.tensor([0.0, 0.0, 1.0])
    mask = torch.tensor([True, True])
    env.sim.write_state(mask, root_pos=torch.stack([target + torch.tensor([0.0, 0.09, 0.0]),
                                                    target + torch.tensor([0.0, 0.0, 0.11])]))
    env.reset_idx(mask)
    assert env.metrics.recorded(EPISODE_SUM)["reached_target"].item() == 1.0
    assert "reached_target" not in env.metrics.recorded(OUTCOME)
    env.metrics.begin_step()
    env.sim.write_state(mask, root_pos=target.expand(2, 3))
    env.reset_idx(torch.tensor([False, True]))  # one episode ends, at the target; the other runs on
    assert env.metrics.recorded(EPISODE_SUM)["reached_target"].item() == 1.0


def test_spin_is_capped_at_max_angular_velocity_with_its_direction_kept(env):
    # PhysX's default cap on a rigid body's angular speed, applied by the task once per policy step.
    mask = torch.ones(2, dtype=torch.bool)
    env.reset_idx(mask)
    env.sim.write_state(mask, root_ang_vel=torch.tensor([[300.0, 400.0, 0.0], [1.0, -2.0, 2.0]]))
    env.fresh.zero_()
    env.pre_physics_step(torch.zeros(2, 12))
    spin = env.sim.root_ang_vel.clone()
    assert torch.linalg.norm(spin[0]).item() == pytest.approx(env.max_angular_velocity, rel=1e-5)
    assert torch.allclose(spin[0] / torch.linalg.norm(spin[0]), torch.tensor([0.6, 0.8, 0.0]), atol=1e-6)
    assert torch.linalg.norm(spin[1]).item() == pytest.approx(3.0, rel=1e-5)  # slower than the cap: unchanged
    assert env.max_angular_velocity == 100.0


def test_max_angular_velocity_must_be_positive():
    with pytest.raises(ConfigError, match=r"^task\.env\.maxAngularVelocity=0\.0 is invalid: give a number > 0"):
        make("Quadcopter", num_envs=1, overrides=("task.env.maxAngularVelocity=0",))


def test_joint_limits_are_the_rotor_hinges_thirty_degrees(env):
    lower, upper = env.sim.joint_limits()  # the dofs in dof_pos order: IGE's ±30° on every rotor hinge
    assert lower.shape == (8,) and torch.allclose(lower, torch.full((8,), -math.pi / 6), atol=1e-6)
    assert torch.allclose(upper, torch.full((8,), math.pi / 6), atol=1e-6)
    one_lower, _ = env.sim.joint_limits(["rotor_roll2"])  # by name
    assert one_lower.tolist() == pytest.approx([-math.pi / 6])
