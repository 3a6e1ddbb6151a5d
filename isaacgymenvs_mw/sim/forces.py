"""External forces and torques on bodies, for one env step or until cleared (IsaacGymEnvs' force tensors).

MuJoCo's own input, ``xfrc_applied``, is a wrench at each body's centre of mass in world axes that persists until
overwritten, and it is fixed in world axes across the ``controlFrequencyInv`` physics steps of an env step. Tasks
ported from IsaacGymEnvs want more: a wrench in the body's own axes that turns with the body, a force at a point,
and forces that act for the coming env step only. ``BodyForces`` keeps those requests in its own buffers and, before
every physics step of the captured physics, a Warp kernel writes

    xfrc_applied = user's xfrc_applied + world wrench + R(body) @ body wrench

from the current body rotations. The user's ``xfrc_applied`` is saved before the physics steps and put back after
them, so direct writes to it keep their meaning (persistent, world frame).

Buffers, per world and body, (slot, world, body, term) vec3; slot 0 acts for one env step, slot 1 persists:
  term 0: world force; 1: world torque plus the moment of point forces about the world origin; 2: the sum of world
  forces applied at a point (the kernel subtracts com x that sum, giving torques about the current centre of mass);
  3: body-frame force; 4: body-frame torque about the centre of mass (point forces' moments included: the arm is
  fixed in the body, so the torque is constant in body axes).
"""

from __future__ import annotations

from typing import Sequence

import torch
import warp as wp

FRAMES = ("world", "body")
_WORLD_F, _WORLD_T, _POINT_F, _BODY_F, _BODY_T = range(5)


@wp.kernel
def _add_body_wrench(
    wrench: wp.array4d[wp.vec3],
    user: wp.array2d[wp.spatial_vector],
    xmat: wp.array2d[wp.mat33],
    xipos: wp.array2d[wp.vec3],
    xfrc: wp.array2d[wp.spatial_vector],
):
    world, body = wp.tid()
    rot = xmat[world, body]
    force = wp.vec3(0.0)
    torque = wp.vec3(0.0)
    for slot in range(2):
        force += wrench[slot, world, body, 0] + rot * wrench[slot, world, body, 3]
        torque += wrench[slot, world, body, 1] + rot * wrench[slot, world, body, 4]
        torque -= wp.cross(xipos[world, body], wrench[slot, world, body, 2])
    xfrc[world, body] = user[world, body] + wp.spatial_vector(force, torque)


class BodyForces:
    """Force requests of all worlds and bodies, and the kernel that turns them into ``xfrc_applied``.

    Made by ``Simulator`` on first use. ``needs_kinematics`` is True once a request depends on the pose (a body-frame
    wrench or a force at a point): the simulator then recomputes body poses before each physics step, since a step
    leaves the poses of its start and the kernel must rotate with the pose of the step about to run.
    """

    def __init__(self, data, num_worlds: int, nbody: int, body_ipos: torch.Tensor, device: torch.device) -> None:
        self.wrench = torch.zeros(2, num_worlds, nbody, 5, 3, dtype=torch.float32, device=device)
        self._wrench_wp = wp.from_torch(self.wrench, dtype=wp.vec3)
        self._user = wp.zeros_like(data.xfrc_applied)
        self._data = data
        self._body_ipos = body_ipos  # (1 or num_worlds, nbody, 3): COM offsets in body frames, maybe per world
        self.needs_kinematics = False
        self.active = False  # set by add(), cleared by Simulator.clear_body_forces

    def add(self, body_ids: torch.Tensor, forces: torch.Tensor | None, torques: torch.Tensor | None,
            positions: torch.Tensor | None, frame: str, persist: bool) -> None:
        """Accumulate (num_worlds, len(body_ids), 3) forces/torques; torch ops only, so a CUDA graph can hold it."""
        self.active = True
        slot = self.wrench[1 if persist else 0]
        shape = (slot.shape[0], body_ids.shape[0], 5, 3)
        terms = torch.zeros(shape, dtype=slot.dtype, device=slot.device)
        force_col, torque_col = (_WORLD_F, _WORLD_T) if frame == "world" else (_BODY_F, _BODY_T)
        if forces is not None:
            terms[:, :, force_col] = forces
        if torques is not None:
            terms[:, :, torque_col] = torques
        if positions is not None and forces is not None:
            if frame == "world":
                terms[:, :, _WORLD_T] += torch.cross(positions, forces, dim=-1)
                terms[:, :, _POINT_F] = forces
            else:
                arm = positions - self._body_ipos[:, body_ids]
                terms[:, :, _BODY_T] += torch.cross(arm, forces, dim=-1)
            self.needs_kinematics = True
        if frame == "body":
            self.needs_kinematics = True
        slot.index_add_(1, body_ids, terms)

    def clear(self, mask: torch.Tensor | None = None) -> None:
        """Zero both slots, of every world or of the masked ones (a reset)."""
        if mask is None:
            self.wrench.zero_()
        else:
            self.wrench.masked_fill_(mask.view(1, -1, 1, 1, 1), 0.0)

    # Warp work inside the captured physics.
    def save_user(self) -> None:
        wp.copy(self._user, self._data.xfrc_applied)

    def launch(self) -> None:
        d = self._data
        wp.launch(_add_body_wrench, dim=self._user.shape, inputs=[self._wrench_wp, self._user, d.xmat, d.xipos],
                  outputs=[d.xfrc_applied])

    def end_step(self) -> None:
        """Put the user's ``xfrc_applied`` back and drop the one-step requests."""
        wp.copy(self._data.xfrc_applied, self._user)
        self._wrench_wp[0].zero_()


class BodyForceRequests:
    """The simulator's body-force API (IsaacGym's force tensors) over ``BodyForces``: a part of ``Simulator``
    (sim/simulator.py), which sets ``body_forces`` (None until the first request), ``data``, ``num_worlds``,
    ``mj_model`` and ``device``, and resolves bodies (``body_ids``, sim/lookups.py)."""

    def apply_body_forces(
        self,
        forces: torch.Tensor | None = None,
        torques: torch.Tensor | None = None,
        bodies: Sequence[str | int] | torch.Tensor | None = None,
        positions: torch.Tensor | None = None,
        frame: str = "world",
        persist: bool = False,
    ) -> None:
        """Push bodies with forces and torques, (N, len(bodies), 3) each, from the next ``simulate()`` on.

        IsaacGym's ``apply_rigid_body_force_tensors`` / ``..._at_pos_tensors``, which act for one simulate call.
        - ``persist=False``: acts during the next ``simulate()`` only (all its physics steps), then is dropped;
          ``persist=True``: acts every step until ``clear_body_forces()`` or a reset of the world. Calls add up.
        - ``frame="world"``: forces and torques in world axes, fixed over the step; ``positions`` are world points
          that stay put while the body moves (MuJoCo's ``mj_applyFT`` at each physics step: torque about the
          centre of mass ``t + (p - com) x f``). ``frame="body"``: forces, torques and ``positions`` in the body's
          own frame (points relative to the body origin); the wrench turns with the body at every physics step.
        - Without ``positions`` forces act at the centre of mass.
        Torch ops only (no host sync), so it may sit in a captured ``pre_physics_step``; bodies given as a list are
        resolved once and cached. Once used, each step launches one small kernel per physics step (plus a pose
        refresh when a body-frame wrench or a point was used) until ``clear_body_forces()``. ``xfrc_applied`` keeps
        the user's own writes only: these forces are added to it inside the physics and do not show there.
        """
        if frame not in FRAMES:
            raise ValueError(f"frame={frame!r} is invalid: give one of {list(FRAMES)}")
        if forces is None and torques is None:
            raise ValueError("apply_body_forces: give forces, torques or both (both are None)")
        if positions is not None and forces is None:
            raise ValueError("positions given without forces: a point of application needs a force")
        ids = self.body_ids(bodies)
        expected = (self.num_worlds, int(ids.shape[0]), 3)
        values = []
        for name, value in (("forces", forces), ("torques", torques), ("positions", positions)):
            if value is not None and tuple(value.shape) != expected:
                raise ValueError(f"{name} has shape {tuple(value.shape)}; valid: (num_envs, len(bodies), 3) = "
                                 f"{expected}")
            values.append(None if value is None else value.to(self.device, torch.float32))
        if self.body_forces is None:
            self.body_forces = BodyForces(self.data, self.num_worlds, self.mj_model.nbody,
                                          self.model_field("body_ipos"), self.device)
        self.body_forces.add(ids, *values, frame=frame, persist=bool(persist))

    def clear_body_forces(self) -> None:
        """Drop every force of ``apply_body_forces`` (one-step and persistent) and stop launching its kernel."""
        if self.body_forces is not None:
            self.body_forces.clear()
            self.body_forces.active = self.body_forces.needs_kinematics = False
