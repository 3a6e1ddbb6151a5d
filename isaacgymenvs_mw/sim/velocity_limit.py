"""A cap on the angular speed of free bodies, IsaacGym's ``asset_options.max_angular_velocity``.

PhysX clamps each rigid body's angular velocity to a maximum (IsaacGym's ``AssetOptions.max_angular_velocity``,
64 rad/s unless an asset says otherwise); MuJoCo has no such limit. Ports of tasks that rely on it (a rotor-driven
body, an object flicked by fingers) otherwise clamp by hand. Here a small Warp kernel scales the angular part of each
limited free joint's velocity, ``w <- w * min(1, limit / |w|)`` (direction kept), after every ``mjw.step`` of the
captured physics graph, so the cap holds at the physics rate as PhysX's does. A free joint's angular velocity in
``qvel`` is in the body frame; its norm, which is what is capped, is the same in any frame.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import warp as wp

import mujoco


@wp.kernel
def _cap_angular_speed(dofadr: wp.array[int], limit: wp.array[float], qvel: wp.array2d[float]):
    world, k = wp.tid()
    a = dofadr[k] + 3  # a free joint's dofs: linear velocity (3), then angular velocity (3)
    w = wp.vec3(qvel[world, a], qvel[world, a + 1], qvel[world, a + 2])
    speed = wp.length(w)
    if speed > limit[k]:
        scale = limit[k] / speed
        qvel[world, a] = w[0] * scale
        qvel[world, a + 1] = w[1] * scale
        qvel[world, a + 2] = w[2] * scale


class AngularSpeedLimit:
    """The free joints of ``limits`` ({joint index: rad/s}; a free joint often has no name) and the kernel that caps
    their angular speed."""

    def __init__(self, mj_model: mujoco.MjModel, data, num_worlds: int, limits: Mapping[int, float]) -> None:
        dofadr, caps = [], []
        for joint, limit in limits.items():
            if int(mj_model.jnt_type[joint]) != int(mujoco.mjtJoint.mjJNT_FREE):
                raise ValueError(f"angular speed limit on joint {joint}: only free joints have one")
            dofadr.append(int(mj_model.jnt_dofadr[joint]))
            caps.append(float(limit))
        device = data.qvel.device
        self._dofadr = wp.array(np.array(dofadr, dtype=np.int32), dtype=int, device=device)
        self._limit = wp.array(np.array(caps, dtype=np.float32), dtype=float, device=device)
        self._data, self._dim = data, (num_worlds, len(dofadr))
        self.joints = list(limits)

    def launch(self) -> None:
        wp.launch(_cap_angular_speed, dim=self._dim, inputs=[self._dofadr, self._limit], outputs=[self._data.qvel])


def free_joint_speed_limits(mj_model: mujoco.MjModel, by_prefix: Mapping[str, float]) -> dict[int, float]:
    """{free joint index: rad/s} from {asset name prefix ('' for the main asset): rad/s}: each free joint of the compiled
    model belongs to the asset whose prefix its body's name starts with (the longest such; the main asset's names
    have none)."""
    if not by_prefix:
        return {}
    prefixes = sorted((p for p in by_prefix if p), key=len, reverse=True)
    out: dict[int, float] = {}
    for j in range(mj_model.njnt):
        if int(mj_model.jnt_type[j]) != int(mujoco.mjtJoint.mjJNT_FREE):
            continue
        body = mj_model.body(int(mj_model.jnt_bodyid[j])).name
        owner = next((p for p in prefixes if body.startswith(p)), "")
        if owner in by_prefix:
            out[j] = float(by_prefix[owner])
    return out
