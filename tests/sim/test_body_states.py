"""Simulator.body_states / root_states / root_ang_vel_world against MuJoCo C (mj_objectVelocity, xpos, xquat).

A free torso with its centre of mass off its origin carries a leg on a hinge; both move and spin, so the origin and
centre-of-mass velocities differ and the angular velocity is not along one axis.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from isaacgymenvs_mw.sim import Simulator

XML = """
<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <body name="torso" pos="0 0 1" quat="0.9 0.1 0.3 0.2">
      <freejoint/>
      <inertial pos="0.05 0.02 -0.03" mass="3" diaginertia="0.05 0.04 0.03"/>
      <geom type="box" size="0.2 0.1 0.05" contype="0" conaffinity="0"/>
      <body name="leg" pos="0.2 0 0">
        <joint name="knee" type="hinge" axis="0 1 0.2"/>
        <inertial pos="0 0 -0.15" mass="0.5" diaginertia="0.004 0.004 0.001"/>
        <geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03" contype="0" conaffinity="0"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor joint="knee" gear="1"/></actuator>
</mujoco>
"""
N = 2
QVEL0 = np.array([[0.5, -0.3, 1.0, 2.0, -1.0, 3.0, -4.0], [-0.2, 0.6, 0.0, -1.5, 2.5, 0.5, 6.0]])
CTRL = np.array([[0.3], [-0.5]])


@pytest.fixture(scope="module")
def moving():
    """Simulator and MuJoCo C data stepped side by side from the same state."""
    model = mujoco.MjModel.from_xml_string(XML)
    sim = Simulator(model, N, "cpu", substeps=4)
    sim.qvel.copy_(torch.tensor(QVEL0, dtype=torch.float32))
    sim.ctrl.copy_(torch.tensor(CTRL, dtype=torch.float32))
    datas = []
    for env in range(N):
        d = mujoco.MjData(model)
        d.qvel[:], d.ctrl[:] = QVEL0[env], CTRL[env]
        datas.append(d)
    for _ in range(5):
        sim.simulate()
        for d in datas:
            for _ in range(4):
                mujoco.mj_step(model, d)
    return model, sim, datas


def reference_states(model, d, com: bool) -> np.ndarray:
    """(nbody, 13) from MuJoCo C: origin, xquat (w, x, y, z), then mj_objectVelocity (world axes) of the body
    origin (XBODY) or of its centre of mass (BODY), linear then angular."""
    rows = []
    for b in range(model.nbody):
        v = np.zeros(6)
        kind = mujoco.mjtObj.mjOBJ_BODY if com else mujoco.mjtObj.mjOBJ_XBODY
        mujoco.mj_objectVelocity(model, d, kind, b, v, 0)
        rows.append(np.concatenate([d.xpos[b], d.xquat[b], v[3:], v[:3]]))
    return np.stack(rows)


def compare(model, sim, datas, com: bool, ids=None) -> None:
    got = sim.body_states(None if ids is None else torch.tensor(ids), com=com).numpy()
    want = np.stack([reference_states(model, d, com) for d in datas])
    if ids is not None:
        want = want[:, ids]
    np.testing.assert_allclose(got, want, atol=2e-4)


@pytest.mark.parametrize("com", [False, True])
def test_body_states_after_a_step_match_mujoco_c(moving, com):
    """Straight after simulate(): both hold the poses and velocities of the last physics step's start."""
    model, sim, datas = moving
    assert sim.body_states().shape == (N, model.nbody, 13)
    compare(model, sim, datas, com)
    compare(model, sim, datas, com, ids=[2, 1])


def test_body_states_after_forward_match_mujoco_c_and_differ_by_point(moving):
    model, sim, datas = moving
    sim.forward()
    for d in datas:
        mujoco.mj_forward(model, d)
    for com in (False, True):
        compare(model, sim, datas, com)
    origin, centre = sim.body_states(), sim.body_states(com=True)
    # The torso spins about an offset centre of mass: the two linear velocities are not the same quantity.
    assert (origin[:, 1:, 7:10] - centre[:, 1:, 7:10]).abs().max() > 0.05
    torch.testing.assert_close(origin[..., 10:], centre[..., 10:])


def test_root_states_are_world_frame(moving):
    """root_states: qpos/qvel's root with the angular velocity turned into world axes (MuJoCo keeps it in the body
    frame); checked against mj_objectVelocity of the root body on the current state."""
    model, sim, datas = moving
    for d in datas:
        mujoco.mj_forward(model, d)
    want = np.stack([reference_states(model, d, com=False)[1] for d in datas])
    np.testing.assert_allclose(sim.root_states().numpy(), want, atol=2e-4)
    np.testing.assert_allclose(sim.root_ang_vel_world().numpy(), want[:, 10:], atol=2e-4)
    assert np.abs(sim.root_ang_vel.numpy() - want[:, 10:]).max() > 0.1  # the body-frame view is another thing


def test_root_states_need_a_floating_base():
    model = mujoco.MjModel.from_xml_string(XML.replace("<freejoint/>", ""))
    sim = Simulator(model, 1, "cpu")
    with pytest.raises(ValueError, match="root_states needs a floating base"):
        sim.root_states()
