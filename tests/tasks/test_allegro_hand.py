"""Allegro Hand MJCF (issues 34 and 69, the robot model): fingertip positions against a forward-kinematics product of
IsaacGymEnvs' allegro_touch_sensor.urdf joint origins written here in numpy, masses / joint ranges / drive gains against the
IsaacGymEnvs URDF and task figures, a contact-free zero pose, and a 0.065 m cube dropped onto the upturned palm
coming to rest there, all in MuJoCo C."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
from hand_kinematics import (
    all_colliding,
    assert_primitive_hand_without_self_contacts,
    hand_and_cube,
    pose,
    posed,
)

ALLEGRO = Path(__file__).resolve().parents[2] / "assets" / "mjcf" / "allegro_hand.xml"
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


def rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF origin rotation: fixed-axis roll, pitch, yaw."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


# IsaacGymEnvs assets/urdf/kuka_allegro_description/allegro_touch_sensor.urdf (@aeed298): joint origins (xyz, rpy)
MOUNT_TO_PALM = ((-0.008219, -0.02063, 0.08086), (0.0, -1.5708, 0.785398))  # allegro_mount -> palm_link
ROOTS = {  # *_joint_0 origin in palm_link
    "index": ((0.0514302, -0.03632, -0.0113), (3.1415, -1.57075, -0.0872638888889)),
    "middle": ((0.0537375, 0.0087771, -0.0113), (3.1415, -1.57075, 0.0)),
    "ring": ((0.0514302, 0.0538749, -0.0113), (3.1415, -1.57075, 0.0872638888889)),
    "thumb": ((-0.0367482, -0.0081281, -0.0295), (-1.57075, -1.57075, 1.48348611111)),
}
FINGER_JOINT_1 = (3.1415, -1.57075, 1.57075)  # *_joint_1 rpy, xyz 0
THUMB_JOINT_1 = ((0.005, 0.0, 0.0), (1.57075, 0.0, 0.0))
THUMB_JOINT_2 = ((0.0, 0.0, 0.0554), (3.1415, -1.57075, 0.0))
# the sites: the far end of the tip meshes (touch_sensor_tip.obj x max 0.0622, touch_sensor_thumb_tip.obj 0.0771)
FINGER_TIP, THUMB_TIP = (0.0622, 0.0054, 0.0), (0.0771, 0.00515, 0.0)


def palm_link() -> np.ndarray:
    """Pose of the URDF palm_link in the hand root (allegro_mount) frame."""
    return pose(rpy(*MOUNT_TO_PALM[1]), MOUNT_TO_PALM[0])


def fingertip(finger: str, q) -> np.ndarray:
    """Fingertip site position in the hand root frame: the product of the URDF chain, every joint about its z."""
    pos, angles = ROOTS[finger]
    t = palm_link() @ pose(rpy(*angles), pos) @ pose(rot_z(q[0]))
    if finger == "thumb":
        t = t @ pose(rpy(*THUMB_JOINT_1[1]), THUMB_JOINT_1[0]) @ pose(rot_z(q[1]))
        t = t @ pose(rpy(*THUMB_JOINT_2[1]), THUMB_JOINT_2[0]) @ pose(rot_z(q[2]))
        t = t @ pose(p=(0.0514, 0, 0)) @ pose(rot_z(q[3]))
        return (t @ pose(p=THUMB_TIP))[:3, 3]
    t = t @ pose(rpy(*FINGER_JOINT_1)) @ pose(rot_z(q[1])) @ pose(p=(0.054, 0, 0)) @ pose(rot_z(q[2]))
    t = t @ pose(p=(0.0384, 0, 0)) @ pose(rot_z(q[3]))
    return (t @ pose(p=FINGER_TIP))[:3, 3]


# IsaacGymEnvs allegro_touch_sensor.urdf joint limits (reference manipulation.md F.2.2, rad)
FINGER_RANGES = [(-0.5585, 0.5585), (-0.2792, 1.7278), (-0.2792, 1.7278), (-0.2792, 1.7278)]
THUMB_RANGES = [(0.2792, 1.5708), (-0.3316, 1.1519), (-0.2792, 1.7278), (-0.2792, 1.7627)]
RANGES = FINGER_RANGES * 3 + THUMB_RANGES
# IsaacGymEnvs URDF masses (F.2.3, kg): link 0, 1, 2, 3 with its fixed tip (0.021) merged in; palm 0.4154 with the
# fixed mount 0.05
FINGER_MASSES = (0.0119, 0.065, 0.0355, 0.0096 + 0.021)
THUMB_MASSES = (0.0176, 0.0119, 0.038, 0.0388 + 0.021)
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
    base, end = d.xpos[m.body("middle_link_1").id], d.xpos[m.body("middle_link_3").id]
    axis = (end - base) / np.linalg.norm(end - base)
    # straight finger along the root's +z, to the URDF's rounded pi (3.1415, 1.57075)
    np.testing.assert_allclose(axis, [0, 0, 1], atol=3e-4)
    np.testing.assert_allclose(np.linalg.norm(end - base), 0.054 + 0.0384, atol=1e-9)
    palm_normal = d.geom_xmat[m.geom("palm_collision").id].reshape(3, 3)[:, 2]  # palm_link z: the palm mesh's top
    np.testing.assert_allclose(palm_normal, [-math.sqrt(0.5), -math.sqrt(0.5), 0], atol=3e-4)
    world = quat_matrix(*IGE_HAND_QUAT)
    assert (world @ palm_normal)[2] > 0.99  # palm up: R_y(pi) R_x(0.47 pi) R_z(pi/4) tilts it 5.4 deg
    assert (world @ axis)[1] < -0.99  # fingers towards world -y, where IsaacGymEnvs puts the cube


# ------------------------------------------------------------------------------------------------- parameters
def test_masses_equal_the_urdf_masses(model):
    m = model
    assert m.body("palm").mass[0] == pytest.approx(PALM_MASS + MOUNT_MASS, abs=1e-12)
    for finger in FINGERS:
        table = THUMB_MASSES if finger == "thumb" else FINGER_MASSES
        bodies = [f"{finger}_link_{i}" for i in range(4)]
        for body, mass in zip(bodies, table):
            assert m.body(body).mass[0] == pytest.approx(mass, abs=1e-12), body
    assert m.body_mass.sum() == pytest.approx(TOTAL_MASS, abs=5e-4)  # 1.0217, the reference rounds to 1.022
    assert m.nbody == 1 + 1 + 4 * 4


def test_inertias_are_uniform_solids_of_the_collision_shapes(model):
    """Each geom a uniform box (or cylinder) of its mass; a body's inertia about its centre of mass is their sum
    moved there (parallel axes): the formulas written out here."""
    m = model
    for b in range(1, m.nbody):
        geoms = [g for g in range(m.ngeom) if m.geom_bodyid[g] == b]
        masses = [GEOM_MASSES[m.geom(g).name] for g in geoms]
        assert sum(masses) == pytest.approx(m.body_mass[b], abs=1e-12)
        com = sum(mass * m.geom_pos[g] for g, mass in zip(geoms, masses)) / sum(masses)
        np.testing.assert_allclose(m.body_ipos[b], com, atol=1e-12)
        expected = np.zeros((3, 3))
        for g, mass in zip(geoms, masses):
            size = m.geom_size[g]
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
                a2 = size**2
                local = mass / 3 * np.array([a2[1] + a2[2], a2[0] + a2[2], a2[0] + a2[1]])
            else:  # cylinder: radius, half height
                r, h = size[0], size[1]
                local = mass * np.array([(3 * r * r + 4 * h * h) / 12] * 2 + [r * r / 2])
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, m.geom_quat[g])
            rot = rot.reshape(3, 3)
            c = m.geom_pos[g] - com
            expected += rot @ np.diag(local) @ rot.T + mass * (c @ c * np.eye(3) - np.outer(c, c))
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, m.body_iquat[b])
        rot = rot.reshape(3, 3)
        inertia = rot @ np.diag(m.body_inertia[b]) @ rot.T  # principal axes back into the body frame
        np.testing.assert_allclose(inertia, expected, rtol=1e-6, atol=1e-12, err_msg=m.body(b).name)


# each geom's mass in the file (the URDF link masses; MuJoCo keeps only the bodies' sums)
GEOM_MASSES = {"mount_collision": MOUNT_MASS, "palm_collision": PALM_MASS,
               **{f"{f}_link_{i}_collision": mass for f in FINGERS[:3] for i, mass in
                  enumerate((0.0119, 0.065, 0.0355, 0.0096))},
               **{f"thumb_link_{i}_collision": mass for i, mass in enumerate((0.0176, 0.0119, 0.038, 0.0388))},
               **{f"{f}_tip_collision": 0.021 for f in FINGERS}}


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
    assert len(moving) == 16 and all(m.body_gravcomp[b] == 1.0 for b in moving)  # IGE: hand gravity off


# ------------------------------------------------------------------------------------------------- contacts
def test_primitive_shapes_and_a_contact_free_zero_pose(model):
    m = model
    assert_primitive_hand_without_self_contacts(m, {mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CYLINDER})
    assert {m.body(int(b)).name for b in m.geom_bodyid} == {m.body(b).name for b in range(1, m.nbody)}

    # Every hand geom made to touch every other: only links seated in the palm overlap its box (the bounding box of
    # the URDF palm mesh, whose hull the finger roots sit in); no two fingers and no finger and the wrist mount touch,
    # at zero and at IsaacGymEnvs' start (thumb joint 0 at its lower limit, as Isaac Lab's ALLEGRO_HAND_CFG).
    m2, d2 = all_colliding(ALLEGRO)
    seated = {"index_link_0", "index_link_1", "middle_link_0", "ring_link_0", "ring_link_1", "thumb_link_0",
              "thumb_link_1", "thumb_link_2"}
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
    # the palm face (the top of the palm box, palm_link z = 0) in the world, from the hand's pose written out here
    world = pose(quat_matrix(*IGE_HAND_QUAT), IGE_HAND_POS) @ palm_link()
    normal = world[:3, :3] @ [0, 0, 1]
    face = (world @ [-0.0078, 0.00875, 0.0, 1])[:3]  # the palm mesh's bounding box: x -0.0579..0.0423, y -0.0499..0.0674
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
    local = world[:3, :3].T @ (d.xpos[cube_id] - face)  # from the face centre; x along the hand, y across it
    assert abs(local[0]) < 0.0501 and abs(local[1]) < 0.05865  # centre over the palm face (its half sizes)
    touching = {m.body(int(m.geom_bodyid[g])).name for c in d.contact[: d.ncon] for g in c.geom} - {"cube"}
    assert "palm" in touching and touching <= {"palm", "thumb_link_0", "thumb_link_1", "thumb_link_2"}, touching
