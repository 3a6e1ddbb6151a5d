"""The motion library against the motion file itself and MuJoCo's kinematics of the AMP humanoid (issue 73)."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from isaacgymenvs_mw.tasks.amp.motion_library import JointGroup, MotionLibrary

ROOT = Path(__file__).resolve().parents[2]
MJCF = ROOT / "assets" / "mjcf" / "amp_humanoid.xml"
RUN = ROOT / "assets" / "amp" / "motions" / "amp_humanoid_run.npy"
KEYS = ["right_hand", "left_hand", "right_foot", "left_foot"]


@pytest.fixture(scope="module")
def setup():
    m = mujoco.MjModel.from_xml_path(str(MJCF))
    groups: dict[str, list] = {}
    for j in range(1, m.njnt):
        groups.setdefault(m.body(int(m.jnt_bodyid[j])).name, []).append(tuple(float(v) for v in m.jnt_axis[j]))
    lib = MotionLibrary([RUN], [JointGroup(b, tuple(a)) for b, a in groups.items()], KEYS, "cpu")
    raw = np.load(RUN, allow_pickle=True).item()
    return m, lib, raw


def _kinematics(m, root_pos, root_rot, dof_pos):
    d = mujoco.MjData(m)
    d.qpos[:3], d.qpos[3:7], d.qpos[7:] = root_pos, root_rot, dof_pos
    mujoco.mj_kinematics(m, d)
    return d


def _xyzw_to_wxyz(q):
    return np.asarray(q)[..., [3, 0, 1, 2]]


def test_frames_reproduce_the_file(setup):
    m, lib, raw = setup
    fps = float(raw["fps"])
    frames = raw["rotation"]["arr"].shape[0]
    assert lib.lengths[0].item() == pytest.approx((frames - 1) / fps)
    idx = torch.tensor([0, 7, 40, frames - 1])
    s = lib.state(torch.zeros(4, dtype=torch.long), idx.float() / fps)
    root = raw["root_translation"]["arr"][idx.numpy()]
    np.testing.assert_allclose(s.root_pos.numpy(), root, atol=1e-5)
    q_file = _xyzw_to_wxyz(raw["rotation"]["arr"][idx.numpy(), 0])
    # the same rotation up to the quaternion's sign
    assert np.all(np.abs(np.sum(s.root_rot.numpy() * q_file, axis=-1)) > 1 - 1e-5)
    np.testing.assert_allclose(s.root_vel.numpy(), raw["global_velocity"]["arr"][idx.numpy(), 0], atol=1e-5)
    for k in range(4):
        # the joint coordinates, put into MuJoCo, give every body the local rotation the file holds
        d = _kinematics(m, s.root_pos[k].numpy(), s.root_rot[k].numpy(), s.dof_pos[k].numpy())
        names = raw["skeleton_tree"]["node_names"]
        parents = raw["skeleton_tree"]["parent_indices"]["arr"]
        for j in range(1, len(names)):
            b, p = m.body(names[j]).id, m.body(names[int(parents[j])]).id
            local = np.zeros(4)
            neg = np.zeros(4)
            mujoco.mju_negQuat(neg, d.xquat[p])
            mujoco.mju_mulQuat(local, neg, d.xquat[b])
            want = _xyzw_to_wxyz(raw["rotation"]["arr"][int(idx[k]), j])
            assert abs(np.dot(local, want / np.linalg.norm(want))) > 1 - 1e-5, names[j]
        key_ids = [m.body(n).id for n in KEYS]
        np.testing.assert_allclose(d.xpos[key_ids], s.key_pos[k].numpy(), atol=1e-5)


def _slerp(q0, q1, a):
    q0, q1 = q0 / np.linalg.norm(q0), q1 / np.linalg.norm(q1)
    if np.dot(q0, q1) < 0:
        q1 = -q1
    omega = np.arccos(np.clip(np.dot(q0, q1), -1, 1))
    return (np.sin((1 - a) * omega) * q0 + np.sin(a * omega) * q1) / np.sin(omega)


def _axis_quat(angle, axis):
    q = np.zeros(4)
    q[0], q[1 + axis] = np.cos(angle / 2), np.sin(angle / 2)
    return q


def test_interpolation_between_frames(setup):
    m, lib, raw = setup
    fps = float(raw["fps"])
    rot = raw["rotation"]["arr"].astype(np.float64)
    # the frame pair over which the root turns most, so that a lerp would differ from a slerp
    turn = np.abs(np.sum(rot[1:, 0] * rot[:-1, 0], axis=-1))
    i, a = int(np.argmin(turn)), 0.3
    s = lib.state(torch.zeros(1, dtype=torch.long), torch.tensor([(i + a) / fps]))
    p0, p1 = raw["root_translation"]["arr"][i], raw["root_translation"]["arr"][i + 1]
    np.testing.assert_allclose(s.root_pos[0].numpy(), (1 - a) * p0 + a * p1, atol=1e-5)
    want = _slerp(_xyzw_to_wxyz(rot[i, 0]), _xyzw_to_wxyz(rot[i + 1, 0]), a)
    assert abs(np.dot(s.root_rot[0].numpy(), want)) == pytest.approx(1.0, abs=1e-5)
    # the right hip's three hinge angles compose (x, then y, then z) to the slerped local rotation of the thigh
    node = raw["skeleton_tree"]["node_names"].index("right_thigh")
    first = [m.joint(j).name for j in range(1, m.njnt)].index("right_hip_x")
    ax, ay, az = s.dof_pos[0, first:first + 3].double().numpy()
    got = np.zeros(4)
    tmp = np.zeros(4)
    mujoco.mju_mulQuat(tmp, _axis_quat(ax, 0), _axis_quat(ay, 1))
    mujoco.mju_mulQuat(got, tmp, _axis_quat(az, 2))
    want = _slerp(_xyzw_to_wxyz(rot[i, node]), _xyzw_to_wxyz(rot[i + 1, node]), a)
    assert abs(np.dot(got, want)) == pytest.approx(1.0, abs=1e-5)
    # velocities are the earlier frame's
    np.testing.assert_allclose(s.root_ang_vel[0].numpy(), raw["global_angular_velocity"]["arr"][i, 0], atol=1e-5)


def test_dof_velocity_is_the_frame_difference(setup):
    _, lib, raw = setup
    fps = float(raw["fps"])
    ids = torch.zeros(2, dtype=torch.long)
    s = lib.state(ids, torch.tensor([30.0, 31.0]) / fps)
    diff = torch.atan2(torch.sin(s.dof_pos[1] - s.dof_pos[0]), torch.cos(s.dof_pos[1] - s.dof_pos[0]))
    torch.testing.assert_close(s.dof_vel[0], diff * fps, atol=1e-3, rtol=1e-4)


def test_sampled_times_lie_in_the_clip(setup):
    _, lib, _ = setup
    ids = lib.sample_motions(500)
    assert (ids == 0).all()
    t = lib.sample_times(ids)
    assert (t >= 0).all() and (t <= lib.lengths[0]).all() and t.std() > 0.2
