"""AllegroKukaRegrasping and AllegroKukaThrow (IsaacGymEnvs' other AllegroKuka subtasks): the bucket against IGE's
mesh, build / step / reset, the success rule on states placed through the simulator, the reward terms whose meaning
the subtasks change (one keypoint at the centre, the bonus spread over successSteps, the lift paid again after a
success) against formulas written here, the fall-only failure rule, the reset ranges, and a 2-iteration train.py run
then test mode.

IGE's numbers (isaac-sim/IsaacGymEnvs, isaacgymenvs/tasks/allegro_kuka/allegro_kuka_{base,regrasping,throw}.py,
cfg/task/env/{regrasping,throw}.yaml, assets/urdf/objects/meshes/bucket.obj) are restated here.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from conftest import train_py_two_iterations_then_test

from isaacgymenvs_mw import make
from isaacgymenvs_mw.utils.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
TOLERANCE = 0.075 * 1.5          # successTolerance x keypointScale (m)
CUBE_START = torch.tensor([0.0, 0.0, 0.63])
START_NOISE = torch.tensor([0.1, 0.1, 0.02])
GOAL_BOX = (torch.tensor([-0.4, 0.0, 0.68]), torch.tensor([0.4, 0.35, 1.05]))  # origin (0, 0.05, 0.8) + extent
# bucket.obj: inner floor vertices at radius 0.0705 m, z 0.0099 m; inner rim at 0.1034 m, z 0.1977 m; 12 vertices at
# multiples of 30 deg around the axis (0, -0.002016)
MESH_AXIS = np.array([0.0, -0.002016])
INNER = ((0.0705, 0.0099), (0.1034, 0.1977))
ALL = torch.ones(2, dtype=torch.bool)
ZERO3 = torch.zeros(2, 3)


@pytest.fixture(scope="module")
def regrasp():
    return make("AllegroKukaRegrasping", num_envs=2, sim_device="cpu", rl_device="cpu")


@pytest.fixture(scope="module")
def throw():
    return make("AllegroKukaThrow", num_envs=2, sim_device="cpu", rl_device="cpu")


def place_cube(env, pos, quat=None, lin_vel=None):
    quat = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2) if quat is None else quat
    env.sim.write_state(ALL, root_pos=pos, root_quat=quat, root_lin_vel=ZERO3 if lin_vel is None else lin_vel,
                        root_ang_vel=ZERO3, asset="object")


def place_bucket(env, bucket):
    env.sim.mocap_pos[:, env.bucket_marker] = bucket
    env.goal_pos[:] = bucket + torch.tensor([0.0, 0.0, 0.05])  # IGE: the goal 5 cm above the bucket's origin
    env.sim.refresh_kinematics()


def test_bucket_walls_lie_on_the_inner_faces_of_iges_mesh():
    m = mujoco.MjModel.from_xml_path(str(REPO / "assets" / "mjcf" / "bucket_allegro_kuka.xml"))
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    for k in range(12):
        g = m.geom(f"wall{k}").id
        normal = d.geom_xmat[g].reshape(3, 3)[:, 0]   # the box's x axis: the side's outward normal
        inner_face = d.geom_xpos[g] - m.geom_size[g, 0] * normal
        for radius, z in INNER:
            for deg in (30 * k, 30 * k + 30):        # the side's two vertices
                a = math.radians(deg)
                vertex = np.array([*(MESH_AXIS + radius * np.array([math.cos(a), math.sin(a)])), z])
                assert abs(np.dot(vertex - inner_face, normal)) < 2e-4, (k, deg, radius)
        assert normal[2] < 0.0 and d.geom_xpos[g, 2] - m.geom_size[g, 2] * abs(d.geom_xmat[g, 8]) < 0.005
    floor = m.geom("floor").id
    assert d.geom_xpos[floor, 2] + m.geom_size[floor, 2] == pytest.approx(0.0099, abs=1e-4)  # the inner floor
    assert m.body_mocapid[m.body("bucket").id] == 0


@pytest.mark.parametrize("task", ["regrasp", "throw"])
def test_builds_steps_and_resets(task, request):
    env = request.getfixturevalue(task)
    obs = env.reset()["obs"]
    # IGE's full_state with one keypoint: 23 x 2 + 3 + 10 + 10 + 12 + 3 + 3 + 3 + 1 + 4 + 1 + 1 + 1 + 1
    assert obs.shape == (2, 99) and env.num_actions == 23
    assert env.max_episode_length == 300
    for _ in range(4):
        obs_dict, rew, _, _ = env.step(torch.rand(2, 23) * 2 - 1)
    assert torch.isfinite(obs_dict["obs"]).all() and torch.isfinite(rew).all()
    assert torch.equal(env.sim.mocap_pos[:, env.goal_marker], env.goal_pos)
    before = env.goal_pos.clone()
    env.reset_envs(torch.tensor([True, False]))
    assert env.progress_buf.tolist()[0] == 0 and torch.equal(env.goal_pos[1], before[1])


def test_subtask_settings_are_iges():
    regrasp_env = make("AllegroKukaRegrasping", num_envs=1, sim_device="cpu", rl_device="cpu")
    assert regrasp_env.success_steps == 30 and regrasp_env.k["forceScale"] == 2.0
    throw_env = make("AllegroKukaThrow", num_envs=1, sim_device="cpu", rl_device="cpu")
    assert throw_env.success_steps == 5 and throw_env.k["forceScale"] == 0.0
    assert throw_env.k["successTolerance"] == throw_env.k["targetSuccessTolerance"] == 0.075


def test_regrasping_success_needs_the_centre_near_the_goal_for_30_steps(regrasp):
    env = regrasp
    env.reset()
    goal = torch.tensor([[0.1, 0.2, 0.9], [-0.2, 0.1, 0.8]])
    env.goal_pos[:] = goal
    # env 0: 0.1 m from the goal (inside 0.1125), rotated (orientation does not count); env 1: 0.12 m away
    offset = torch.tensor([[0.06, 0.0, -0.08], [0.0, 0.12, 0.0]])
    turned = torch.tensor([[math.cos(0.7), math.sin(0.7), 0.0, 0.0]] * 2)
    place_cube(env, goal + offset, turned)
    env.near_goal_steps[:] = 28
    env.successes[:] = 0
    env.refresh_state()
    expected = (offset.norm(dim=-1) <= TOLERANCE).tolist()
    assert expected == [True, False] and env.near_goal().tolist() == expected
    assert env.near_goal_steps.tolist() == [29, 28] and env.successes.tolist() == [0.0, 0.0]
    env.refresh_state()  # the 30th step near the goal: a success in env 0 only
    assert env.successes.tolist() == [1.0, 0.0] and env.goal_reset.tolist() == [True, False]


def test_a_success_puts_the_cube_back_on_the_table_and_draws_a_goal(regrasp):
    env = regrasp
    env.reset()
    env.step(torch.zeros(2, 23))
    env.goal_pos[:] = torch.tensor([[0.1, 0.2, 0.9], [-0.2, 0.1, 0.8]])
    place_cube(env, env.goal_pos.clone())
    env.lifted[:] = True
    env.near_goal_steps[:] = torch.tensor([29, 0])
    env.successes[:] = 0
    old_goal = env.goal_pos.clone()
    _, rew, reset, _ = env.step(torch.zeros(2, 23))
    assert env.successes.tolist() == [1.0, 0.0] and reset.tolist() == [0, 0]
    assert rew[0].item() > 1000.0 / 30 - 5.0  # the bonus, spread over successSteps
    cube = env.cube.root_pos[0]
    assert torch.all((cube - CUBE_START).abs() <= START_NOISE + 1e-6)  # back at its start pose
    assert env.lifted.tolist() == [False, True] and env.near_goal_steps[0].item() == 0
    assert not torch.equal(env.goal_pos[0], old_goal[0]) and torch.equal(env.goal_pos[1], old_goal[1])
    assert env.closest_keypoint_max_dist[0].item() == pytest.approx((cube - env.goal_pos[0]).norm().item(), abs=1e-5)


def test_reward_terms_with_the_centre_keypoint(regrasp):
    env = regrasp
    env.reset()
    goal = torch.tensor([[0.1, 0.1, 0.9], [0.0, 0.15, 0.8]])
    cube = torch.tensor([[0.12, 0.08, 0.85], [0.05, 0.0, 0.64]])  # env 0 lifted (0.22 above its start), env 1 not
    env.goal_pos[:] = goal
    place_cube(env, cube, torch.tensor([[math.cos(0.4), 0.0, math.sin(0.4), 0.0]] * 2))
    dof_vel = torch.tensor([[0.5, -1.0, 0, 0, 0.2, 0, 0.1] + [0.3] * 16, [0.0] * 7 + [-2.0] * 16])
    env.sim.write_state(ALL, dof_vel=dof_vel)
    env.lifted[:] = False
    env.closest_keypoint_max_dist[:] = 0.4
    env.closest_fingertip_dist[:] = 0.0  # no approach reward: these terms are AllegroKuka's, tested there
    env.near_goal_steps[:] = 0
    env.refresh_state()
    env.compute_reward()
    for e in range(2):
        dist = (cube[e] - goal[e]).norm().item()  # one keypoint: the centre
        z_lift = 0.05 + cube[e, 2].item() - 0.63
        lifted = z_lift > 0.15
        lifting = 0.0 if lifted else min(max(z_lift, 0.0), 0.5)
        keypoint = max(0.4 - dist, 0.0) if lifted else 0.0
        near = dist <= TOLERANCE
        total = (20 * lifting + 300 * lifted + 200 * keypoint + 1000 / 30 * near
                 - 0.003 * dof_vel[e, :7].abs().sum().item() - 0.0003 * dof_vel[e, 7:].abs().sum().item())
        assert env.terms["keypoint"][e].item() == pytest.approx(keypoint, abs=1e-5)
        assert env.terms["lifting"][e].item() == pytest.approx(lifting, abs=1e-5)
        assert env.terms["lift_bonus"][e].item() == float(lifted)
        assert env.terms["bonus"][e].item() == pytest.approx(near / 30)
        assert env.rew_buf[e].item() == pytest.approx(total, abs=2e-2)
    assert env.terms["keypoint"][0].item() > 0.0 and bool(env.terms["bonus"][0] > 0)
    assert env.closest_keypoint_max_dist[0].item() == pytest.approx((cube[0] - goal[0]).norm().item(), abs=1e-5)


def test_the_hand_far_from_the_cube_does_not_end_a_subtask_episode(regrasp):
    env = regrasp
    env.reset()
    place_cube(env, torch.tensor([[2.5, 0.0, 0.6], [0.0, 0.0, 0.05]]))  # env 0: 2 m from the hand; env 1: fallen
    _, _, reset, _ = env.step(torch.zeros(2, 23))
    assert env.tip_dist[0].min().item() > 1.5
    assert reset.tolist() == [0, 1]


def test_reset_draws_within_iges_ranges(regrasp, throw):
    goals, cubes, buckets, throw_goals = [], [], [], []
    for _ in range(40):
        regrasp.reset_idx(ALL)
        throw.reset_idx(ALL)
        goals.append(regrasp.goal_pos.clone())
        cubes += [regrasp.cube.root_pos.clone(), throw.cube.root_pos.clone()]
        buckets.append(throw.bucket_pos.clone())
        throw_goals.append(throw.goal_pos.clone())
    g, c, b = torch.cat(goals), torch.cat(cubes), torch.cat(buckets)
    assert torch.all((g >= GOAL_BOX[0] - 1e-6) & (g <= GOAL_BOX[1] + 1e-6))
    assert torch.all((c - CUBE_START).abs() <= START_NOISE + 1e-6)
    assert torch.all((b[:, 0].abs() >= 0.5) & (b[:, 0].abs() <= 0.9))
    assert (b[:, 0] > 0).any() and (b[:, 0] < 0).any()  # both sides of the table
    assert torch.all((b[:, 1] >= -1.0) & (b[:, 1] <= 0.7) & (b[:, 2] >= 0.0) & (b[:, 2] <= 1.0))
    assert torch.allclose(torch.cat(throw_goals), b + torch.tensor([0.0, 0.0, 0.05]))
    assert torch.equal(regrasp.goal_quat, torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2))


def test_a_cube_thrown_into_the_bucket_stays_there(throw):
    env = throw
    env.reset()
    bucket = torch.tensor([[0.7, -0.4, 0.5], [-0.7, -0.4, 0.3]])
    place_bucket(env, bucket)
    env.success_steps = 10 ** 6  # watch the cube settle: no success resets it
    try:
        turned = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.9238795, 0.3826834, 0.0, 0.0]])
        place_cube(env, bucket + torch.tensor([0.0, 0.0, 0.12]), turned,
                   lin_vel=torch.tensor([[1.5, 0.0, 0.0], [-1.0, -1.0, 0.0]]))  # into the walls
        for _ in range(40):
            _, _, reset, _ = env.step(torch.zeros(2, 23))
            assert not reset.any()
        rel = env.cube.root_pos - bucket
        # resting on the inner floor (0.0099 m) inside the inner wall (apothem 0.068 m there)
        assert torch.all(rel[:, :2].norm(dim=-1) < 0.068 - 0.025)
        assert torch.all((rel[:, 2] > 0.0099 + 0.024) & (rel[:, 2] < 0.0099 + 0.025 * math.sqrt(3)))
        assert env.near_goal().all()
    finally:
        env.success_steps = 5


def test_throw_success_fires_in_the_bucket_only_and_moves_it(throw):
    env = throw
    env.reset()
    bucket = torch.tensor([[0.7, -0.4, 0.5], [-0.6, 0.3, 0.6]])
    place_bucket(env, bucket)
    # env 0: resting in the bucket; env 1: just outside its wall, at the goal's height (0.15 m from the goal)
    cube = bucket + torch.tensor([[0.0, 0.0, 0.0349], [0.15, 0.0, 0.05]])
    place_cube(env, cube)
    env.near_goal_steps[:] = 4
    env.successes[:] = 0
    _, rew, _, _ = env.step(torch.zeros(2, 23))
    assert env.successes.tolist() == [1.0, 0.0]
    assert rew[0].item() > 1000.0 / 5 - 5.0 and rew[1].item() < 50.0
    assert not torch.equal(env.bucket_pos[0], bucket[0]) and torch.equal(env.bucket_pos[1], bucket[1])
    assert torch.allclose(env.goal_pos[0], env.bucket_pos[0] + torch.tensor([0.0, 0.0, 0.05]))
    assert torch.all((env.cube.root_pos[0] - CUBE_START).abs() <= START_NOISE + 1e-6)


def test_throw_without_a_bucket_is_a_one_line_error():
    with pytest.raises(ConfigError) as err:
        make("AllegroKukaThrow", num_envs=1, sim_device="cpu", rl_device="cpu", overrides=["~task.env.assets.bucket"])
    assert "env.assets.bucket is not set" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("task", ["AllegroKukaRegrasping", "AllegroKukaThrow"])
def test_train_py_two_iterations_then_test_mode(task, tmp_path):
    summary, evaluation = train_py_two_iterations_then_test(task, tmp_path, 2, ("task.env.episodeLength_s=0.1",))
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 16 * 2  # AllegroKukaPPO's horizon 16
    assert evaluation["episodes"] == 2
    assert evaluation["consecutive_successes"] >= 0.0
