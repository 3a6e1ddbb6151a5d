"""env.asset / env.assets ``linearDamping`` and ``angularDamping`` (sim/velocity_limit.py): a free body's velocity is
damped after every physics step as PhysX damps it, v * max(0, 1 - c dt), and a cap on its angular speed follows the
damping. Reference: MuJoCo C steps the same model from the same state and the rules are applied by formulas written
here after each of its steps."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from isaacgymenvs_mw.sim import Simulator, free_joint_damping, free_joint_speed_limits
from isaacgymenvs_mw.sim.request import body_damping
from isaacgymenvs_mw.utils.errors import ConfigError

XML = (Path(__file__).resolve().parents[1] / "assets" / "free_box_and_hinge.xml").read_text()
SUBSTEPS = 3
QVEL0 = np.array([[0.4, -0.2, 0.3, 1.0, -2.0, 6.0, 3.0], [0.0, 0.9, -0.5, -3.0, 0.5, 2.0, -4.0]])


def reference(qvel0: np.ndarray, steps: int, linear: float, angular: float, cap: float | None) -> np.ndarray:
    """MuJoCo C, then after each step: the free joint's linear velocity times max(0, 1 - linear dt), its angular
    velocity times max(0, 1 - angular dt), then the angular speed scaled down to ``cap``."""
    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    data.qvel[:] = qvel0
    dt = model.opt.timestep
    for _ in range(steps):
        mujoco.mj_step(model, data)
        data.qvel[0:3] *= max(0.0, 1.0 - linear * dt)
        data.qvel[3:6] *= max(0.0, 1.0 - angular * dt)
        speed = np.linalg.norm(data.qvel[3:6])
        if cap is not None and speed > cap:
            data.qvel[3:6] *= cap / speed
    return data.qvel.copy()


@pytest.mark.parametrize("linear, angular, cap", [(0.0, 0.5, None),    # IsaacGym's asset defaults, no cap
                                                  (2.0, 8.0, None),    # strong enough to see in 6 steps
                                                  (0.0, 0.5, 5.0),     # damping, then the cap
                                                  (0.0, 150.0, None)])  # c dt > 1: the factor stops at 0
def test_a_free_body_is_damped_as_mujoco_c_with_physx_damping_applied(linear, angular, cap):
    model = mujoco.MjModel.from_xml_string(XML)
    damping = free_joint_damping(model, {"": (linear, angular)})
    (free,) = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    assert damping == {free: (linear, angular)}  # the hinge is not a free joint: not damped
    caps = free_joint_speed_limits(model, {"": cap}) if cap is not None else {}
    sim = Simulator(model, 2, "cpu", substeps=SUBSTEPS, angular_speed_limits=caps, free_body_damping=damping)
    sim.qvel.copy_(torch.tensor(QVEL0, dtype=torch.float32))
    sim.simulate(), sim.simulate()
    for world in range(2):
        want = reference(QVEL0[world], 2 * SUBSTEPS, linear, angular, cap)
        np.testing.assert_allclose(sim.qvel[world].numpy(), want, rtol=2e-4, atol=2e-4)
    undamped = reference(QVEL0[0], 2 * SUBSTEPS, 0.0, 0.0, None)
    if angular * model.opt.timestep >= 1.0:
        assert np.abs(sim.qvel[0, 3:6].numpy()).max() < 1e-6  # no rotation left after a step
    elif linear > 0:
        assert np.linalg.norm(sim.qvel[0, 0:3].numpy()) < 0.95 * np.linalg.norm(undamped[0:3])


def test_without_damping_or_a_cap_nothing_is_applied():
    model = mujoco.MjModel.from_xml_string(XML)
    assert free_joint_damping(model, {}) == {}
    sim = Simulator(model, 1, "cpu", angular_speed_limits={}, free_body_damping={})
    assert sim.free_body_velocity is None


@pytest.mark.parametrize("name, value", [("angularDamping", -0.5), ("linearDamping", "slow"),
                                         ("angularDamping", True)])
def test_a_bad_damping_is_one_line_naming_the_key(name, value):
    with pytest.raises(ConfigError, match=rf"^env\.assets\.ball\.{name}={value!r} is invalid: give a number "
                                          r">= 0\.0$"):
        body_damping({name: value}, "env.assets.ball")


def test_the_damping_reaches_the_task_from_its_yaml():
    import isaacgymenvs_mw

    # BallBalance's YAML damps its ball (an env.assets entry with a free joint), and only it: the tray, the main
    # asset's free body, is not damped; with the key at 0 nothing is.
    task = isaacgymenvs_mw.make("BallBalance", num_envs=2, sim_device="cpu", rl_device="cpu")
    rules = task.sim.free_body_velocity
    assert rules is not None and len(rules.joints) == 1
    joint = rules.joints[0]
    assert int(task.sim.mj_model.jnt_type[joint]) == int(mujoco.mjtJoint.mjJNT_FREE)
    assert task.sim.mj_model.body(int(task.sim.mj_model.jnt_bodyid[joint])).name.startswith("ball")
    free = [j for j in range(task.sim.mj_model.njnt) if task.sim.mj_model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    assert len(free) == 2  # the tray's and the ball's
    undamped = isaacgymenvs_mw.make("BallBalance", num_envs=2, sim_device="cpu", rl_device="cpu",
                                    overrides=["task.env.assets.ball.angularDamping=0"])
    assert undamped.sim.free_body_velocity is None


def test_allegro_kuka_cube_keeps_isaacgyms_default_damping_and_cap():
    import isaacgymenvs_mw

    # IGE loads AllegroKuka's cube with IsaacGym's default asset options: angular damping 0.5 1/s and a 64 rad/s cap
    # on that free body, nothing on the arm and hand (fixed base) or the table.
    task = isaacgymenvs_mw.make("AllegroKuka", num_envs=2, sim_device="cpu", rl_device="cpu")
    m = task.sim.mj_model
    rules = task.sim.free_body_velocity
    free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    assert rules is not None and rules.joints == free and len(free) == 1
    assert m.body(int(m.jnt_bodyid[free[0]])).name.startswith("object")
    # the rule on a cube moving at 1 m/s and spinning at 40 and then 200 rad/s: damped by 1 - 0.5 dt (dt 1/120 s),
    # the faster spin then scaled down to 64 rad/s; the linear velocity is not damped (IsaacGym's default 0)
    dof = int(m.jnt_dofadr[free[0]])
    keep = 1.0 - 0.5 / 120.0
    for spin, want in ((40.0, 40.0 * keep), (200.0, 64.0)):
        qvel = task.sim.data.qvel.numpy()
        qvel[:, dof:dof + 6] = [1.0, 0.0, 0.0, 0.0, 0.0, spin]
        task.sim.data.qvel.assign(qvel)
        rules.launch()
        after = task.sim.data.qvel.numpy()[:, dof:dof + 6]
        np.testing.assert_allclose(after[:, 0], 1.0, rtol=1e-6)
        np.testing.assert_allclose(after[:, 5], want, rtol=1e-5)
