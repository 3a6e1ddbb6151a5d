"""Allegro Hand MJCF (issue 34, the robot model): fingertip positions against a forward-kinematics product of the
menagerie right_hand.xml offsets and axes written here in numpy, masses / joint ranges / drive gains against the
IsaacGymEnvs URDF and task figures, a contact-free zero pose, and a 0.065 m cube dropped onto the upturned palm
coming to rest there, all in MuJoCo C."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from hand_kinematics import all_colliding, assert_primitive_hand_without_self_contacts, hand_and_cube, pose, posed

ALLEGRO = Path(__file__).resolve().parents[1] / "assets" / "mjcf" / "allegro_hand.xml"
FINGERS = ("index", "middle", "ring", "thumb")
JOINTS = [f"{f}_joint_{i}" for f in FINGERS for i in range(4)]


# ------------------------------------------------------------------------------------------------- reference data
def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def quat_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    w, x, y, z = np.array([w, x, y, z]) / math.sqrt(w * w + x * x + y * y + z * z)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


# Hand root (IsaacGymEnvs allegro_touch_sensor.urdf allegro_mount) -> URDF palm_link: rpy (0, -pi/2, pi/4), xyz below;
# URDF palm_link axes in the menagerie palm frame: x_urdf = z, y_urdf = -y, z_urdf = x.
MOUNT_TO_PALM_R = rot_z(math.pi / 4) @ rot_y(-math.pi / 2)
MOUNT_TO_PALM_P = np.array([-0.008219, -0.02063, 0.08086])
URDF_FROM_MENAGERIE = np.array([[0, 0, 1], [0, -1, 0], [1, 0, 0]])
URDF_MIDDLE_BASE = np.array([0.0537375, 0.0087771, -0.0113])  # middle_joint_0 origin in palm_link
# menagerie right_hand.xml (@28ffb48): finger roots on the palm (pos, quat wxyz)
ROOTS = {
    "index": ((0.0, 0.0435, -0.001542), (0.999048, -0.0436194, 0.0, 0.0)),
    "middle": ((0.0, 0.0, 0.0007), (1.0, 0.0, 0.0, 0.0)),
    "ring": ((0.0, -0.0435, -0.001542), (0.999048, 0.0436194, 0.0, 0.0)),
    "thumb": ((-0.0182, 0.019333, -0.045987), (0.477714, -0.521334, -0.521334, -0.477714)),
}
FINGER_TIP, THUMB_TIP = 0.0267, 0.0423  # fingertip frame beyond the distal joint


def menagerie_palm() -> np.ndarray:
    """Pose of the menagerie palm frame in the hand root frame."""
    r = MOUNT_TO_PALM_R @ URDF_FROM_MENAGERIE
    middle_root = np.array(ROOTS["middle"][0])
    p = MOUNT_TO_PALM_P + MOUNT_TO_PALM_R @ (URDF_MIDDLE_BASE - URDF_FROM_MENAGERIE @ middle_root)
    return pose(r, p)


def fingertip(finger: str, q) -> np.ndarray:
    """Fingertip position in the hand root frame: product of the menagerie chain, joint 0 about z (thumb: -x)."""
    pos, quat = ROOTS[finger]
    t = menagerie_palm() @ pose(quat_matrix(*quat), pos)
    if finger == "thumb":
        t = t @ pose(rot_x(-q[0])) @ pose(p=(-0.027, 0.005, 0.0399)) @ pose(rot_z(q[1]))
        t = t @ pose(p=(0, 0, 0.0177)) @ pose(rot_y(q[2])) @ pose(p=(0, 0, 0.0514)) @ pose(rot_y(q[3]))
        return (t @ pose(p=(0, 0, THUMB_TIP)))[:3, 3]
    t = t @ pose(rot_z(q[0])) @ pose(p=(0, 0, 0.0164)) @ pose(rot_y(q[1])) @ pose(p=(0, 0, 0.054))
    t = t @ pose(rot_y(q[2])) @ pose(p=(0, 0, 0.0384)) @ pose(rot_y(q[3]))
    return (t @ pose(p=(0, 0, FINGER_TIP)))[:3, 3]


# IsaacGymEnvs allegro_touch_sensor.urdf joint limits (reference manipulation.md F.2.2, rad)
FINGER_RANGES = [(-0.5585, 0.5585), (-0.2792, 1.7278), (-0.2792, 1.7278), (-0.2792, 1.7278)]
THUMB_RANGES = [(0.2792, 1.5708), (-0.3316, 1.1519), (-0.2792, 1.7278), (-0.2792, 1.7627)]
RANGES = FINGER_RANGES * 3 + THUMB_RANGES
# IsaacGymEnvs URDF masses (F.2.3, kg): link 0, 1, 2, 3, tip; palm 0.4154 with the fixed mount 0.05
FINGER_MASSES = (0.0119, 0.065, 0.0355, 0.0096, 0.021)
THUMB_MASSES = (0.0176, 0.0119, 0.038, 0.0388, 0.021)
PALM_MASS, MOUNT_MASS, TOTAL_MASS = 0.4154, 0.05, 1.022
# IsaacGymEnvs tasks/allegro_hand.py per-DOF drive
KP, KV, EFFORT, FRICTION, ARMATURE = 3.0, 0.1, 0.5, 0.01, 0.001
# IsaacGymEnvs AllegroHand hand pose, wxyz
IGE_HAND_POS, IGE_HAND_QUAT = (0.0, 0.0, 0.5), (0.257551, 0.283045, 0.68333, -0.621782)
CUBE_SIDE, CUBE_DENSITY = 0.065, 400.0


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(ALLEGRO))


# ------------------------------------------------------------------------------------------------- kinematics
def test_fingertips_equal_the_forward_kinematics_product(model):
    m = model
    for q, d in posed(m, JOINTS, seed=34):
        for k, finger in enumerate(FINGERS):
            expected = fingertip(finger, q[4 * k: 4 * k + 4])
            # 2e-6: the file writes the root-to-palm offset to 6 decimals
            np.testing.assert_allclose(d.site_xpos[m.site(f"{finger}_tip").id], expected, atol=2e-6, rtol=0,
                                       err_msg=finger)


def test_middle_finger_lies_along_the_hand_axis_and_the_palm_faces_up_in_the_ige_pose(model):
    m, d = model, mujoco.MjData(model)
    mujoco.mj_kinematics(m, d)
    tip = d.site_xpos[m.site("middle_tip").id]
    base = d.xpos[m.body("middle_link_0").id]
    axis = (tip - base) / np.linalg.norm(tip - base)
    np.testing.assert_allclose(axis, [0, 0, 1], atol=1e-9)  # straight finger along the root's +z
    np.testing.assert_allclose(np.linalg.norm(tip - base), 0.0164 + 0.054 + 0.0384 + FINGER_TIP, atol=1e-9)
    palm_normal = d.geom_xmat[m.geom("palm_collision").id].reshape(3, 3)[:, 0]
    np.testing.assert_allclose(palm_normal, [-math.sqrt(0.5), -math.sqrt(0.5), 0], atol=1e-9)
    world = quat_matrix(*IGE_HAND_QUAT)
    assert (world @ palm_normal)[2] > 0.99  # palm up: R_y(pi) R_x(0.47 pi) R_z(pi/4) tilts it 5.4 deg
    assert (world @ axis)[1] < -0.99  # fingers towards world -y, where IsaacGymEnvs puts the cube


# ------------------------------------------------------------------------------------------------- parameters
def test_masses_equal_the_urdf_masses(model):
    m = model
    assert m.body("palm").mass[0] == pytest.approx(PALM_MASS + MOUNT_MASS, abs=1e-12)
    for finger in FINGERS:
        table = THUMB_MASSES if finger == "thumb" else FINGER_MASSES
        bodies = [f"{finger}_link_{i}" for i in range(4)] + [f"{finger}_fingertip"]
        for body, mass in zip(bodies, table):
            assert m.body(body).mass[0] == pytest.approx(mass, abs=1e-12), body
    assert m.body_mass.sum() == pytest.approx(TOTAL_MASS, abs=5e-4)  # 1.0217, the reference rounds to 1.022
    assert m.nbody == 1 + 1 + 4 * 5


def test_inertias_are_uniform_solids_of_the_collision_shapes(model):
    """A uniform box (or capsule) of the link's mass, centred on the geom: the formulas written out here."""
    m = model
    for g in range(m.ngeom):
        b = m.geom_bodyid[g]
        mass, size = m.body_mass[b], m.geom_size[g]
        np.testing.assert_allclose(m.body_ipos[b], m.geom_pos[g], atol=1e-12)
        if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
            a2 = size**2
            expected = mass / 3 * np.array([a2[1] + a2[2], a2[0] + a2[2], a2[0] + a2[1]])
        else:
            r, h = size[0], size[1]
            v_cyl, v_sph = math.pi * r * r * 2 * h, 4 / 3 * math.pi * r**3
            m_cyl, m_sph = mass * v_cyl / (v_cyl + v_sph), mass * v_sph / (v_cyl + v_sph)
            axial = m_cyl * r * r / 2 + m_sph * 2 * r * r / 5
            transverse = m_cyl * (r * r / 4 + (2 * h) ** 2 / 12) + m_sph * (2 * r * r / 5 + h * h + 3 * h * r / 4)
            expected = np.array([transverse, transverse, axial])
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, m.body_iquat[b])
        rot = rot.reshape(3, 3)
        inertia = rot @ np.diag(m.body_inertia[b]) @ rot.T  # principal axes back into the body frame
        geom_rot = np.zeros(9)
        mujoco.mju_quat2Mat(geom_rot, m.geom_quat[g])
        geom_rot = geom_rot.reshape(3, 3)
        np.testing.assert_allclose(geom_rot.T @ inertia @ geom_rot, np.diag(expected), rtol=1e-6, atol=1e-12,
                                   err_msg=m.body(b).name)


def test_joint_ranges_and_drives_equal_isaacgymenvs(model):
    m = model
    assert m.njnt == 16 and m.nu == 16 and m.nq == 16
    assert [m.joint(j).name for j in range(m.njnt)] == JOINTS
    for i, (name, (lo, hi)) in enumerate(zip(JOINTS, RANGES)):
        j = m.joint(name)
        assert j.type[0] == mujoco.mjtJoint.mjJNT_HINGE and j.limited[0]
        np.testing.assert_allclose(j.range, [lo, hi], atol=1e-4, err_msg=name)  # the table rounds to 4 decimals
        a = m.actuator(i)
        assert a.name == name.replace("_joint", "") and m.actuator_trnid[i, 0] == j.id
        assert a.gainprm[0] == KP and a.biasprm[:3].tolist() == [0.0, -KP, -KV]
        assert a.forcelimited[0] and a.forcerange.tolist() == [-EFFORT, EFFORT]
        assert a.ctrllimited[0] and a.ctrlrange.tolist() == j.range.tolist()
        dof = j.dofadr[0]
        assert m.dof_armature[dof] == ARMATURE and m.dof_frictionloss[dof] == FRICTION
        assert m.dof_damping[dof] == 0.0  # the damping is the servo's kv, as IsaacGymEnvs' drive damping
    moving = [b for b in range(m.nbody) if m.body_weldid[b] != 0]
    assert len(moving) == 20 and all(m.body_gravcomp[b] == 1.0 for b in moving)  # IGE: hand gravity off


# ------------------------------------------------------------------------------------------------- contacts
def test_primitive_shapes_and_a_contact_free_zero_pose(model):
    m = model
    assert_primitive_hand_without_self_contacts(m, {mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CAPSULE})
    assert {m.body(int(b)).name for b in m.geom_bodyid} == {m.body(b).name for b in range(1, m.nbody)}

    # Every hand geom made to touch every other: only the links seated in the palm overlap it (the pairs the
    # menagerie model excludes); no two fingers and no finger and the palm face touch, at zero and at IsaacGymEnvs'
    # start (thumb joint 0 at its lower limit, as Isaac Lab's ALLEGRO_HAND_CFG).
    m2, d2 = all_colliding(ALLEGRO)
    seated = {"index_link_0", "middle_link_0", "ring_link_0", "thumb_link_0", "thumb_link_1"}
    for thumb_0 in (0.0, RANGES[12][0]):
        d2.qpos[:] = 0
        d2.qpos[m2.joint("thumb_joint_0").qposadr[0]] = thumb_0
        mujoco.mj_forward(m2, d2)
        pairs = {frozenset(m2.body(int(m2.geom_bodyid[g])).name for g in c.geom) for c in d2.contact[: d2.ncon]}
        assert all(len(p) == 2 and "palm" in p and (p - {"palm"}) <= seated for p in pairs), pairs


def test_a_cube_dropped_on_the_upturned_palm_comes_to_rest_there():
    """IsaacGymEnvs' hand pose and cube (0.065 m, density 400: 0.110 kg), 2 s at its physics step 1/120 s
    (dt 1/60, 2 substeps), zero joint targets; the elliptic cone with impratio 10 of in-hand MuJoCo scenes (the
    pyramidal cone at impratio 1 lets the cube creep about 1 mm/s down the 5.4 deg slope of the palm)."""
    # the palm face (+x side of the palm box) in the world, from the hand's pose written out here
    world = pose(quat_matrix(*IGE_HAND_QUAT), IGE_HAND_POS) @ menagerie_palm()
    normal = world[:3, :3] @ [1, 0, 0]
    face = (world @ [0.0111, 0, -0.0475, 1])[:3]  # box centre x -0.0093 + half size 0.0204
    half = CUBE_SIDE / 2
    m = hand_and_cube(ALLEGRO, "palm", (IGE_HAND_POS, IGE_HAND_QUAT), face + normal * (half + 0.02),  # 2 cm above
                      CUBE_SIDE, CUBE_DENSITY)
    d = mujoco.MjData(m)
    assert m.body("cube").mass[0] == pytest.approx(0.110, abs=5e-4)
    assert normal[2] > 0.99
    cube_id, lowest = m.body("cube").id, np.inf
    for _ in range(240):
        d.ctrl[:] = 0  # clamped to each ctrlrange: thumb joint 0 holds its lower limit
        mujoco.mj_step(m, d)
        lowest = min(lowest, (d.xpos[cube_id] - face) @ normal)
    # Soft contacts let the cube sink into the palm briefly at impact (measured 0.5 mm); 2 mm allows that and is
    # far from a cube that slides off the palm, whose centre drops below the face by more than its half side.
    assert lowest > half - 0.002
    assert np.linalg.norm(d.qvel[-6:-3]) < 1e-3 and np.linalg.norm(d.qvel[-3:]) < 1e-2  # at rest
    local = world[:3, :3].T @ (d.xpos[cube_id] - face)  # from the face centre; y across the palm, z along it
    assert abs(local[1]) < 0.0565 and abs(local[2]) < 0.0475  # centre over the palm face (its half sizes)
    # It lies on the palm and leans on the thumb's base, whose box stands 6 mm proud of the palm face over the
    # index half of the palm (the menagerie collision box), but on no finger.
    touching = {m.body(int(m.geom_bodyid[g])).name for c in d.contact[: d.ncon] for g in c.geom} - {"cube"}
    assert "palm" in touching and touching <= {"palm", "thumb_link_0", "thumb_link_1"}, touching
