"""AllegroHand (issue 34): the rotation distance against the angle of the relative rotation matrix, the reward
against a numpy transcription of IsaacGymEnvs' compute_hand_reward written here, the success / new-goal / episode
logic and IGE's consecutive_successes average on constructed sequences, the fall, the actions' joint targets, the
observation sizes of the three types, the cube resting in the open hand for 2 s (MuJoCo C agrees), the one-line
errors, and one training iteration plus test mode on the CPU."""

from __future__ import annotations

import json
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from in_hand_reference import assert_reward_is_the_reference, place_cube, reference_reward
from isaacgymenvs_mw import make
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.tasks.base.metrics import OUTCOME, RUNNING
from isaacgymenvs_mw.tasks.in_hand import hand_terms, random_rotation
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import rotation_distance

ALLEGRO = Path(__file__).resolve().parents[2] / "assets" / "mjcf" / "allegro_hand.xml"
CPU = dict(sim_device="cpu", rl_device="cpu", headless=True)
IDENTITY = [1.0, 0.0, 0.0, 0.0]


def matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a (w, x, y, z) quaternion, by MuJoCo C."""
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, q / np.linalg.norm(q))
    return out.reshape(3, 3)


def random_quats(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_rotation_distance_is_the_angle_of_the_relative_rotation():
    rng = np.random.default_rng(0)
    a = random_quats(rng, 300)
    # b: a turned by known angles (0 ... pi) about random axes, half of them with the sign of q flipped
    axes = rng.normal(size=(300, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(0.0, math.pi, 300)
    b = np.empty_like(a)
    for i in range(300):
        turn = np.concatenate([[math.cos(angles[i] / 2)], math.sin(angles[i] / 2) * axes[i]])
        mujoco.mju_mulQuat(b[i], turn, a[i])
    b[::2] *= -1.0
    got = rotation_distance(torch.tensor(a), torch.tensor(b)).numpy()
    # independent: the angle of R_a R_b^T from its trace
    ref = [math.acos(np.clip((np.trace(matrix(x) @ matrix(y).T) - 1.0) / 2.0, -1.0, 1.0)) for x, y in zip(a, b)]
    np.testing.assert_allclose(got, ref, atol=2e-6)
    np.testing.assert_allclose(got, angles, atol=2e-6)


def compute_hand_reward(terms: dict[str, torch.Tensor], actions: torch.Tensor, dist_scale: float = -10.0,
                        rot_scale: float = 1.0, rot_eps: float = 0.1, action_penalty_scale: float = -0.0002,
                        reach_goal_bonus: float = 250.0, fall_penalty: float = 0.0) -> torch.Tensor:
    """IsaacGymEnvs' compute_hand_reward (without maxConsecutiveSuccesses' time-limit penalty) in torch, on the task's
    hand_terms: checked here against the plain-Python transcription, as the task's reward terms are below."""
    reward = dist_scale * terms["goal_dist"] + rot_scale / (terms["rot_dist"] + rot_eps)
    reward = reward + action_penalty_scale * torch.sum(actions ** 2, dim=-1)
    reward = reward + reach_goal_bonus * terms["reached"].float()
    return reward + fall_penalty * terms["fell"].float()


def test_reward_equals_ige_formula_on_constructed_states():
    rng = np.random.default_rng(1)
    n = 400
    goal_pos = np.tile([0.0, -0.2, 0.52], (n, 1))
    obj_pos = goal_pos + rng.normal(0.0, 0.12, (n, 3))  # some beyond the 0.24 m fall distance
    goal_quat = random_quats(rng, n)
    obj_quat = random_quats(rng, n)
    obj_quat[: n // 4] = goal_quat[: n // 4] + rng.normal(0.0, 0.02, (n // 4, 4))  # a quarter near the goal
    obj_quat /= np.linalg.norm(obj_quat, axis=1, keepdims=True)
    actions = rng.uniform(-1.0, 1.0, (n, 16))
    t = lambda x: torch.tensor(x, dtype=torch.float64)
    terms = hand_terms(t(obj_pos), t(obj_quat), t(goal_pos), t(goal_quat), 0.1, 0.24)
    got = compute_hand_reward(terms, t(actions), fall_penalty=-5.0)
    ref = [reference_reward(*v, fall_penalty=-5.0) for v in zip(obj_pos, obj_quat, goal_pos, goal_quat, actions)]
    np.testing.assert_allclose(got.numpy(), [r for r, _, _ in ref], rtol=1e-9, atol=1e-9)
    assert terms["reached"].tolist() == [s for _, s, _ in ref]
    assert terms["fell"].tolist() == [f for _, _, f in ref]
    assert 20 < terms["reached"].sum() < n - 20 and 10 < terms["fell"].sum() < n - 10  # both branches exercised


def test_random_rotation_is_ige_draw_x_then_y():
    torch.manual_seed(3)
    q = random_rotation(2000, "cpu").double()
    np.testing.assert_allclose(torch.linalg.norm(q, dim=1).numpy(), 1.0, atol=1e-6)
    # R_x(a) R_y(b) maps the y axis to R_x(a) y, which has no x component, whatever b; the z axis to one whose x
    # component is sin(b) with |b| <= pi (so its sign varies, unlike a uniform-in-one-half draw).
    mats = np.stack([matrix(v) for v in q.numpy()])
    np.testing.assert_allclose(mats[:, 0, 1], 0.0, atol=1e-6)
    assert (mats[:, 0, 2] > 0.5).any() and (mats[:, 0, 2] < -0.5).any()


@pytest.fixture(scope="module")
def env():
    return make("AllegroHand", num_envs=3, seed=0, **CPU,
                overrides=["task.env.resetPositionNoise=0.0", "task.env.fallPenalty=-7.0"])


def test_a_success_pays_the_bonus_draws_a_new_goal_and_the_episode_goes_on(env):
    env.reset()
    goals = env.goal_quat.clone()
    start = env.object_start_pos.numpy()
    # env 0 at its goal orientation, env 1 turned 0.5 rad from it, env 2 fallen 0.3 m below the goal position;
    # all start at rest in the air above the hand, so one 1/30 s step does not turn them.
    turn = np.array([math.cos(0.25), math.sin(0.25), 0.0, 0.0])
    quat1 = np.zeros(4)
    mujoco.mju_mulQuat(quat1, turn, goals[1].numpy().astype(float))
    pos = np.stack([start + [0, 0, 0.03], start + [0, 0, 0.03], start - [0, 0, 0.34]])
    place_cube(env, pos, np.stack([goals[0].numpy(), quat1, goals[2].numpy()]))
    env.progress_buf[:] = 5
    _, rew, done, extras = env.step(torch.zeros(3, 16))
    assert done.tolist() == [0, 0, 1]
    assert extras["time_outs"].tolist() == [False, False, False]  # the fall is a failure, not a time-out
    assert env.successes.tolist() == [1.0, 0.0, 0.0]
    assert not torch.allclose(env.goal_quat[0], goals[0])  # a new goal for env 0, in this step's observation
    assert torch.equal(env.goal_quat[1], goals[1])
    np.testing.assert_allclose(env.sim.mocap_quat[:, env.goal_marker].numpy(), env.goal_quat.numpy())
    obs_goal = env.observations.obs_layout.columns(["goal_quat"], "test")
    np.testing.assert_allclose(env.obs_buf[0, obs_goal].numpy(), env.goal_quat[0].numpy(), atol=1e-6)
    assert env.progress_buf.tolist() == [6, 6, 0]
    sums = env.rewards.names
    assert set(sums) == {"dist", "rot", "action_penalty", "reach_goal", "fall"}
    # the reward of the step: the reference formula on the state the step ended in (IsaacGymEnvs' own, unscaled)
    assert rew[0].item() > 250  # the reach-goal bonus
    assert rew[1].item() < 10


def test_reward_terms_sum_to_the_plain_function(env):
    env.reset()
    rng = np.random.default_rng(4)
    start = env.object_start_pos.numpy()
    pos = start + rng.normal(0.0, 0.05, (3, 3))
    quat = random_quats(rng, 3)
    quat[0] = env.goal_quat[0].numpy()
    assert_reward_is_the_reference(env, pos, quat, rng.uniform(-1, 1, (3, 16)), fall_penalty=-7.0)


def test_consecutive_successes_is_ige_running_average_over_resetting_envs():
    env = make("AllegroHand", num_envs=2, seed=0, **CPU, overrides=["task.env.maxConsecutiveSuccesses=1"])
    env.reset()
    assert env.consecutive_successes.item() == 0.0
    start = env.object_start_pos.numpy()
    # env 0 reaches its goal: with maxConsecutiveSuccesses 1 its episode ends as a success (bootstrapped)
    env.goal_quat[1] = torch.tensor([0.0, 1.0, 0.0, 0.0])  # env 1's cube (identity) is pi from its goal
    place_cube(env, np.stack([start + [0, 0, 0.03]] * 2), np.stack([env.goal_quat[0].numpy(), IDENTITY]))
    _, _, done, extras = env.step(torch.zeros(2, 16))
    assert done.tolist() == [1, 0]
    assert extras["successes"].tolist() == [True, False] and extras["time_outs"].tolist() == [True, False]
    assert env.metrics.recorded(OUTCOME)["consecutive_successes"].tolist() == [1.0, 0.0]
    # one env reset with 1 success: cs = 0.1 x 1 / 1 + 0.9 x 0
    assert env.consecutive_successes.item() == pytest.approx(0.1)
    assert env.metrics.recorded(RUNNING)["consecutive_successes"].item() == pytest.approx(0.1)
    # env 1 falls with no success: cs = 0.1 x 0 + 0.9 x 0.1
    place_cube(env, np.stack([start + [0, 0, 0.03], start - [0, 0, 0.34]]),
               np.stack([IDENTITY, IDENTITY]))
    env.goal_quat[0] = torch.tensor([0.0, 1.0, 0.0, 0.0])  # env 0 far from its goal: no success
    _, _, done, _ = env.step(torch.zeros(2, 16))
    assert done.tolist() == [0, 1]
    assert env.consecutive_successes.item() == pytest.approx(0.09)
    # a step without resets leaves it unchanged
    env.step(torch.zeros(2, 16))
    assert env.consecutive_successes.item() == pytest.approx(0.09)


def test_absolute_actions_span_the_joint_ranges_and_relative_ones_move_the_targets():
    env = make("AllegroHand", num_envs=2, seed=0, **CPU)
    env.reset()
    lo, hi = env.dof_lower, env.dof_upper
    env.pre_physics_step(torch.stack([-torch.ones(16), torch.ones(16)]))
    np.testing.assert_allclose(env.sim.ctrl[0, :16].numpy(), lo.numpy(), atol=1e-6)
    np.testing.assert_allclose(env.sim.ctrl[1, :16].numpy(), hi.numpy(), atol=1e-6)
    m = env.sim.mj_model
    np.testing.assert_allclose(lo.numpy(), [m.joint(j).range[0] for j in env.sim.dof_names])
    assert env.sim.dof_names[0] == "index_joint_0" and env.sim.dof_names[-1] == "thumb_joint_3"

    rel = make("AllegroHand", num_envs=1, seed=0, **CPU, overrides=["task.env.useRelativeControl=True"])
    rel.reset()
    before = rel.prev_targets.clone()
    action = torch.full((1, 16), 0.5)
    rel.pre_physics_step(action)
    # IGE: dofSpeedScale x its sim dt (1/60 s) x action, clamped to the range
    expected = torch.clamp(before + 20.0 * (1.0 / 60.0) * action, rel.dof_lower, rel.dof_upper)
    np.testing.assert_allclose(rel.sim.ctrl[0, :16].numpy(), expected[0].numpy(), atol=1e-6)


def test_reset_draws_hand_joints_and_cube_as_ige():
    env = make("AllegroHand", num_envs=64, seed=2, **CPU)
    env.reset()
    q = env.sim.dof_pos
    lo, hi = env.dof_lower, env.dof_upper
    assert bool(((q >= lo - 1e-6) & (q <= hi + 1e-6)).all())
    # 0.2 x a point of the range (thumb_joint_0 clamped up to its lower limit 0.279)
    assert bool((q <= 0.2 * hi + 1e-6).all()) and bool((q >= torch.maximum(0.2 * lo, lo) - 1e-6).all())
    np.testing.assert_allclose(env.prev_targets.numpy(), q.numpy(), atol=1e-6)
    offset = env.cube.root_pos - env.object_start_pos
    assert float(offset.abs().max()) <= 0.01 + 1e-6 and float(offset.abs().max()) > 0.005
    np.testing.assert_allclose(env.object_start_pos.numpy(), [0.0, -0.2, 0.56], atol=1e-6)
    np.testing.assert_allclose(env.goal_pos[0].numpy(), [0.0, -0.2, 0.52], atol=1e-6)
    np.testing.assert_allclose(env.sim.mocap_pos[0, env.goal_marker].numpy(), [-0.2, -0.26, 0.64], atol=1e-6)


@pytest.mark.parametrize("kind, size", [("full_no_vel", 50), ("full", 72), ("full_state", 88)])
def test_observation_types_have_ige_sizes(kind, size):
    env = make("AllegroHand", num_envs=1, seed=0, **CPU, overrides=[f"task.env.observationType={kind}"])
    assert env.num_obs == size and env.num_states == 0
    obs = env.reset()["obs"]
    assert obs.shape == (1, size)


def test_asymmetric_critic_sees_full_state():
    env = make("AllegroHand", num_envs=2, seed=0, **CPU,
               overrides=["task.env.observationType=full_no_vel", "task.env.asymmetric_observations=True"])
    out = env.reset()
    assert out["obs"].shape == (2, 50) and out["states"].shape == (2, 88)
    force = env.observations.state_layout.columns(["dof_force"], "test")
    env.step(torch.ones(2, 16))
    # the drives' torques x 10, from MuJoCo Warp's actuator forces (0.5 N m at most)
    np.testing.assert_allclose(env.states_buf[:, force].numpy(), 10.0 * env.sim.actuator_force[:, :16].numpy(),
                               atol=1e-5)


def test_cube_rests_in_the_open_hand_for_two_seconds_and_mujoco_c_agrees():
    """Zero relative actions hold the hand at its reset pose (joints at 0, thumb_joint_0 at its lower limit): the
    dropped cube settles on the palm and fingers and stays there for 2 s; MuJoCo C from the same state agrees."""
    env = make("AllegroHand", num_envs=1, seed=0, **CPU,
               overrides=["task.env.useRelativeControl=True", "task.env.resetDofPosRandomInterval=0.0",
                          "task.env.resetPositionNoise=0.0"])
    env.reset()
    m = env.sim.mj_model
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:], d.ctrl[:] = env.sim.qpos[0].numpy(), env.sim.qvel[0].numpy(), env.sim.ctrl[0].numpy()
    warp_path, c_path = [], []
    for _ in range(60):  # 2 s of 30 Hz policy steps
        _, _, done, _ = env.step(torch.zeros(1, 16))
        assert done.item() == 0
        for _ in range(env.control_freq_inv):
            mujoco.mj_step(m, d)
        warp_path.append(env.cube.root_pos[0].numpy().copy())
        c_path.append(d.qpos[16:19].copy())
    warp_path, c_path = np.array(warp_path), np.array(c_path)
    settled = warp_path[15:]  # after 0.5 s
    assert np.ptp(settled, axis=0).max() < 0.002  # at rest: it moves less than 2 mm in the last 1.5 s
    assert settled[-1, 2] > 0.52  # on the hand (the palm face is below 0.52 m; a cube that slid off is far lower)
    assert np.abs(warp_path - c_path).max() < 0.003


@pytest.mark.parametrize("override, message", [
    ("task.env.observationType=openai",
     r"^task\.env\.observationType='openai' is invalid: choose one of \['full_no_vel', 'full', 'full_state'\]$"),
    ("task.env.successTolerance=0.0", r"^task\.env\.successTolerance=0\.0 is invalid: give an angle > 0 \(rad\)$"),
    ("task.env.successTolerance=-0.1", r"^task\.env\.successTolerance=-0\.1 is invalid: give an angle > 0 \(rad\)$"),
    ("task.env.assets.object.fixBaseLink=True",
     r"^task\.env\.assets\.object\.fixBaseLink=True: the cube must float \(a free joint\); set fixBaseLink: False$"),
])
def test_bad_settings_are_one_line_errors_naming_the_key(override, message):
    with pytest.raises(ConfigError, match=message):
        make("AllegroHand", num_envs=1, **CPU, overrides=[override])


def test_training_one_iteration_then_test_mode_reports_consecutive_successes(tmp_path, run_args):
    cfg = compose_config(["task=AllegroHand", "num_envs=4", "max_iterations=1", "task.env.episodeLength_s=0.2",
                          "train.runner.num_steps_per_env=8", *run_args])
    summary = run(cfg)
    assert summary["iterations"] == 1
    assert "consecutive_successes" in summary and "successes" in summary
    run_dir = [p for p in (tmp_path / "runs" / "AllegroHand").iterdir() if p.is_dir()][0]
    eval_cfg = compose_config(["task=AllegroHand", "num_envs=4", "test=True", f"checkpoint={run_dir / 'model_1.pt'}",
                               "task.env.episodeLength_s=0.2", *run_args])
    result = run(eval_cfg)
    written = json.loads((run_dir / "eval.json").read_text())
    assert written["consecutive_successes"] == result["consecutive_successes"] and written["episodes"] == 4
    assert 0.0 <= written["consecutive_successes"] <= 6.0


def test_the_hand_is_welded_at_base_init_state_and_the_goal_is_a_mocap_body():
    """env.baseInitState places a fixed base: the fingertips at the hand's zero pose equal MuJoCo C's for the
    hand file with its palm moved to IGE's pose by hand."""
    env = make("AllegroHand", num_envs=1, seed=0, **CPU)
    mask = torch.ones(1, dtype=torch.bool)
    env.sim.write_state(mask, dof_pos=torch.zeros(1, 16), refresh=True)
    spec = mujoco.MjSpec.from_file(str(ALLEGRO))
    spec.body("palm").pos = [0.0, 0.0, 0.5]
    spec.body("palm").quat = [0.257551, 0.283045, 0.68333, -0.621782]
    m = spec.compile()
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    for tip in ("index_tip", "middle_tip", "ring_tip", "thumb_tip"):
        np.testing.assert_allclose(env.sim.site_xpos[0, env.sim.site_id(tip)].numpy(), d.site(tip).xpos, atol=1e-6)
    assert env.sim.mj_model.body("goal/cube").mocapid[0] == env.goal_marker == 0
    with pytest.raises(ValueError, match=r"^body 'object/cube' is not a mocap body; mocap bodies: \['goal/cube'\]$"):
        env.sim.mocap_index("object/cube")


def test_longest_episode_counts_the_time_limits_successes_restart():
    """With maxConsecutiveSuccesses each success restarts the time limit, so an episode can last that many limits
    and one more; test mode (evaluation.evaluate) waits that long, or it would count a long episode's successes as 0."""
    env = make("AllegroHand", num_envs=2, seed=0, **CPU,
               overrides=["task.env.maxConsecutiveSuccesses=3", "task.env.episodeLength_s=0.2"])
    assert env.max_episode_length == 6 and env.longest_episode() == 24
    plain = make("AllegroHand", num_envs=1, seed=0, **CPU, overrides=["task.env.episodeLength_s=0.2"])
    assert plain.longest_episode() == 6


def test_the_shipped_randomisation_block_applies_when_turned_on():
    """task.randomize=True: the YAML's IGE block (cube mass, friction, drive gains, noise, delay) draws per world."""
    env = make("AllegroHand", num_envs=4, seed=0, **CPU, overrides=["task.task.randomize=True"])
    env.reset()
    mass = env.sim.model_field("body_mass")[:, env.sim.body_id("object/cube")]
    nominal = env.sim.mj_model.body("object/cube").mass[0]
    assert bool(((mass >= 0.5 * nominal - 1e-6) & (mass <= 1.5 * nominal + 1e-6)).all())
    assert float(mass.max() - mass.min()) > 1e-3  # drawn per world
    kp = env.sim.model_field("actuator_gainprm")[:, :16, 0]
    assert bool(((kp >= 0.75 * 3.0 - 1e-6) & (kp <= 1.5 * 3.0 + 1e-6)).all()) and float(kp.std()) > 1e-3
    _, rew, _, _ = env.step(torch.zeros(4, 16))
    assert bool(torch.isfinite(rew).all())
