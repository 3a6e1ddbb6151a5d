"""Simulator.apply_body_forces against MuJoCo C, where the same wrench goes in through mj_applyFT at every step.

The model: a free box and a body on a tilted hinge, both with their centre of mass off the body origin, spinning,
no contacts. The reference rebuilds each wrench from its definition at every physics step (a world force at a
fixed world point; a body-frame force at a body-fixed point, rotated by that step's xmat), which is not how the
helper computes it (a torque about the centre of mass, rotated by a kernel).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from isaacgymenvs_mw.sim import Simulator
from isaacgymenvs_mw.tasks.base.vec_task import VecTask

XML = (Path(__file__).resolve().parents[1] / "assets" / "free_box_and_hinge.xml").read_text()
N, SUBSTEPS = 2, 3
BOX, ARM = 1, 2
QVEL0 = np.array([[0.1, -0.2, 0.3, 1.0, -2.0, 6.0, 3.0], [0.0, 0.4, 0.0, -3.0, 0.5, 2.0, -4.0]])
# (forces, torques, positions) per world, for (box, arm).
FORCES = np.array([[[3.0, -1.0, 25.0], [0.5, 2.0, -1.0]], [[-4.0, 2.0, 15.0], [-1.0, 0.0, 2.0]]])
TORQUES = np.array([[[0.2, -0.1, 0.05], [0.0, 0.1, 0.3]], [[-0.3, 0.2, 0.1], [0.2, -0.2, 0.1]]])
POINTS_BODY = np.array([[[0.1, 0.05, -0.2], [0.3, 0.0, 0.02]], [[-0.1, 0.15, 0.2], [0.1, 0.02, 0.0]]])
POINTS_WORLD = np.array([[[0.1, 0.05, 1.2], [1.3, 0.1, 1.0]], [[-0.1, 0.15, 0.8], [1.1, -0.1, 1.05]]])


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(XML)


def make_sim(model: mujoco.MjModel) -> Simulator:
    sim = Simulator(model, N, "cpu", substeps=SUBSTEPS)
    sim.qvel.copy_(torch.tensor(QVEL0, dtype=torch.float32))
    return sim


def reference_data(model: mujoco.MjModel) -> list[mujoco.MjData]:
    out = []
    for env in range(N):
        d = mujoco.MjData(model)
        d.qvel[:] = QVEL0[env]
        out.append(d)
    return out


def reference_step(model, datas, wrenches=(), substeps: int = SUBSTEPS) -> None:
    """``substeps`` mj_step calls; before each, every (env, body, force, torque, point, frame) through mj_applyFT."""
    for _ in range(substeps):
        for d in datas:
            mujoco.mj_kinematics(model, d)  # the pose this step starts from
            mujoco.mj_comPos(model, d)  # what mj_applyFT's Jacobian needs
            d.qfrc_applied[:] = 0.0
        for env, body, f, t, p, frame in wrenches:
            d = datas[env]
            if frame == "body":
                rot = d.xmat[body].reshape(3, 3)
                f, t = rot @ f, rot @ t
                p = d.xipos[body].copy() if p is None else d.xpos[body] + rot @ p
            elif p is None:
                p = d.xipos[body].copy()
            mujoco.mj_applyFT(model, d, f, t, p, body, d.qfrc_applied)
        for d in datas:
            mujoco.mj_step(model, d)


def wrench_list(frame: str, points: np.ndarray | None, forces=FORCES, torques=TORQUES) -> list:
    return [(env, body, forces[env, i], torques[env, i], None if points is None else points[env, i], frame)
            for env in range(N) for i, body in enumerate((BOX, ARM))]


def assert_matches(sim: Simulator, datas, atol: float = 2e-4) -> None:
    np.testing.assert_allclose(sim.qpos.numpy(), np.stack([d.qpos for d in datas]), atol=atol)
    np.testing.assert_allclose(sim.qvel.numpy(), np.stack([d.qvel for d in datas]), atol=atol * 10)


def as_torch(x: np.ndarray) -> torch.Tensor:
    return torch.tensor(x, dtype=torch.float32)


@pytest.mark.parametrize("frame,points", [("world", POINTS_WORLD), ("body", POINTS_BODY), ("body", None)])
def test_one_step_wrench_matches_mj_applyFT(model, frame, points):
    """A force and torque at a point acts for one env step (all its physics steps) and is then gone."""
    sim, datas = make_sim(model), reference_data(model)
    sim.apply_body_forces(as_torch(FORCES), as_torch(TORQUES), bodies=["box", "arm"],
                          positions=None if points is None else as_torch(points), frame=frame)
    sim.simulate()
    reference_step(model, datas, wrench_list(frame, points))
    assert_matches(sim, datas)
    sim.simulate()  # no force this time
    reference_step(model, datas)
    assert_matches(sim, datas)


def test_persistent_body_frame_wrench_turns_with_the_body(model):
    """persist=True acts at every env step until cleared; in the body frame it follows the rotation, which here
    makes a visible difference to the same wrench held in world axes."""
    sim, datas = make_sim(model), reference_data(model)
    sim.apply_body_forces(as_torch(FORCES), as_torch(TORQUES), bodies=torch.tensor([BOX, ARM]),
                          positions=as_torch(POINTS_BODY), frame="body", persist=True)
    wrenches = wrench_list("body", POINTS_BODY)
    for _ in range(4):
        sim.simulate()
        reference_step(model, datas, wrenches)
        assert_matches(sim, datas)

    held = reference_data(model)  # the wrench of the first physics step, kept in world axes
    for d in held:
        mujoco.mj_kinematics(model, d)
        mujoco.mj_comPos(model, d)
    fixed = [(env, body, held[env].xmat[body].reshape(3, 3) @ f, held[env].xmat[body].reshape(3, 3) @ t,
              held[env].xpos[body] + held[env].xmat[body].reshape(3, 3) @ p, "world")
             for env, body, f, t, p, _ in wrenches]
    for _ in range(4):
        reference_step(model, held, fixed)
    assert np.abs(np.stack([d.qvel for d in held]) - sim.qvel.numpy()).max() > 0.05

    sim.clear_body_forces()
    sim.simulate()
    reference_step(model, datas)
    assert_matches(sim, datas)


def test_calls_add_up_with_the_users_xfrc_applied(model):
    """Two calls in one step add; a direct xfrc_applied write keeps acting and is not overwritten by the helper."""
    sim, datas = make_sim(model), reference_data(model)
    user = np.zeros((N, model.nbody, 6))
    user[:, BOX, 2] = 5.0
    sim.xfrc_applied.copy_(as_torch(user))
    sim.apply_body_forces(as_torch(FORCES[:, :1]), bodies=["box"])
    sim.apply_body_forces(torques=as_torch(TORQUES), bodies=[BOX, ARM], frame="body")
    sim.simulate()
    zero = np.zeros(3)
    wrenches = [(env, BOX, user[env, BOX, :3] + FORCES[env, 0], zero, None, "world") for env in range(N)]
    wrenches += wrench_list("body", None, forces=np.zeros_like(FORCES))
    reference_step(model, datas, wrenches)
    assert_matches(sim, datas)
    np.testing.assert_array_equal(sim.xfrc_applied.numpy(), user)
    sim.simulate()
    reference_step(model, datas, [(env, BOX, user[env, BOX, :3], zero, None, "world") for env in range(N)])
    assert_matches(sim, datas)


def test_reset_drops_persistent_forces_of_reset_worlds(model):
    sim = make_sim(model)
    sim.apply_body_forces(as_torch(FORCES), bodies=["box", "arm"], persist=True)
    sim.reset_worlds(torch.tensor([True, False]))
    wrench = sim.body_forces.wrench
    assert wrench[:, 0].abs().sum() == 0 and wrench[1, 1].abs().sum() > 0


@pytest.mark.parametrize("kwargs,message", [
    (dict(forces=torch.zeros(N, 2, 3), bodies=["box", "lid"]), "bodies: no body named 'lid'"),
    (dict(forces=torch.zeros(N, 1, 3), bodies=[7]), "bodies: index 7 is out of range"),
    (dict(forces=torch.zeros(N, 3), bodies=["box"]), "forces has shape (2, 3); valid: (num_envs, len(bodies), 3)"),
    (dict(forces=torch.zeros(N, 1, 3), bodies=["box"], frame="local"), "frame='local' is invalid"),
    (dict(bodies=["box"]), "give forces, torques or both"),
    (dict(torques=torch.zeros(N, 1, 3), positions=torch.zeros(N, 1, 3), bodies=["box"]), "positions given"),
])
def test_invalid_arguments_name_what_is_wrong(model, kwargs, message):
    sim = make_sim(model)
    with pytest.raises(ValueError) as err:
        sim.apply_body_forces(**kwargs)
    assert message in str(err.value)


# --------------------------------------------------------------- through a task: site thrusters and pushes
QUAD_XML = """
<mujoco>
  <worldbody>
    <body name="quad" pos="0 0 1">
      <freejoint/>
      <geom type="box" size="0.1 0.1 0.02" mass="1" contype="0" conaffinity="0"/>
      <site name="rotor0" pos="0.1 0.1 0"/>
      <site name="rotor1" pos="-0.1 0.1 0"/>
      <site name="rotor2" pos="-0.1 -0.1 0"/>
      <site name="rotor3" pos="0.1 -0.1 0" quat="0.9962 0.0872 0 0"/>
    </body>
  </worldbody>
  <actuator>
    <motor name="thrust0" site="rotor0" gear="0 0 10 0 0 0.5"/>
    <motor name="thrust1" site="rotor1" gear="0 0 10 0 0 -0.5"/>
    <general name="thrust2" site="rotor2" gear="0 0 10 0 0 0.5"/>
    <motor name="thrust3" site="rotor3" gear="0 0 10 0 0 -0.5"/>
  </actuator>
</mujoco>
"""


class Quad(VecTask):
    """Actions are the four rotor commands; ``push`` (kwargs of apply_body_forces) is applied in the step."""

    max_episode_length = 100
    push: dict | None = None

    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.sim.ctrl[:] = actions
        if self.push is not None:
            self.apply_body_forces(**self.push)

    def post_physics_step(self) -> None:
        self.progress_buf += 1
        self.compute_observations()

    def compute_observations(self) -> None:
        self.obs_buf[:] = self.sim.root_pos


def quad_task(tmp_path) -> Quad:
    (tmp_path / "quad.xml").write_text(QUAD_XML)
    cfg = {"env": {"numEnvs": N, "numObservations": 3, "numActions": 4, "controlFrequencyInv": SUBSTEPS,
                   "asset": {"assetRoot": str(tmp_path), "assetFileName": "quad.xml", "fixBaseLink": False},
                   "plane": {"enabled": False}},
           "sim": {"dt": 0.01}}
    return Quad(cfg, rl_device="cpu", sim_device="cpu", graphics_device_id=0, headless=True)


ACTIONS = np.array([[0.3, 0.5, 0.6, 0.4], [0.6, 0.4, 0.6, 0.4]])


def test_site_actuators_are_rotor_thrusts(tmp_path):
    """An MJCF ``<motor site=...>`` / ``<general site=...>`` is one ctrl column: its gear is a wrench in the site's
    frame (force 0 0 10: 10 N of thrust along the site's z per unit command; 0 0 0.5 about z: rotor drag)."""
    task = quad_task(tmp_path)
    assert task.sim.actuator_names == ["thrust0", "thrust1", "thrust2", "thrust3"]
    assert task.sim.actuator_joints == [None] * 4  # site transmission, no joint
    m = task.sim.mj_model
    task.reset()
    datas = [mujoco.MjData(m) for _ in range(N)]
    for _ in range(3):
        task.step(as_torch(ACTIONS))
        for env, d in enumerate(datas):
            d.ctrl[:] = ACTIONS[env]
        reference_step(m, datas)
        assert_matches(task.sim, datas)
    # World 1: 20 N of thrust lift 1 kg, balanced in roll and pitch; the rotors' drag spins it up about z.
    assert task.sim.root_lin_vel[1, 2] > 0.5 and task.sim.root_ang_vel[1, 2] > 0.1


def test_task_push_acts_for_one_env_step(tmp_path):
    """VecTask.apply_body_forces from pre_physics_step: the step that asked for it feels it, the next does not."""
    task = quad_task(tmp_path)
    m = task.sim.mj_model
    task.reset()
    datas = [mujoco.MjData(m) for _ in range(N)]
    force, torque, point = FORCES[:, :1], TORQUES[:, :1], POINTS_BODY[:, :1]
    task.push = dict(forces=as_torch(force), torques=as_torch(torque), bodies=["quad"],
                     positions=as_torch(point), frame="body")
    for push in (True, False):
        task.step(as_torch(ACTIONS))
        task.push = None
        for env, d in enumerate(datas):
            d.ctrl[:] = ACTIONS[env]
        wrenches = [(env, 1, force[env, 0], torque[env, 0], point[env, 0], "body") for env in range(N)]
        reference_step(m, datas, wrenches if push else ())
        assert_matches(task.sim, datas)


def test_first_captured_step_advances_once(model, monkeypatch):
    """Where graphs are on, a graph's first call runs the physics eagerly (compiling) and then captures it; the
    eager run's state is put back, so forces used for the first time still act for exactly one env step. Stand-ins
    for Warp's capture run the captured function for real and make the launch a no-op (CPU has no graphs)."""

    class RunningCapture:
        def __init__(self, **kwargs) -> None:
            self.graph = object()

        def __enter__(self) -> "RunningCapture":
            return self

        def __exit__(self, *exc) -> bool:
            return False

    sim, datas = make_sim(model), reference_data(model)
    monkeypatch.setattr(sim, "use_graphs", True)
    monkeypatch.setattr("warp.ScopedCapture", RunningCapture)
    monkeypatch.setattr("warp.capture_launch", lambda graph: None)
    sim.apply_body_forces(as_torch(FORCES), as_torch(TORQUES), bodies=["box", "arm"], frame="body")
    sim.simulate()
    reference_step(model, datas, wrench_list("body", None))
    assert_matches(sim, datas)
    assert sim.body_forces.wrench[0].abs().sum() == 0  # the one-step slot was dropped by the captured run
