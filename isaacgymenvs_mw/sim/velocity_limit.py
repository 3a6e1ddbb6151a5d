"""IsaacGym's velocity rules for free bodies: damping (``asset_options.linear_damping`` / ``angular_damping``) and a cap
on the angular speed (``asset_options.max_angular_velocity``).

PhysX damps each rigid body's velocity every step, ``v <- v * max(0, 1 - c dt)`` with its linear and angular
coefficients (IsaacGym's asset defaults: 0 and 0.5), then clamps its angular velocity to a maximum (64 rad/s unless an
asset says otherwise): PhysX 4's ``bodyCoreComputeUnconstrainedVelocity`` (lowleveldynamics/src/DyBodyCoreIntegrator.h
of the PhysX 4 SDK, as vendored in bulletphysics/bullet3 under src/PhysX). MuJoCo has neither. Ports of tasks
that rely on them (a ball that slows as it rolls, a rotor-driven body, an object flicked by fingers) otherwise differ.
Here a small Warp kernel applies both to each listed free joint's velocity after every ``mjw.step`` of the captured
physics graph, so they hold at the physics rate as PhysX's do: the linear part times its factor, the angular part
times its factor, then ``w <- w * min(1, limit / |w|)`` (direction kept). A free joint's angular velocity in ``qvel``
is in the body frame; its norm, and a uniform scaling of it, are the same in any frame. PhysX damps before its solver
and MuJoCo's step solves first, so the two orders differ by terms of order dt.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import warp as wp

import mujoco


NO_CAP = float(np.finfo(np.float32).max)  # the limit of a joint that is damped but not capped


@wp.kernel
def _free_body_velocity(dofadr: wp.array[int], keep_linear: wp.array[float], keep_angular: wp.array[float],
                        limit: wp.array[float], qvel: wp.array2d[float]):
    world, k = wp.tid()
    a = dofadr[k]  # a free joint's dofs: linear velocity (3), then angular velocity (3)
    for i in range(3):
        qvel[world, a + i] = qvel[world, a + i] * keep_linear[k]
    w = wp.vec3(qvel[world, a + 3], qvel[world, a + 4], qvel[world, a + 5]) * keep_angular[k]
    speed = wp.length(w)
    if speed > limit[k]:
        w = w * (limit[k] / speed)
    qvel[world, a + 3] = w[0]
    qvel[world, a + 4] = w[1]
    qvel[world, a + 5] = w[2]


class FreeBodyVelocity:
    """The free joints of ``caps`` ({joint index: rad/s}) and ``damping`` ({joint index: (linear, angular)
    coefficient, 1/s}; a free joint often has no name), and the kernel that damps and caps their velocity."""

    def __init__(self, mj_model: mujoco.MjModel, data, num_worlds: int, caps: Mapping[int, float],
                 damping: Mapping[int, tuple[float, float]]) -> None:
        dt = float(mj_model.opt.timestep)
        self.joints = sorted(set(caps) | set(damping))
        dofadr, keep, limits = [], [], []
        for joint in self.joints:
            if int(mj_model.jnt_type[joint]) != int(mujoco.mjtJoint.mjJNT_FREE):
                raise ValueError(f"velocity damping or cap on joint {joint}: only free joints have them")
            dofadr.append(int(mj_model.jnt_dofadr[joint]))
            linear, angular = damping.get(joint, (0.0, 0.0))
            keep.append([max(0.0, 1.0 - linear * dt), max(0.0, 1.0 - angular * dt)])  # PhysX's factor per step
            limits.append(float(caps.get(joint, NO_CAP)))
        device = data.qvel.device
        keep_arr = np.array(keep, dtype=np.float32).reshape(-1, 2)
        self._inputs = [wp.array(np.array(dofadr, dtype=np.int32), dtype=int, device=device),
                        wp.array(keep_arr[:, 0].copy(), dtype=float, device=device),
                        wp.array(keep_arr[:, 1].copy(), dtype=float, device=device),
                        wp.array(np.array(limits, dtype=np.float32), dtype=float, device=device)]
        self._data, self._dim = data, (num_worlds, len(dofadr))

    def launch(self) -> None:
        wp.launch(_free_body_velocity, dim=self._dim, inputs=self._inputs, outputs=[self._data.qvel])


def free_joint_speed_limits(mj_model: mujoco.MjModel, by_prefix: Mapping[str, float]) -> dict[int, float]:
    """{free joint index: rad/s} from {asset name prefix ('' for the main asset): rad/s} (``free_joints_of``)."""
    return {j: float(v) for j, v in free_joints_of(mj_model, by_prefix).items()}


def free_joint_damping(mj_model: mujoco.MjModel,
                       by_prefix: Mapping[str, tuple[float, float]]) -> dict[int, tuple[float, float]]:
    """{free joint index: (linear, angular) damping} from {asset name prefix: (linear, angular)} (``free_joints_of``)."""
    return {j: (float(v[0]), float(v[1])) for j, v in free_joints_of(mj_model, by_prefix).items()}


def free_joints_of(mj_model: mujoco.MjModel, by_prefix: Mapping[str, object]) -> dict[int, object]:
    """{free joint index: value} from {asset name prefix ('' for the main asset): value}: each free joint of the
    compiled model belongs to the asset whose prefix its body's name starts with (the longest such; the main asset's
    names have none)."""
    if not by_prefix:
        return {}
    prefixes = sorted((p for p in by_prefix if p), key=len, reverse=True)
    out: dict[int, object] = {}
    for j in range(mj_model.njnt):
        if int(mj_model.jnt_type[j]) != int(mujoco.mjtJoint.mjJNT_FREE):
            continue
        body = mj_model.body(int(mj_model.jnt_bodyid[j])).name
        owner = next((p for p in prefixes if body.startswith(p)), "")
        if owner in by_prefix:
            out[j] = by_prefix[owner]
    return out
