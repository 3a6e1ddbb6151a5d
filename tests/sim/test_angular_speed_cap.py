"""env.asset / env.assets ``maxAngularVelocity`` (sim/velocity_limit.py): a free body's angular speed is capped after
every physics step, direction kept, as PhysX caps it. Reference: MuJoCo C steps the same model from the same state
and the cap is applied by a formula written here, w * min(1, limit / |w|), after each of its steps."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from isaacgymenvs_mw.sim import Simulator, free_joint_speed_limits
from isaacgymenvs_mw.sim.request import max_angular_velocity
from isaacgymenvs_mw.utils.errors import ConfigError

XML = (Path(__file__).resolve().parents[1] / "assets" / "free_box_and_hinge.xml").read_text()
SUBSTEPS, LIMIT = 3, 5.0
QVEL0 = np.array([[0.1, -0.2, 0.3, 1.0, -2.0, 6.0, 3.0], [0.0, 0.4, 0.0, -3.0, 0.5, 2.0, -4.0]])


def capped(w: np.ndarray, limit: float) -> np.ndarray:
    speed = np.linalg.norm(w)
    return w * min(1.0, limit / speed) if speed > 0 else w


def test_a_free_body_spins_no_faster_than_its_cap_as_mujoco_c_with_the_cap_applied():
    model = mujoco.MjModel.from_xml_string(XML)
    limits = free_joint_speed_limits(model, {"": LIMIT})
    (free,) = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    assert limits == {free: LIMIT}  # the hinge is not a free joint: not capped
    sim = Simulator(model, 2, "cpu", substeps=SUBSTEPS, angular_speed_limits=limits)
    sim.qvel.copy_(torch.tensor(QVEL0, dtype=torch.float32))
    adr = int(model.jnt_dofadr[free]) + 3
    for world in range(2):
        data = mujoco.MjData(model)
        data.qvel[:] = QVEL0[world]
        for _ in range(2 * SUBSTEPS):
            mujoco.mj_step(model, data)
            data.qvel[adr:adr + 3] = capped(data.qvel[adr:adr + 3].copy(), LIMIT)
        if world == 0:
            sim.simulate(), sim.simulate()
        got = sim.qvel[world].numpy()
        np.testing.assert_allclose(got, data.qvel, rtol=2e-4, atol=2e-4)
        assert np.linalg.norm(got[adr:adr + 3]) <= LIMIT * (1 + 1e-5)
    # world 0 started at |w| = 6.4 rad/s (capped), world 1 at 3.6 (below the cap, so left alone at first)
    assert np.linalg.norm(QVEL0[0, 3:6]) > LIMIT > np.linalg.norm(QVEL0[1, 3:6])


def test_without_a_cap_the_body_keeps_its_speed():
    model = mujoco.MjModel.from_xml_string(XML)
    sim = Simulator(model, 2, "cpu", substeps=SUBSTEPS, angular_speed_limits=free_joint_speed_limits(model, {}))
    assert sim.free_body_velocity is None
    sim.qvel.copy_(torch.tensor(QVEL0, dtype=torch.float32))
    sim.simulate()
    assert np.linalg.norm(sim.qvel[0, 3:6].numpy()) > LIMIT


@pytest.mark.parametrize("value", [0, -1.0, "fast", True])
def test_a_bad_cap_is_one_line_naming_the_key(value):
    with pytest.raises(ConfigError, match=rf"^env\.assets\.cube\.maxAngularVelocity={value!r} is invalid: give a "
                                          r"number > 0\.0$"):
        max_angular_velocity({"maxAngularVelocity": value}, "env.assets.cube")


def test_the_cap_reaches_the_task_from_its_yaml():
    import isaacgymenvs_mw

    # Quadcopter's craft is a floating main asset: the YAML key caps its free joint.
    task = isaacgymenvs_mw.make("Quadcopter", num_envs=2, sim_device="cpu", rl_device="cpu",
                                overrides=["+task.env.asset.maxAngularVelocity=7.5"])
    cap = task.sim.free_body_velocity
    assert cap is not None and len(cap.joints) == 1
    assert int(task.sim.mj_model.jnt_type[cap.joints[0]]) == int(mujoco.mjtJoint.mjJNT_FREE)
