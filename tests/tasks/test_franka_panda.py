"""Franka Emika Panda MJCF (issue 32, the robot model): forward kinematics against the modified DH product of
Gaz et al. written here in numpy, masses / centres of mass / inertias / joint ranges / torque limits against the
published tables (franka_ros joint_limits.yaml and inertial.yaml, Franka FCI "Limits for Panda"), and the coupled
gripper under a position command in MuJoCo C."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

PANDA = Path(__file__).resolve().parents[2] / "assets" / "mjcf" / "franka_panda.xml"

# Modified (Craig) DH: a_{i-1}, d_i, alpha_{i-1}; theta_i = q_i. Gaz et al., RA-L 2019 (Load_Franka_DH.m).
DH = [
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -math.pi / 2),
    (0.0, 0.316, math.pi / 2),
    (0.0825, 0.0, math.pi / 2),
    (-0.0825, 0.384, -math.pi / 2),
    (0.0, 0.0, math.pi / 2),
    (0.088, 0.0, math.pi / 2),
]
FLANGE_D = 0.107
HAND_YAW = -math.pi / 4  # hand mounted on the flange turned -45 deg about z

# joint: (q_min, q_max, tau_max), franka_ros joint_limits.yaml / FCI "Limits for Panda"
LIMITS = [
    (-2.8973, 2.8973, 87.0),
    (-1.7628, 1.7628, 87.0),
    (-2.8973, 2.8973, 87.0),
    (-3.0718, -0.0698, 87.0),
    (-2.8973, 2.8973, 12.0),
    (-0.0175, 3.7525, 12.0),
    (-2.8973, 2.8973, 12.0),
]

# body: (mass, com, (Ixx, Iyy, Izz, Ixy, Ixz, Iyz)), Gaz et al. via franka_ros inertial.yaml
INERTIAL = {
    "link0": (0.629769, (-0.041018, -0.00014, 0.049974), (0.00315, 0.00388, 0.004285, 8.2904e-7, 0.00015, 8.2299e-6)),
    "link1": (4.970684, (0.003875, 0.002081, -0.04762), (0.70337, 0.70661, 0.009117, -0.000139, 0.006772, 0.019169)),
    "link2": (0.646926, (-0.003141, -0.02872, 0.003495), (0.007962, 0.02811, 0.025995, -0.003925, 0.010254, 0.000704)),
    "link3": (3.228604, (0.027518, 0.039252, -0.066502),
              (0.037242, 0.036155, 0.01083, -0.004761, -0.011396, -0.012805)),
    "link4": (3.587895, (-0.05317, 0.104419, 0.027454), (0.025853, 0.019552, 0.028323, 0.007796, -0.001332, 0.008641)),
    "link5": (1.225946, (-0.011953, 0.041065, -0.038437),
              (0.035549, 0.029474, 0.008627, -0.002117, -0.004037, 0.000229)),
    "link6": (1.666555, (0.060149, -0.014117, -0.010517), (0.001964, 0.004354, 0.005433, 0.000109, -0.001158, 0.000341)),
    "link7": (0.735522, (0.010517, -0.004252, 0.061597),
              (0.012516, 0.010027, 0.004815, -0.000428, -0.001196, -0.000741)),
    "hand": (0.73, (-0.01, 0.0, 0.03), (0.001, 0.0025, 0.0017, 0.0, 0.0, 0.0)),
    "left_finger": (0.015, (0.0, 0.0, 0.0), (2.375e-6, 2.375e-6, 7.5e-7, 0.0, 0.0, 0.0)),
    "right_finger": (0.015, (0.0, 0.0, 0.0), (2.375e-6, 2.375e-6, 7.5e-7, 0.0, 0.0, 0.0)),
}
ARM_JOINTS = [f"joint{i}" for i in range(1, 8)]
FINGERS = ["finger_joint1", "finger_joint2"]


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(PANDA))


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def homogeneous(r: np.ndarray, p) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = r, p
    return t


def dh_flange(q: np.ndarray) -> np.ndarray:
    """T_0^F = prod_i Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i) Tz(d_i), then Tz(0.107)."""
    t = np.eye(4)
    for (a, d, alpha), theta in zip(DH, q):
        t = t @ homogeneous(rot_x(alpha), (0, 0, 0)) @ homogeneous(np.eye(3), (a, 0, 0))
        t = t @ homogeneous(rot_z(theta), (0, 0, 0)) @ homogeneous(np.eye(3), (0, 0, d))
    return t @ homogeneous(np.eye(3), (0, 0, FLANGE_D))


def rotation_angle(r: np.ndarray) -> float:
    return math.acos(max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0)))


def qadr(m: mujoco.MjModel, names: list[str]) -> list[int]:
    return [int(m.jnt_qposadr[m.joint(n).id]) for n in names]


# ------------------------------------------------------------------------------------------------- kinematics
def test_forward_kinematics_equals_the_dh_product(model):
    m, d = model, mujoco.MjData(model)
    rng = np.random.default_rng(32)
    lo, hi = np.array([l[0] for l in LIMITS]), np.array([l[1] for l in LIMITS])
    adr = qadr(m, ARM_JOINTS)
    hand, flange = m.body("hand").id, m.site("flange").id
    configs = [np.zeros(7), lo, hi] + [rng.uniform(lo, hi) for _ in range(30)]
    for q in configs:
        d.qpos[:] = 0
        d.qpos[adr] = q
        mujoco.mj_kinematics(m, d)
        ref = dh_flange(q)
        np.testing.assert_allclose(d.site_xpos[flange], ref[:3, 3], atol=1e-6, rtol=0)
        np.testing.assert_allclose(d.xpos[hand], ref[:3, 3], atol=1e-6, rtol=0)
        site_r = d.site_xmat[flange].reshape(3, 3)
        hand_r = d.xmat[hand].reshape(3, 3)
        assert rotation_angle(site_r.T @ ref[:3, :3]) < 1e-6
        assert rotation_angle(hand_r.T @ ref[:3, :3] @ rot_z(HAND_YAW)) < 1e-6


def test_joint_axes_are_local_z_and_the_grasp_site_lies_between_the_fingertips(model):
    m, d = model, mujoco.MjData(model)
    for n in ARM_JOINTS:
        j = m.joint(n)
        assert j.type[0] == mujoco.mjtJoint.mjJNT_HINGE
        np.testing.assert_array_equal(j.axis, [0, 0, 1])
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    mujoco.mj_kinematics(m, d)
    hand_r, hand_p = d.xmat[m.body("hand").id].reshape(3, 3), d.xpos[m.body("hand").id]
    grasp = hand_r.T @ (d.site_xpos[m.site("grasp").id] - hand_p)
    np.testing.assert_allclose(grasp, [0, 0, 0.1025], atol=1e-12)
    left, right = d.xpos[m.body("left_finger").id], d.xpos[m.body("right_finger").id]
    np.testing.assert_allclose((left + right) / 2, hand_p + hand_r @ [0, 0, 0.0584], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(left - right), 0.08, atol=1e-12)  # both open 0.04


# ------------------------------------------------------------------------------------------------- parameters
def test_masses_centres_of_mass_and_inertias_equal_the_identified_values(model):
    m = model
    for name, (mass, com, (ixx, iyy, izz, ixy, ixz, iyz)) in INERTIAL.items():
        b = m.body(name)
        assert b.mass[0] == pytest.approx(mass, abs=1e-12), name
        np.testing.assert_allclose(b.ipos, com, atol=1e-12, err_msg=name)
        r = np.zeros(9)
        mujoco.mju_quat2Mat(r, b.iquat)
        r = r.reshape(3, 3)
        inertia = r @ np.diag(b.inertia) @ r.T  # principal inertia back into the link frame
        ref = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        np.testing.assert_allclose(inertia, ref, atol=1e-9, err_msg=name)
    arm = sum(INERTIAL[f"link{i}"][0] for i in range(1, 8))
    assert arm == pytest.approx(16.06, abs=0.005)
    moving = sum(m.body_mass[m.body(n).id] for n in INERTIAL if n != "link0")
    assert moving == pytest.approx(16.82, abs=0.005)
    assert m.body_mass.sum() == pytest.approx(sum(v[0] for v in INERTIAL.values()), abs=1e-12)


def test_joint_ranges_and_torque_limits_equal_the_published_limits(model):
    m = model
    assert m.nu == 8 and m.nq == 9
    for i, (name, (lo, hi, tau)) in enumerate(zip(ARM_JOINTS, LIMITS)):
        j = m.joint(name)
        assert j.limited[0]
        np.testing.assert_array_equal(j.range, [lo, hi])
        a = m.actuator(f"actuator{i + 1}")
        assert m.actuator_trnid[a.id, 0] == j.id
        assert a.forcelimited[0] and a.ctrllimited[0]
        np.testing.assert_array_equal(a.forcerange, [-tau, tau])
        np.testing.assert_array_equal(a.ctrlrange, [lo, hi])
        kp = a.gainprm[0]
        assert kp > 0 and a.biasprm[1] == -kp and a.biasprm[2] < 0  # PD position servo
    for name in FINGERS:
        j = m.joint(name)
        assert j.type[0] == mujoco.mjtJoint.mjJNT_SLIDE
        np.testing.assert_array_equal(j.range, [0.0, 0.04])
    g = m.actuator("gripper")
    assert m.actuator_trnid[g.id, 0] == m.joint("finger_joint1").id
    np.testing.assert_array_equal(g.ctrlrange, [0.0, 0.04])


def test_collision_shapes_are_primitives_and_home_is_contact_free(model):
    m, d = model, mujoco.MjData(model)
    primitives = {mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CYLINDER,
                  mujoco.mjtGeom.mjGEOM_SPHERE}
    assert m.ngeom > 0 and m.nmesh == 0
    assert all(int(t) in primitives for t in m.geom_type)
    bodies_with_geoms = {m.body(int(b)).name for b in m.geom_bodyid}
    assert bodies_with_geoms == set(INERTIAL)
    for fingers in (0.04, 0.0):
        mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
        d.qpos[qadr(m, FINGERS)] = fingers
        mujoco.mj_forward(m, d)
        assert d.ncon == 0


# ------------------------------------------------------------------------------------------------- gripper
def test_fingers_move_together_within_their_stroke_under_a_gripper_command(model):
    m, d = model, mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    home = d.qpos[qadr(m, ARM_JOINTS)].copy()
    f1, f2 = qadr(m, FINGERS)
    g = m.actuator("gripper").id
    steps = int(round(0.5 / m.opt.timestep))
    for target in (0.0, 0.02, 0.04, -1.0, 1.0):  # the last two lie outside ctrlrange and are clamped to it
        d.ctrl[g] = target
        for _ in range(steps):
            mujoco.mj_step(m, d)
            assert abs(d.qpos[f1] - d.qpos[f2]) < 1e-3
            assert -1e-3 < d.qpos[f1] < 0.041 and -1e-3 < d.qpos[f2] < 0.041
        expected = min(max(target, 0.0), 0.04)
        assert d.qpos[f1] == pytest.approx(expected, abs=2e-3), target
        assert d.qpos[f2] == pytest.approx(expected, abs=2e-3), target
        assert np.all(np.isfinite(d.qpos))
    # the arm servos hold the home pose against gravity meanwhile
    np.testing.assert_allclose(d.qpos[qadr(m, ARM_JOINTS)], home, atol=0.05)
