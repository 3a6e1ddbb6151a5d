"""Ingenuity (IsaacGymEnvs' task): the model against IGE's figures, Mars gravity and thrust, reward, targets,
termination, and train.py training then evaluating it.

IGE's figures (isaacgymenvs/tasks/ingenuity.py, _create_ingenuity_asset, compute_ingenuity_reward, set_targets) are
restated here, and the masses and the expected motions are computed from them independently of the task code.
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
from isaacgymenvs_mw.tasks.ingenuity import (
    compute_ingenuity_reward,
    ingenuity_failed,
    ingenuity_forces,
)

REPO = Path(__file__).resolve().parents[2]
XML = REPO / "assets" / "mjcf" / "ingenuity.xml"
TASK_YAML = REPO / "cfg" / "task" / "Ingenuity.yaml"
# IGE's figures
CHASSIS_HALF, CHASSIS_RHO = 0.06, 50.0
ROTOR_R, ROTOR_T, ROTOR_RHO = 0.15, 0.01, 1000.0
ROTOR_SEPARATION = 0.025
MARS_G = 3.721
POLICY_DT = 0.01  # IGE's sim dt (its policy step)


def ige_mass() -> float:
    return (2 * CHASSIS_HALF) ** 3 * CHASSIS_RHO + 2 * math.pi * ROTOR_R ** 2 * ROTOR_T * ROTOR_RHO


def test_model_mass_and_rotor_positions_match_ige_figures():
    m = mujoco.MjModel.from_xml_path(str(XML))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    chassis = m.body("chassis").id
    assert m.body_subtreemass[chassis] == pytest.approx(ige_mass(), rel=1e-6)
    assert m.body_mass[chassis] == pytest.approx((2 * CHASSIS_HALF) ** 3 * CHASSIS_RHO, rel=1e-6)
    for i in range(2):
        rotor = m.body(f"rotor_physics_{i}").id
        assert m.body_mass[rotor] == pytest.approx(math.pi * ROTOR_R ** 2 * ROTOR_T * ROTOR_RHO, rel=1e-6)
        np.testing.assert_allclose(d.xpos[rotor], [0.0, 0.0, 1.0 + i * ROTOR_SEPARATION], atol=1e-9)
        # a solid disc: I_zz = m r^2 / 2 about its axis
        assert m.body_inertia[rotor][2] == pytest.approx(0.5 * m.body_mass[rotor] * ROTOR_R ** 2, rel=1e-6)
    assert m.njnt == 1 and m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE  # rotors welded: IGE's locked hinges


@pytest.fixture(scope="module")
def env():
    return make("Ingenuity", num_envs=2)


def place_level(env, z: float = 2.0):
    n = env.num_envs
    mask = torch.ones(n, dtype=torch.bool)
    env.sim.write_state(mask, root_pos=torch.tensor([[0.0, 0.0, z]] * n), root_quat=torch.tensor([[1.0, 0, 0, 0]] * n),
                        root_lin_vel=torch.zeros(n, 3), root_ang_vel=torch.zeros(n, 3))
    env.target[:] = torch.tensor([0.0, 0.0, z])
    env.fresh.zero_()


def test_builds_resets_and_steps_with_the_yaml_sizes(env):
    declared = yaml.safe_load(TASK_YAML.read_text())["env"]
    obs = env.reset()["obs"]
    assert obs.shape == (2, declared["numObservations"]) == (2, 13)
    assert env.num_actions == declared["numActions"] == 6
    assert env.max_episode_length == 2000  # IGE's maxEpisodeLength
    assert env.sim.mj_model.opt.gravity.tolist() == pytest.approx([0.0, 0.0, -MARS_G])
    for _ in range(3):
        obs_dict, rew, _, _ = env.step(torch.rand(2, 6) * 2 - 1)
    assert torch.isfinite(obs_dict["obs"]).all() and torch.isfinite(rew).all()
    # IGE's layout: (target - position) / 3, quaternion, linear velocity / 2, angular velocity / pi
    sim = env.sim
    expected = torch.cat([(env.target - sim.root_pos) / 3, sim.root_quat, sim.root_lin_vel / 2,
                          sim.root_ang_vel_world() / math.pi], dim=-1).clamp(-5, 5)
    assert torch.allclose(obs_dict["obs"], expected, atol=1e-5)


def test_zero_thrust_falls_at_mars_gravity(env):
    place_level(env)
    env.step(torch.zeros(2, 6))
    v0 = env.sim.root_lin_vel[:, 2].clone()
    for _ in range(10):
        env.step(torch.zeros(2, 6))
    accel = (env.sim.root_lin_vel[:, 2] - v0) / (10 * POLICY_DT)
    assert torch.allclose(accel, torch.full((2,), -MARS_G), rtol=0.01), accel
    assert torch.all(env.sim.root_pos[:, 2] < 2.0)


def thrust_action(total_newton: float) -> torch.Tensor:
    """Both rotors straight up, sharing ``total_newton``: IGE's vertical thrust is action x 2000 x dt per rotor."""
    a = total_newton / 2 / (2000.0 * POLICY_DT)
    return torch.tensor([[0.0, 0.0, a, 0.0, 0.0, a]] * 2)


def test_thrust_above_mars_weight_lifts_and_weight_thrust_hovers(env):
    mass = ige_mass()
    place_level(env)
    for _ in range(50):
        env.step(thrust_action(mass * MARS_G))
    assert torch.all((env.sim.root_pos[:, 2] - 2.0).abs() < 0.005), env.sim.root_pos
    place_level(env)
    thrust = 1.5 * mass * MARS_G
    for _ in range(20):  # 0.2 s
        env.step(thrust_action(thrust))
    expected_vz = (thrust - mass * MARS_G) / mass * 20 * POLICY_DT
    assert torch.allclose(env.sim.root_lin_vel[:, 2], torch.full((2,), expected_vz), rtol=0.03), env.sim.root_lin_vel
    assert torch.all(env.sim.root_pos[:, 2] > 2.0)


def test_forces_follow_iges_action_scaling():
    actions = torch.tensor([[0.5, -0.1, 0.3, -1.0, 1.0, -0.25],
                            [0.0, 0.0, 1.0, 0.1, 0.15, 0.0]])
    got = ingenuity_forces(actions, POLICY_DT)
    for k in range(2):
        for rotor in range(2):
            a = actions[k, 3 * rotor:3 * rotor + 3].tolist()
            fz = a[2] * 2000 * POLICY_DT
            fx, fy = (fz * min(max(c, -0.2), 0.2) for c in a[:2])
            assert got[k, rotor].tolist() == pytest.approx([fx, fy, fz], abs=1e-5)
    assert got[0, 0, 0].item() == pytest.approx(0.2 * 6.0, abs=1e-5)  # lateral fraction clamped at 0.2


def test_lateral_thrust_accelerates_sideways_in_the_body_frame(env):
    mass = ige_mass()
    place_level(env)
    a = mass * MARS_G / 2 / 20.0  # per-rotor action for hover; lateral x fraction 0.2 on both rotors
    actions = torch.tensor([[0.2, 0.0, a, 0.2, 0.0, a]] * 2)
    for _ in range(5):
        env.step(actions)
    # 0.05 s of 0.2 x weight along +x (the craft barely tilts: forces act at the rotors' centres, on the axis)
    expected_vx = 0.2 * MARS_G * 5 * POLICY_DT
    assert torch.allclose(env.sim.root_lin_vel[:, 0], torch.full((2,), expected_vx), rtol=0.05), env.sim.root_lin_vel


def quat_about_x(theta: float) -> list[float]:
    return [math.cos(theta / 2), math.sin(theta / 2), 0.0, 0.0]


def test_reward_matches_ige_formula_on_constructed_states():
    targets = torch.tensor([[0.0, 0.0, 1.0], [2.0, -1.0, 1.5], [-4.0, 3.0, 1.2]])
    cases = [((0.0, 0.0, 1.0), 0.0, 0.0), ((1.0, -0.5, 2.0), 0.3, 1.5), ((-2.0, 0.0, 0.5), 1.2, -4.0)]
    pos = torch.tensor([c[0] for c in cases])
    quat = torch.tensor([quat_about_x(c[1]) for c in cases])
    angvel = torch.tensor([[0.3, -0.2, c[2]] for c in cases])
    got = compute_ingenuity_reward(pos, quat, angvel, targets)
    for k, (p, tilt, spin) in enumerate(cases):
        d2 = sum((p[i] - targets[k, i].item()) ** 2 for i in range(3))
        pos_r = 1 / (1 + d2)
        up_r = 5 / (1 + (1 - math.cos(tilt)) ** 2)  # body z tilted by `tilt`: its world z is cos(tilt)
        spin_r = 1 / (1 + spin ** 2)
        assert got[k].item() == pytest.approx(pos_r + pos_r * (up_r + spin_r), rel=1e-5)
    assert got[0].item() == pytest.approx(7.0)  # at the target, upright, not spinning: 1 + 1 (5 + 1)


def test_failure_rule_is_iges():
    target = torch.tensor([[1.0, 1.0, 1.5]]).expand(6, 3)
    pos = torch.tensor([[1.0, 1.0, 1.5], [8.9, 1.0, 1.5], [9.1, 1.0, 1.5], [1.0, 1.0, 0.51], [1.0, 1.0, 0.49],
                        [1.0, 1.0, 9.6]])
    assert ingenuity_failed(pos, target).tolist() == [False, False, True, False, True, True]


def test_a_craft_below_half_a_metre_ends_its_episode_as_a_failure(env):
    env.reset()
    mask = torch.tensor([True, False])
    env.sim.write_state(mask, root_pos=torch.tensor([[0.0, 0.0, 0.45], [0.0, 0.0, 0.45]]))
    _, _, reset, extras = env.step(torch.zeros(2, 6))
    assert reset.tolist() == [1, 0]
    assert not extras["time_outs"].any()
    assert env.progress_buf[0].item() == 0 and env.progress_buf[1].item() > 0


def test_reset_draws_iges_start_and_target_ranges(env):
    mask = torch.ones(2, dtype=torch.bool)
    targets, starts = [], []
    for _ in range(40):
        env.reset_idx(mask)
        targets.append(env.target.clone())
        starts.append(env.sim.root_pos.clone())
        assert torch.equal(env.sim.mocap_pos[:, env.marker], env.target)  # the marker shows the target
    t, p = torch.cat(targets), torch.cat(starts)
    assert torch.all(t[:, :2].abs() <= 5.0) and torch.all((t[:, 2] >= 1.0) & (t[:, 2] <= 2.0))
    assert torch.all(p[:, :2].abs() <= 1.5) and torch.all((p[:, 2] >= 0.8) & (p[:, 2] <= 2.5))
    assert t[:, :2].abs().max() > 3.0 and p[:, :2].abs().max() > 1.0  # drawn over the ranges, not fixed
    assert torch.all(env.fresh)
    assert torch.all(env.sim.root_lin_vel == 0) and torch.all(env.sim.root_quat == torch.tensor([1.0, 0, 0, 0]))


def test_first_step_of_an_episode_applies_no_thrust(env):
    place_level(env)
    env.fresh[:] = torch.tensor([True, False])
    env.step(thrust_action(3 * ige_mass() * MARS_G))
    vz = env.sim.root_lin_vel[:, 2].clone()
    assert vz[0].item() == pytest.approx(-MARS_G * POLICY_DT, rel=0.02)
    assert vz[1].item() == pytest.approx(2 * MARS_G * POLICY_DT, rel=0.02)
    env.step(thrust_action(3 * ige_mass() * MARS_G))  # the episode's second step: thrust in both
    dv = env.sim.root_lin_vel[:, 2] - vz
    assert torch.allclose(dv, torch.full((2,), 2 * MARS_G * POLICY_DT), rtol=0.02), dv


def test_thrust_turns_with_the_craft(env):
    """Tilted by 30 degrees about x, the rotors push along the body's z axis: (0, -sin 30, cos 30) in the world."""
    mass, tilt = ige_mass(), math.radians(30.0)
    place_level(env)
    env.sim.write_state(torch.ones(2, dtype=torch.bool), root_quat=torch.tensor([quat_about_x(tilt)] * 2))
    thrust = 2 * mass * MARS_G
    for _ in range(5):
        env.step(thrust_action(thrust))
    t = 5 * POLICY_DT
    expected = torch.tensor([0.0, -thrust * math.sin(tilt) / mass * t, (thrust * math.cos(tilt) / mass - MARS_G) * t])
    assert torch.allclose(env.sim.root_lin_vel, expected.expand(2, 3), atol=2e-3), env.sim.root_lin_vel


def test_targets_move_every_500_steps_of_an_episode(env):
    env.reset()
    before = env.target.clone()
    env.fresh.zero_()
    env.progress_buf[:] = torch.tensor([500, 499])
    env.pre_physics_step(torch.zeros(2, 6))
    assert not torch.equal(env.target[0], before[0]) and torch.equal(env.target[1], before[1])
    assert torch.equal(env.sim.mocap_pos[:, env.marker], env.target)
    # 0: a new episode keeps the target its reset drew; only whole multiples of 500 steps draw
    for steps, draws in [((0, 1000), (False, True)), ((250, 1500), (False, True)), ((501, 750), (False, False))]:
        moved = env.target.clone()
        env.progress_buf[:] = torch.tensor(steps)
        env.pre_physics_step(torch.zeros(2, 6))
        assert [not torch.equal(env.target[k], moved[k]) for k in range(2)] == list(draws), steps
    env.clear_body_forces()


def test_spin_is_capped_at_iges_four_pi(env):
    place_level(env)
    env.sim.write_state(torch.ones(2, dtype=torch.bool), root_ang_vel=torch.tensor([[0.0, 0.0, 30.0], [1.0, 2.0, 2.0]]))
    env.step(torch.zeros(2, 6))
    speed = torch.linalg.norm(env.sim.root_ang_vel, dim=-1)
    assert speed[0].item() == pytest.approx(4 * math.pi, rel=1e-4)
    assert speed[1].item() == pytest.approx(3.0, rel=1e-3)  # below the cap: unchanged


def test_train_py_trains_two_iterations_and_test_mode_evaluates(tmp_path):
    # test mode, with 0.2 s episodes so that every env finishes one quickly
    summary, result = train_py_two_iterations_then_test("Ingenuity", tmp_path, 8, ("task.env.episodeLength_s=0.2",))
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 16 * 8
    assert result["episodes"] == 8
    assert math.isfinite(result["target_distance"])
