"""Actuator realism for position drives: a DC motor's torque-speed limit, applied at every physics step.

A DC motor's available torque falls linearly with speed (back-EMF): with saturation (stall) torque tau_sat, a
continuous torque limit tau_lim and no-load speed qd_max, the force a drive may apply at joint speed qd is

    tau_max(qd) = clip(tau_sat * ( 1 - qd / qd_max), 0, tau_lim)
    tau_min(qd) = clip(tau_sat * (-1 - qd / qd_max), -tau_lim, 0)
    tau = clip(tau_PD, tau_min(qd), tau_max(qd))

(the four-quadrant form of Isaac Lab's ``DCMotor`` actuator model, https://isaac-sim.github.io/IsaacLab/main/
source/api/lab/isaaclab.actuators.html: driving with the motion the limit shrinks to 0 at qd_max, braking against it
the motor may apply up to tau_lim). MuJoCo clamps an actuator's force to ``actuator_forcerange`` inside each physics
step, so a small Warp kernel writes each world's range from its current joint speeds before every ``mjw.step`` of
the captured physics graph: the PD law keeps running at the physics rate and the limit follows the speed.
"""

from __future__ import annotations

import numpy as np
import torch
import warp as wp

import mujoco


@wp.kernel
def _torque_speed_range(
    dofadr: wp.array[int],
    saturation: wp.array2d[float],
    limit: wp.array2d[float],
    speed: wp.array2d[float],
    qvel: wp.array2d[float],
    forcerange: wp.array2d[wp.vec2],
):
    world, act = wp.tid()
    qd = qvel[world, dofadr[act]]
    tau_sat = saturation[world, act]
    tau_lim = limit[world, act]
    ratio = qd / speed[world, act]
    upper = wp.clamp(tau_sat * (1.0 - ratio), 0.0, tau_lim)
    lower = wp.clamp(tau_sat * (-1.0 - ratio), -tau_lim, 0.0)
    forcerange[world, act] = wp.vec2(lower, upper)


class TorqueSpeedLimit:
    """Per-world, per-actuator DC-motor parameters and the kernel that turns them into force ranges.

    ``saturation``, ``limit`` and ``speed`` are (num_worlds, nu) torch views that randomisation may rewrite in
    place. Actuators without a limit carry ``inf`` (their range stays open).
    """

    def __init__(self, mj_model: mujoco.MjModel, model, data, num_worlds: int, device: torch.device,
                 saturation: np.ndarray, limit: np.ndarray, speed: np.ndarray) -> None:
        if model.actuator_forcerange.shape[0] != num_worlds:
            raise ValueError("the torque-speed limit needs actuator_forcerange batched per world")
        nu = mj_model.nu
        joint = mj_model.actuator_trnid[:, 0]
        self._dofadr = wp.array(mj_model.jnt_dofadr[joint].astype(np.int32), dtype=int, device=model.qpos0.device)

        def per_world(values: np.ndarray) -> wp.array:
            rows = np.tile(np.asarray(values, dtype=np.float32).reshape(1, nu), (num_worlds, 1))
            return wp.array(rows, dtype=float, device=model.qpos0.device)

        self._arrays = [per_world(saturation), per_world(limit), per_world(speed)]
        self.saturation, self.limit, self.speed = (wp.to_torch(a) for a in self._arrays)
        self._model, self._data, self._dim = model, data, (num_worlds, nu)

    def launch(self) -> None:
        wp.launch(_torque_speed_range, dim=self._dim,
                  inputs=[self._dofadr, *self._arrays, self._data.qvel],
                  outputs=[self._model.actuator_forcerange])
