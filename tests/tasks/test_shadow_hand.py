"""Shadow Dexterous Hand MJCF (issue 47, the robot model): fingertip positions and fingertip-body frames against a
forward-kinematics product of the published link offsets and joint axes written here in numpy, the J1 = J2
coupling of the four fingers under MuJoCo C's mj_step, masses / joint ranges / servo gains against the published
figures, a contact-free zero pose, and a 0.05 m cube dropped onto the upturned palm in IsaacGymEnvs' layout coming to
rest there."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from hand_kinematics import all_colliding, assert_primitive_hand_without_self_contacts, hand_and_cube, pose, posed

SHADOW = Path(__file__).resolve().parents[2] / "assets" / "mjcf" / "shadow_hand.xml"
FINGERS = ("ff", "mf", "rf", "lf")
JOINTS = (["WRJ2", "WRJ1"] + [f"{f.upper()}J{i}" for f in ("ff", "mf", "rf") for i in (4, 3, 2, 1)]
          + [f"LFJ{i}" for i in (5, 4, 3, 2, 1)] + [f"THJ{i}" for i in (5, 4, 3, 2, 1)])


# ------------------------------------------------------------------------------------------------- reference data
def rot(axis, angle: float) -> np.ndarray:
    """Rotation by ``angle`` about the unit ``axis`` (Rodrigues' formula)."""
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * cross + (1 - math.cos(angle)) * cross @ cross


def joint(axis, angle: float) -> np.ndarray:
    return pose(rot(axis, angle))


X, Y, Z = (1, 0, 0), (0, 1, 0), (0, 0, 1)
# Published offsets (menagerie shadow_hand/right_hand.xml @0498058, m): knuckle on the palm, J4 axis
KNUCKLES = {"ff": ((0.033, 0, 0.095), (0, -1, 0)), "mf": ((0.011, 0, 0.099), (0, -1, 0)),
            "rf": ((-0.011, 0, 0.095), (0, 1, 0))}
LF_METACARPAL, LF_KNUCKLE, LFJ5_AXIS = (-0.033, 0, 0.02071), 0.06579, (0.573576, 0, 0.819152)
PROXIMAL, MIDDLE = 0.045, 0.025       # J3 -> J2, J2 -> J1
FINGER_TIP, THUMB_TIP = 0.026, 0.0275  # distal joint -> fingertip (Shadow's distal phalanx lengths)
THUMB_BASE, THUMB_HUB, THUMB_MIDDLE = (0.034, -0.00858, 0.029), 0.038, 0.032


def palm(q: dict[str, float]) -> np.ndarray:
    """Palm frame in the forearm frame: wrist 0.21301 up, turned 90 deg about z, WRJ2 about y, palm 0.034, WRJ1."""
    t = pose(rot(Z, math.pi / 2), (0.01, 0, 0.21301)) @ joint(Y, q["WRJ2"])
    return t @ pose(p=(0, 0, 0.034)) @ joint(X, q["WRJ1"])


def finger(name: str, q: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(distal frame, fingertip position) of a finger in the forearm frame."""
    f = name.upper()
    if name == "lf":
        t = palm(q) @ pose(p=LF_METACARPAL) @ joint(LFJ5_AXIS, q["LFJ5"]) @ pose(p=(0, 0, LF_KNUCKLE))
        t = t @ joint(Y, q["LFJ4"])
    else:
        pos, axis = KNUCKLES[name]
        t = palm(q) @ pose(p=pos) @ joint(axis, q[f"{f}J4"])
    t = t @ joint(X, q[f"{f}J3"]) @ pose(p=(0, 0, PROXIMAL)) @ joint(X, q[f"{f}J2"]) @ pose(p=(0, 0, MIDDLE))
    t = t @ joint(X, q[f"{f}J1"])
    return t, (t @ [0, 0, FINGER_TIP, 1])[:3]


def thumb(q: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    t = palm(q) @ pose(rot(Y, math.pi / 4), THUMB_BASE) @ joint((0, 0, -1), q["THJ5"]) @ joint(X, q["THJ4"])
    t = t @ pose(p=(0, 0, THUMB_HUB)) @ joint(X, q["THJ3"]) @ joint((0, -1, 0), q["THJ2"])
    t = t @ pose(rot(Z, -math.pi / 2), (0, 0, THUMB_MIDDLE)) @ joint(X, q["THJ1"])
    return t, (t @ [0, 0, THUMB_TIP, 1])[:3]


# Published joint ranges (rad)
RANGES = {"WRJ2": (-0.523599, 0.174533), "WRJ1": (-0.698132, 0.488692), "LFJ5": (0.0, 0.785398),
          "THJ5": (-1.0472, 1.0472), "THJ4": (0.0, 1.22173), "THJ3": (-0.20944, 0.20944),
          "THJ2": (-0.698132, 0.698132), "THJ1": (-0.261799, 1.5708)}
for _f in ("FF", "MF", "RF", "LF"):
    RANGES.update({f"{_f}J4": (-0.349066, 0.349066), f"{_f}J3": (-0.261799, 1.5708), f"{_f}J2": (0.0, 1.5708),
                   f"{_f}J1": (0.0, 1.5708)})
# Published masses (kg)
MASSES = {"forearm": 3.0, "wrist": 0.1, "palm": 0.3, "lfmetacarpal": 0.03, "thbase": 0.01, "thproximal": 0.04,
          "thhub": 0.005, "thmiddle": 0.02, "thdistal": 0.017}
for _f in FINGERS:
    MASSES.update({f"{_f}knuckle": 0.008, f"{_f}proximal": 0.03, f"{_f}middle": 0.017, f"{_f}distal": 0.013})
# Published servos: actuator -> (kp, force limit)
SERVOS = {"A_WRJ2": (10.0, 10.0), "A_WRJ1": (8.0, 5.0), "A_THJ5": (0.4, 3.0), "A_THJ4": (1.0, 2.0),
          "A_THJ3": (0.5, 1.0), "A_THJ2": (1.5, 1.0), "A_THJ1": (1.0, 1.0), "A_LFJ5": (1.0, 1.0)}
for _f in ("FF", "MF", "RF", "LF"):
    SERVOS.update({f"A_{_f}J4": (1.0, 1.0), f"A_{_f}J3": (1.0, 1.0), f"A_{_f}J0": (0.5, 1.0)})
# IsaacGymEnvs' action order (its actuated DOFs, in Shadow's names; J0 drives J2 with J1 coupled)
ACTUATORS = (["A_WRJ2", "A_WRJ1"] + [f"A_{f}J{i}" for f in ("FF", "MF", "RF") for i in (4, 3, 0)]
             + ["A_LFJ5", "A_LFJ4", "A_LFJ3", "A_LFJ0"] + [f"A_THJ{i}" for i in (5, 4, 3, 2, 1)])
# IsaacGymEnvs' ShadowHand layout: hand root at (0, 0, 0.5), cube (0.05 m, density 567) at root + (0, -0.39, 0.10);
# the task YAML places the forearm so that the palm face centre is under it (cfg/task/ShadowHand.yaml).
FOREARM_POS, FOREARM_QUAT = (0.011, -0.09799, 0.513), (0.5, 0.5, -0.5, 0.5)
CUBE_START, CUBE_SIDE, CUBE_DENSITY = (0.0, -0.39, 0.6), 0.05, 567.0


MODEL = mujoco.MjModel.from_xml_path(str(SHADOW))  # read only; a test that changes options compiles its own


# ------------------------------------------------------------------------------------------------- kinematics
def test_fingertips_and_distal_frames_equal_the_forward_kinematics_product():
    m = MODEL
    for values, d in posed(m, JOINTS, seed=47):
        q = dict(zip(JOINTS, values))
        for name in FINGERS + ("th",):
            frame, tip = thumb(q) if name == "th" else finger(name, q)
            # 3e-6: the file writes the thumb base's 45 deg turn as the published 6-digit quaternion
            np.testing.assert_allclose(d.site_xpos[m.site(f"{name}tip").id], tip, atol=3e-6, err_msg=name)
            body = m.body(f"{name}distal").id
            np.testing.assert_allclose(d.xpos[body], frame[:3, 3], atol=3e-6, err_msg=name)
            np.testing.assert_allclose(d.xmat[body].reshape(3, 3), frame[:3, :3], atol=3e-6, err_msg=name)
            np.testing.assert_allclose(d.site_xpos[m.site(f"{name}distal").id], d.xpos[body], atol=1e-12)


def test_palm_faces_up_and_fingers_point_to_minus_y_in_the_task_pose():
    m, d = MODEL, mujoco.MjData(MODEL)
    mujoco.mj_kinematics(m, d)
    world = np.zeros(9)
    mujoco.mju_quat2Mat(world, np.array(FOREARM_QUAT))
    world = world.reshape(3, 3)
    palm_axes = d.xmat[m.body("palm").id].reshape(3, 3)
    assert (world @ -palm_axes[:, 1])[2] == pytest.approx(1.0)   # the palm face (palm -y) looks up
    assert (world @ palm_axes[:, 2])[1] == pytest.approx(-1.0)   # fingers along world -y
    mf = d.site_xpos[m.site("mftip").id] - d.xpos[m.body("mfknuckle").id]
    assert np.linalg.norm(mf) == pytest.approx(PROXIMAL + MIDDLE + FINGER_TIP)  # a straight finger at zero


# ------------------------------------------------------------------------------------------------- coupling
def test_distal_joints_follow_the_middle_joints_and_j0_commands_their_sum():
    """MuJoCo C, 1/120 s steps: a J0 command c moves J2 and J1 together to c / 2 each (IGE's J2 target). The
    equality is a soft constraint (time constant 0.02 s, the shortest stable at this step): under a jump of the
    command across the range J1 lags J2 by up to a few hundredths of a radian (IGE's tendon allows 0.14), and
    agrees with it at rest."""
    spec = mujoco.MjSpec.from_file(str(SHADOW))
    spec.option.timestep = 1 / 120
    m = spec.compile()
    d = mujoco.MjData(m)
    act = {m.actuator(a).name: a for a in range(m.nu)}
    rng = np.random.default_rng(5)
    for _ in range(3):
        ctrl = rng.uniform(m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1])
        d.ctrl[:] = ctrl
        worst = 0.0
        for _ in range(240):  # 2 s
            mujoco.mj_step(m, d)
            for f in ("FF", "MF", "RF", "LF"):
                worst = max(worst, abs(d.joint(f"{f}J1").qpos[0] - d.joint(f"{f}J2").qpos[0]))
        assert worst < 0.05
        mujoco.mj_forward(m, d)  # actuator lengths of the final state
        for f in ("FF", "MF", "RF", "LF"):
            assert d.joint(f"{f}J1").qpos[0] == pytest.approx(d.joint(f"{f}J2").qpos[0], abs=1e-3), f
            target = ctrl[act[f"A_{f}J0"]] / 2
            assert d.joint(f"{f}J2").qpos[0] == pytest.approx(target, abs=0.02), f
            assert d.joint(f"{f}J1").qpos[0] == pytest.approx(target, abs=0.02), f
            assert d.actuator(f"A_{f}J0").length[0] == pytest.approx(
                d.joint(f"{f}J1").qpos[0] + d.joint(f"{f}J2").qpos[0], abs=1e-9)


# ------------------------------------------------------------------------------------------------- parameters
def test_masses_ranges_and_servos_equal_the_published_figures():
    m = MODEL
    assert (m.njnt, m.nq, m.nu, m.ntendon, m.neq) == (24, 24, 20, 4, 4)
    assert [m.joint(j).name for j in range(m.njnt)] == JOINTS
    assert [m.actuator(a).name for a in range(m.nu)] == ACTUATORS
    for body, mass in MASSES.items():
        assert m.body(body).mass[0] == pytest.approx(mass, abs=1e-12), body
    assert m.nbody == 1 + len(MASSES)
    assert m.body_mass.sum() == pytest.approx(3.794, abs=1e-9)
    for name, (lo, hi) in RANGES.items():
        j = m.joint(name)
        assert j.limited[0] and j.range.tolist() == pytest.approx([lo, hi], abs=1e-6), name
        assert m.dof_damping[j.dofadr[0]] == (0.5 if name.startswith("WR") else 0.05)
        assert m.dof_armature[j.dofadr[0]] == 0.0002 and m.dof_frictionloss[j.dofadr[0]] == 0.01
    for name, (kp, force) in SERVOS.items():
        a = m.actuator(name)
        assert a.gainprm[0] == kp and a.biasprm[:3].tolist() == [0.0, -kp, 0.0], name
        assert a.forcelimited[0] and a.forcerange.tolist() == [-force, force], name
        if name.endswith("J0"):  # the tendon J1 + J2: twice J2's range
            assert a.trntype[0] == mujoco.mjtTrn.mjTRN_TENDON
            assert a.ctrlrange.tolist() == pytest.approx([0.0, 2 * RANGES["FFJ2"][1]], abs=1e-4)
        else:
            assert a.ctrlrange.tolist() == pytest.approx(list(RANGES[name[2:]]), abs=1e-6), name
    moving = [b for b in range(m.nbody) if m.body_weldid[b] != 0]
    assert len(moving) == 24 and all(m.body_gravcomp[b] == 1.0 for b in moving)  # IGE: hand gravity off


def test_fingertip_force_torque_sensors_sit_on_the_distal_frames():
    m = MODEL
    assert m.nsensordata == 30
    for k, name in enumerate(f + "distal" for f in FINGERS + ("th",)):
        for j, kind in enumerate(("force", "torque")):
            s = m.sensor(f"{name}_{kind}")
            assert s.adr[0] == 6 * k + 3 * j and m.site(int(s.objid[0])).name == name
            assert m.site_bodyid[s.objid[0]] == m.body(name).id
            assert m.site_pos[s.objid[0]].tolist() == [0.0, 0.0, 0.0]


# ------------------------------------------------------------------------------------------------- contacts
def test_primitive_shapes_and_a_contact_free_zero_pose():
    geoms = mujoco.mjtGeom
    assert_primitive_hand_without_self_contacts(MODEL, {geoms.mjGEOM_BOX, geoms.mjGEOM_CAPSULE, geoms.mjGEOM_SPHERE})
    # Made to touch one another, no two digits (the four fingers and the thumb) touch at zero.
    m2, d2 = all_colliding(SHADOW)
    mujoco.mj_forward(m2, d2)
    for c in d2.contact[: d2.ncon]:
        pair = {m2.body(int(m2.geom_bodyid[g])).name for g in c.geom}
        digits = {name[:2] for name in pair if name[:2] in FINGERS + ("th",)}
        assert len(digits) < 2, pair  # links of one finger may touch (as the seated ones touch the palm)


def test_a_cube_dropped_on_the_upturned_palm_comes_to_rest_there():
    """IsaacGymEnvs' layout (hand root at z 0.5, the 0.05 m cube of density 567 let go at root + (0, -0.39, 0.10))
    with the forearm placed as the task YAML does: 2 s at the physics step 1/120 s, joints held at zero."""
    m = hand_and_cube(SHADOW, "forearm", (FOREARM_POS, FOREARM_QUAT), CUBE_START, CUBE_SIDE, CUBE_DENSITY)
    d = mujoco.MjData(m)
    assert m.body("cube").mass[0] == pytest.approx(0.0709, abs=1e-4)
    mujoco.mj_forward(m, d)
    g = m.geom("palm_collision").id
    face = d.geom_xpos[g] + d.geom_xmat[g].reshape(3, 3) @ [0, -0.012, 0]  # centre of the palm box's -y face
    np.testing.assert_allclose(face, [0.0, -0.39, 0.535], atol=1e-9)  # under the cube, 0.035 above the root
    cube_id = m.body("cube").id
    for _ in range(240):
        d.ctrl[:] = np.clip(0.0, m.actuator_ctrlrange[:, 0], m.actuator_ctrlrange[:, 1])
        mujoco.mj_step(m, d)
    assert np.linalg.norm(d.qvel[-6:]) < 1e-2  # at rest
    centre = d.xpos[cube_id]
    # It lies on the palm face, one edge raised on the thumb base, whose sphere (radius 13 mm) stands 9.6 mm proud
    # of the face (the thenar side): measured 4 mm above a flat rest; one that slid off would be far lower.
    assert face[2] + CUBE_SIDE / 2 - 0.001 < centre[2] < face[2] + CUBE_SIDE / 2 + 0.008
    assert abs(centre[0]) < 0.031 and -0.435 < centre[1] < -0.345  # over the palm box (62 x 90 mm)
    touching = {m.body(int(m.geom_bodyid[g])).name for c in d.contact[: d.ncon] for g in c.geom} - {"cube"}
    assert touching == {"palm", "thbase"}, touching
