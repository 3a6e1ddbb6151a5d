"""Shared pieces of the hand-model tests (Allegro, Shadow): homogeneous transforms, the joint configurations the
forward-kinematics products are compared at, and the collision-shape checks. Nothing here imports
isaacgymenvs_mw."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import mujoco
import numpy as np


def pose(r: np.ndarray | None = None, p=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4 x 4 transform of rotation ``r`` (identity if None) and translation ``p``."""
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = np.eye(3) if r is None else r, p
    return t


def joint_ranges(m: mujoco.MjModel, joints: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper limits of the named joints."""
    r = np.array([m.joint(n).range for n in joints])
    return r[:, 0], r[:, 1]


def sampled_configurations(m: mujoco.MjModel, joints: Sequence[str], seed: int, count: int = 20) -> list[np.ndarray]:
    """Zero, both limits, mid-range and ``count`` uniform draws inside the limits of the named joints."""
    lo, hi = joint_ranges(m, joints)
    rng = np.random.default_rng(seed)
    return [np.zeros(len(joints)), lo, hi, (lo + hi) / 2] + [rng.uniform(lo, hi) for _ in range(count)]


def posed(m: mujoco.MjModel, joints: Sequence[str], seed: int) -> Iterator[tuple[np.ndarray, mujoco.MjData]]:
    """For each of ``sampled_configurations``: the joint values and MuJoCo C's kinematics of the model there."""
    d = mujoco.MjData(m)
    adr = [int(m.jnt_qposadr[m.joint(n).id]) for n in joints]
    for q in sampled_configurations(m, joints, seed):
        d.qpos[adr] = q
        mujoco.mj_kinematics(m, d)
        yield q, d


def assert_primitive_hand_without_self_contacts(m: mujoco.MjModel, primitives: set[int]) -> None:
    """Collision shapes of the given primitive types only, hand geoms that touch objects but not one another
    (contype 2, conaffinity 1), and no contact at the zero pose."""
    assert m.nmesh == 0 and all(int(t) in primitives for t in m.geom_type)
    assert m.geom_contype.tolist() == [2] * m.ngeom and m.geom_conaffinity.tolist() == [1] * m.ngeom
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert d.ncon == 0


def all_colliding(path: Path) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The model of ``path`` with every geom made to touch every other (to see which shapes overlap)."""
    spec = mujoco.MjSpec.from_file(str(path))
    for g in spec.geoms:
        g.contype, g.conaffinity = 1, 1
    m = spec.compile()
    return m, mujoco.MjData(m)


def hand_and_cube(path: Path, root: str, pose_wxyz: tuple[Sequence[float], Sequence[float]], cube_pos: Sequence[float],
                  side: float, density: float) -> mujoco.MjModel:
    """The hand of ``path``, its ``root`` body placed at ``pose_wxyz`` (position, quaternion), and a free cube
    (body and geom "cube") at ``cube_pos``; physics step 1/120 s and the elliptic cone with impratio 10 of the
    in-hand tasks."""
    spec = mujoco.MjSpec.from_file(str(path))
    spec.option.timestep = 1 / 120
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10
    body = spec.body(root)
    body.pos, body.quat = pose_wxyz
    cube = spec.worldbody.add_body(name="cube", pos=cube_pos)
    cube.add_freejoint()
    cube.add_geom(name="cube", type=mujoco.mjtGeom.mjGEOM_BOX, size=[side / 2] * 3, density=density)
    return spec.compile()
