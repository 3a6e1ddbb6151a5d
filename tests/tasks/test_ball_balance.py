"""BallBalance (IsaacGymEnvs' task): the model against IGE's figures, the leg force-sensor observations against MuJoCo C,
reward, failure rule, resets, actions, training.

IGE's figures (isaacgymenvs/tasks/ball_balance.py, _create_balance_bot_asset and _create_envs) are restated here, and
the masses and the leg geometry are computed from them independently of the MJCF.
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
from isaacgymenvs_mw.tasks.ball_balance import ball_dropped, compute_ball_balance_reward
from isaacgymenvs_mw.utils.errors import ConfigError

ASSETS = Path(__file__).resolve().parents[2] / "assets" / "mjcf"
# IGE's figures
TRAY_R, TRAY_T, TRAY_RHO = 0.5, 0.02, 100.0
LEG_R, LEG_RHO = 0.02, 1000.0
OUTER = TRAY_R - 0.1                       # leg_outer_offset
LEG_L = OUTER - 2 * LEG_R                  # leg_length
INNER = OUTER - LEG_L / math.sqrt(2)       # leg_inner_offset
TRAY_H = LEG_L * math.sqrt(2) + 2 * LEG_R + 0.5 * TRAY_T
ANGLES = [0.0, 2 * math.pi / 3, 4 * math.pi / 3]
BALL_R, BALL_RHO = 0.1, 200.0
SENSORS = [f"leg{i}_{kind}" for kind in ("force", "torque") for i in range(3)]


def capsule_mass(radius: float, length: float, density: float) -> float:
    return density * (math.pi * radius ** 2 * length + 4.0 / 3.0 * math.pi * radius ** 3)


def test_model_dimensions_masses_and_limits_match_ige_figures():
    m = mujoco.MjModel.from_xml_path(str(ASSETS / "ball_balance.xml"))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert m.body_mass[m.body("tray").id] == pytest.approx(math.pi * TRAY_R ** 2 * TRAY_T * TRAY_RHO, rel=1e-6)
    assert d.xpos[m.body("tray").id][2] == pytest.approx(TRAY_H, abs=1e-6)
    for i, a in enumerate(ANGLES):
        for link in ("upper", "lower"):
            assert m.body_mass[m.body(f"{link}_leg{i}").id] == pytest.approx(capsule_mass(LEG_R, LEG_L, LEG_RHO),
                                                                             rel=1e-6)
        axis = np.array([math.cos(a), math.sin(a)])
        hip = d.xanchor[m.joint(f"upper_leg_joint{i}").id]   # on the tray's rim, under it
        knee = d.xanchor[m.joint(f"lower_leg_joint{i}").id]
        lower = m.body(f"lower_leg{i}").id
        foot = d.xpos[lower] + d.xmat[lower].reshape(3, 3) @ [0.0, 0.0, 0.5 * LEG_L]
        np.testing.assert_allclose(hip, [*(OUTER * axis), TRAY_H - LEG_R - 0.5 * TRAY_T], atol=1e-5)
        np.testing.assert_allclose(knee, [*(INNER * axis), hip[2] - LEG_L / math.sqrt(2)], atol=1e-5)
        np.testing.assert_allclose(foot, [*(OUTER * axis), LEG_R], atol=1e-5)   # IGE's attractor target
        np.testing.assert_allclose(m.eq_data[m.equality(f"foot_pin{i}").id, 3:6], foot, atol=1e-5)  # pinned there
        # Hinge axes: each leg turns in its own vertical plane.
        for joint in (f"upper_leg_joint{i}", f"lower_leg_joint{i}"):
            np.testing.assert_allclose(d.xaxis[m.joint(joint).id], [-math.sin(a), math.cos(a), 0.0], atol=1e-5)
        assert np.degrees(m.jnt_range[m.joint(f"upper_leg_joint{i}").id]) == pytest.approx([-45, 45])
        assert np.degrees(m.jnt_range[m.joint(f"lower_leg_joint{i}").id]) == pytest.approx([-70, 90])
    # IGE's dof order, with the actuated dofs 1, 3, 5 the knees.
    assert [m.joint(j).name for j in range(1, 7)] == [f"{k}_leg_joint{i}" for i in range(3) for k in ("upper", "lower")]
    assert [m.sensor(s).name for s in range(m.nsensor)] == ["leg0_force", "leg1_force", "leg2_force", "leg0_torque",
                                                            "leg1_torque", "leg2_torque"]
    ball = mujoco.MjModel.from_xml_path(str(ASSETS / "ball_balance_ball.xml"))
    assert ball.geom_size[0, 0] == BALL_R
    assert ball.body_mass[1] == pytest.approx(4.0 / 3.0 * math.pi * BALL_R ** 3 * BALL_RHO, rel=1e-6)


@pytest.fixture(scope="module")
def env():
    return make("BallBalance", num_envs=2)


def drop_ball(env, xy=((0.0, 0.0), (0.15, -0.1))):
    """Both worlds in the initial pose, the ball resting just above the tray at ``xy``, targets at rest."""
    n = env.num_envs
    mask = torch.ones(n, dtype=torch.bool)
    env.sim.reset_worlds(mask)
    pos = torch.tensor([[x, y, TRAY_H + 0.5 * TRAY_T + BALL_R + 0.005] for x, y in xy])
    env.sim.write_state(mask, root_pos=pos, root_quat=torch.tensor([[1.0, 0, 0, 0]] * n),
                        root_lin_vel=torch.zeros(n, 3), root_ang_vel=torch.zeros(n, 3), asset="ball")
    env.dof_position_targets.zero_()
    env.fresh.zero_()
    env.reset_buf.zero_()


def test_tripod_holds_the_ball_on_its_pinned_feet(env):
    """Zero actions for 1 s: the ball settles on the tray and stays, the feet stay on their pins."""
    drop_ball(env)
    for _ in range(100):
        _, _, reset, _ = env.step(torch.zeros(2, 3))
        assert not reset.any()
    top = TRAY_H + 0.5 * TRAY_T
    np.testing.assert_allclose(env.ball.root_pos[:, 2].numpy(), top + BALL_R, atol=5e-3)
    assert float(env.sim.equality_violation()[0].max()) < 1e-3
    assert float(env.sim.dof_pos.abs().max()) < 0.02  # the drives hold the initial pose under the load


def test_leg_sensor_observations_equal_mujoco_c(env):
    """Observation columns 12:24 (IGE's layout: each leg's force x, then torques x, y, z, all / 20) against MuJoCo C's
    sensordata at the state the last physics step started from (the policy step's last of ``controlFrequencyInv``:
    MuJoCo C steps the others from the policy step's start), read by sensor name; before the clamp to
    clipObservations (``obs_buf``: these loads reach 300 N, 15 after the scale).

    Within 0.6 N (0.03 after the scale) plus 1 %: MuJoCo Warp's float32 forward pass of this stiff pinned chain
    (kp 4000 knees, three connect constraints) puts the sensed forces up to 0.4 N off MuJoCo C's float64 ones on
    these states, where the largest reach 300 N, whether C's solver stops at Newton's second iteration or CG's
    twenty-sixth; the unconstrained arm of test_sensors.py agrees to 1e-4. A wrong leg, axis or sign is off by far
    more (the legs' readings differ by tens of N)."""
    drop_ball(env)
    gen = torch.Generator().manual_seed(1)
    for _ in range(20):  # the ball lands, the legs move: loaded, asymmetric states
        env.step(0.3 * (torch.rand(2, 3, generator=gen) * 2 - 1))
    m = env.sim.mj_model
    for _ in range(3):
        before = [t.clone().double().numpy() for t in (env.sim.qpos, env.sim.qvel)]
        _, _, reset, _ = env.step(0.3 * (torch.rand(2, 3, generator=gen) * 2 - 1))
        assert not reset.any()
        ctrl = env.sim.ctrl.double().numpy()  # the targets this step ran with
        for w in range(2):
            data = mujoco.MjData(m)
            data.qpos[:], data.qvel[:], data.ctrl[:] = before[0][w], before[1][w], ctrl[w]
            for _ in range(env.control_freq_inv - 1):
                mujoco.mj_step(m, data)
            mujoco.mj_forward(m, data)
            read = {name: data.sensordata[m.sensor(name).adr[0]:][:3] for name in SENSORS}
            expected = np.concatenate([[read[f"leg{i}_force"][0] for i in range(3)]]
                                      + [[read[f"leg{i}_torque"][k] for i in range(3)] for k in range(3)]) / 20.0
            assert np.abs(expected).max() > 0.1  # loaded: the comparison is not of zeros
            np.testing.assert_allclose(env.obs_buf[w, 12:24].double().numpy(), expected, rtol=1e-2, atol=0.03)


def adversarial_actions(step: int, n: int, gen: torch.Generator, held: torch.Tensor) -> torch.Tensor:
    """Knee target rates at full scale: for 100 steps bang-bang every 5 steps with leg 1 against legs 0 and 2, then
    random signs held for 10 steps (``held``, updated in place), per world and knee."""
    if step < 100:
        return torch.tensor([1.0, -1.0, 1.0]).expand(n, 3) * (1.0 if (step // 5) % 2 == 0 else -1.0)
    if step % 10 == 0:
        held.copy_(torch.where(torch.rand(n, 3, generator=gen) < 0.5, -1.0, 1.0))
    return held


def test_full_scale_knee_actions_keep_every_foot_on_its_pin():
    """32 worlds, 300 policy steps of full-scale actions (bang-bang, random signs held for 10 steps): no world blows up,
    and no foot leaves its pin by more than 5 cm (the blow-up reset is at 0.1 m). At IGE's single 0.01 s physics step
    with MuJoCo's default pin stiffness (solref 0.02) this pattern pulled feet 0.1-0.15 m off their pins, in MuJoCo C
    as in MuJoCo Warp: 49 of these 32 x 300 env steps reset a blown-up world."""
    torch.manual_seed(0)  # the ball's resets
    n = 32
    env = make("BallBalance", num_envs=n)
    gen = torch.Generator().manual_seed(0)
    held = torch.ones(n, 3)
    blown_up, worst = 0, 0.0
    for step in range(300):
        _, _, _, extras = env.step(adversarial_actions(step, n, gen, held))
        blown_up += int(extras["nonfinite_resets"].sum())
        worst = max(worst, float(env.sim.equality_violation()[0].max()))
    assert blown_up == 0
    assert worst < 0.05


def test_reward_matches_ige_formula_on_constructed_states():
    cases = [((0.0, 0.0, 0.7), (0.0, 0.0, 0.0)), ((0.3, -0.2, 0.67), (0.5, 0.1, -0.2)),
             ((-0.45, 0.1, 1.9), (2.0, -1.0, -5.0)), ((0.0, 0.6, 0.1), (0.0, 0.0, 0.0))]
    got = compute_ball_balance_reward(torch.tensor([c[0] for c in cases]), torch.tensor([c[1] for c in cases]))
    for k, ((x, y, z), (vx, vy, vz)) in enumerate(cases):
        dist = math.sqrt(x * x + y * y + (z - 0.7) ** 2)
        speed = math.sqrt(vx * vx + vy * vy + vz * vz)
        assert got[k].item() == pytest.approx((1 / (1 + dist)) * (1 / (1 + speed)), rel=1e-6)
    assert got[0].item() == pytest.approx(1.0)


def test_failure_rule_is_iges():
    z = torch.tensor([0.1, 0.149, 0.151, 0.67, 2.0])
    pos = torch.stack((torch.zeros(5), torch.zeros(5), z), dim=1)
    assert ball_dropped(pos).tolist() == [True, True, False, False, False]


def test_reset_ranges_are_iges(env):
    mask = torch.ones(2, dtype=torch.bool)
    for _ in range(30):
        env.sim.qvel.fill_(0.3)
        env.dof_position_targets.fill_(0.2)
        env.reset_idx(mask)
        pos, vel = env.ball.root_pos, env.ball.root_lin_vel
        dist = torch.linalg.norm(pos[:, :2], dim=1)
        assert torch.all((dist >= 0.001 - 1e-6) & (dist <= 0.5 + 1e-6)) and torch.all((pos[:, 2] >= 1) & (pos[:, 2] <= 2))
        inward = -(vel[:, :2] * pos[:, :2]).sum(dim=1) / dist  # speed towards the axis
        speed = torch.linalg.norm(vel[:, :2], dim=1)
        assert torch.allclose(inward, speed, atol=1e-5)  # straight at the axis, never away
        assert torch.all(speed <= 5.0 * (dist - 0.001) / 0.499 + 1e-5)
        assert torch.all(vel[:, 2] == -5.0) and torch.all(env.ball.root_ang_vel == 0)
        assert torch.all(env.sim.dof_pos == 0) and torch.all(env.sim.dof_vel == 0)
        np.testing.assert_allclose(env.sim.root_pos.numpy(), [[0.0, 0.0, TRAY_H]] * 2, atol=1e-6)
        assert torch.all(env.sim.root_lin_vel == 0) and torch.all(env.dof_position_targets == 0) and env.fresh.all()


def test_actions_move_knee_targets_at_action_speed_scale_and_not_on_an_episodes_first_step(env):
    drop_ball(env)
    env.fresh[0] = True  # world 0 starts an episode: IGE applies no action on that step
    env.step(torch.ones(2, 3))
    assert env.dof_position_targets[0].tolist() == [0.0, 0.0, 0.0]
    assert env.dof_position_targets[1].tolist() == pytest.approx([0.01 * 20] * 3)  # dt x actionSpeedScale
    assert torch.equal(env.sim.ctrl, env.dof_position_targets)
    for _ in range(10):
        env.step(-torch.ones(2, 3))
    assert env.dof_position_targets[1].tolist() == pytest.approx([math.radians(-70)] * 3)  # clamped to the range


def test_one_training_iteration_then_test_mode(tmp_path, run_args):
    train_one_iteration_then_test("BallBalance", tmp_path / "runs", run_args, ["task.env.episodeLength_s=0.1"])


def test_an_asset_without_the_leg_sensors_is_a_one_line_error_naming_the_key(tmp_path):
    xml = (ASSETS / "ball_balance.xml").read_text()
    start, end = xml.index("  <sensor>"), xml.index("</sensor>") + len("</sensor>\n")
    (tmp_path / "mjcf").mkdir()
    (tmp_path / "mjcf" / "ball_balance.xml").write_text(xml[:start] + xml[end:])
    with pytest.raises(ConfigError, match=r"^task\.env\.legForceSensors: 'leg0_force' is not a sensor of the model; "
                                          r"its sensors: \[\]$"):
        make("BallBalance", num_envs=1, overrides=(f"task.env.asset.assetRoot={tmp_path}",))
    with pytest.raises(ConfigError, match=r"^task\.env\.legTorqueSensors: 'leg2_torq' is not a sensor of the model; "
                                          r"its sensors: \['leg0_force', [^\n]*\]$"):
        make("BallBalance", num_envs=1, overrides=("task.env.legTorqueSensors=[leg0_torque,leg1_torque,leg2_torq]",))


def test_the_best_checkpoint_follows_the_fraction_of_episodes_that_keep_the_ball_not_the_reward(tmp_path):
    from isaacgymenvs_mw.learning.best_checkpoint import BestCheckpoint
    from isaacgymenvs_mw.learning.vecenv import success_metric_key

    env = make("BallBalance", num_envs=1)
    best = BestCheckpoint(tmp_path, "auto", success_metric_key(env))  # sweep_metric=auto, as shipped
    # two saved checkpoints: the second has the higher reward but keeps the ball in fewer episodes
    history = [{"iteration": 1, "timeout_fraction": 0.98, "mean_episode_reward": 300.0}]
    (tmp_path / "model_1.pt").write_bytes(b"iteration 1")
    best.consider(history, str(tmp_path / "model_1.pt"))
    history.append({"iteration": 2, "timeout_fraction": 0.0, "mean_episode_reward": 1000.0})
    (tmp_path / "model_2.pt").write_bytes(b"iteration 2")
    best.consider(history, str(tmp_path / "model_2.pt"))
    assert best.summary()["metric"] == "timeout_fraction" and best.iteration == 1
    assert best.summary()["chosen_by"] == "declared success metric"
    assert (tmp_path / "model_best.pt").read_bytes() == b"iteration 1"
