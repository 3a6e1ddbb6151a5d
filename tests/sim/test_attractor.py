"""docs/porting.md, "Rigid-body attractors": IsaacGym's attractor as a weld to a mocap body that the task moves each
step. The body follows the moving target, and MuJoCo Warp's worlds match MuJoCo C given the same targets, with
either form of ``solref`` (time constant and damping ratio, or negated stiffness and damping)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

from isaacgymenvs_mw.sim import Simulator

HAND = """<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <body name="hand" pos="0 0 1"><freejoint/>
      <geom type="box" size="0.05 0.04 0.03" mass="1" contype="0" conaffinity="0"/></body>
    <body name="hand_target" mocap="true" pos="0 0 1">
      <geom type="sphere" size="0.01" contype="0" conaffinity="0"/></body>
  </worldbody>
  <equality><weld body1="hand" body2="hand_target" solref="{solref}"/></equality>
</mujoco>"""
WORLDS, STEPS = 2, 200


def target(world: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    """A target circling at 1 Hz (one radius per world) and turning about z: what set_attractor_target would get."""
    t, radius = step * 0.005, 0.1 * (world + 1)
    pos = np.array([radius * math.cos(2 * math.pi * t), radius * math.sin(2 * math.pi * t), 1.2])
    yaw = 0.5 * t
    return pos, np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


@pytest.mark.parametrize("solref", ["0.02 1", "-1000 -50"])
def test_a_weld_to_a_moving_mocap_body_pulls_the_body_as_in_mujoco_c(solref):
    model = mujoco.MjModel.from_xml_string(HAND.format(solref=solref))
    sim = Simulator(model, WORLDS, "cpu")
    column = sim.mocap_index("hand_target")
    data = [mujoco.MjData(model) for _ in range(WORLDS)]
    for step in range(STEPS):
        for w in range(WORLDS):
            pos, quat = target(w, step)
            sim.mocap_pos[w, column] = torch.tensor(pos, dtype=torch.float32)
            sim.mocap_quat[w, column] = torch.tensor(quat, dtype=torch.float32)
            data[w].mocap_pos[column], data[w].mocap_quat[column] = pos, quat
            mujoco.mj_step(model, data[w])
        sim.simulate()
    for w in range(WORLDS):
        np.testing.assert_allclose(sim.qpos[w].double().numpy(), data[w].qpos, atol=1e-4, err_msg=f"world {w}")
        pos, quat = target(w, STEPS - 1)
        # It follows (lagging behind on the circle) and holds the target's height against gravity.
        assert np.linalg.norm(data[w].qpos[:2] - pos[:2]) < 0.3 * np.linalg.norm(pos[:2])
        assert abs(data[w].qpos[2] - pos[2]) < 0.01
        assert abs(np.dot(data[w].qpos[3:7], quat)) > 0.999  # and turns with it
