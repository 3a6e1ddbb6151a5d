"""The humanoid's AMP observation (IsaacGymEnvs' ``build_amp_observations`` and ``compute_humanoid_observations``,
isaacgymenvs/tasks/humanoid_amp.py and tasks/amp/humanoid_amp_base.py): the same vector is the policy observation
and one step of the discriminator's input.

Columns: root height (1); root rotation as tangent and normal, the world x and z axes of the rotation (6; the
rotation without its heading with ``local_root_obs``); root linear and angular velocity in the heading frame (3 + 3);
each joint's rotation (6 per 3-dof joint, as tangent and normal; the angle of a 1-dof joint); dof velocities; key
body positions relative to the root, in the heading frame (3 per body). The heading frame is the root rotation's yaw
about world z. Quaternions are (w, x, y, z); velocities in the world frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from isaacgymenvs_mw.utils.rotations import (
    quat_about_axis,
    quat_mul,
    quat_rotate,
    yaw_from_quat,
)


def tan_norm(q: torch.Tensor) -> torch.Tensor:
    """(n, 6): the rotated x axis and the rotated z axis of unit quaternions (n, 4), rotated as one batch."""
    n = q.shape[0]
    axes = torch.eye(3, device=q.device, dtype=q.dtype)[::2]  # x, z
    return quat_rotate(q.repeat_interleave(2, dim=0), axes.expand(n, 2, 3).reshape(2 * n, 3)).view(n, 6)


def xyz_euler_to_quat(angles: torch.Tensor) -> torch.Tensor:
    """(n, 4) Rx(a) Ry(b) Rz(c) of angles (n, 3): three MuJoCo hinges about x, y, z in one body.

    The Hamilton products (Rx Ry) Rz written out without their terms that multiply a zero component of an axis
    rotation: the same roundings as the full products, in a few ops."""
    half = [0.5 * angles[:, i] for i in range(3)]
    (c1, c2, c3), (s1, s2, s3) = (torch.cos(h) for h in half), (torch.sin(h) for h in half)
    w, x, y, z = c1 * c2, s1 * c2, c1 * s2, s1 * s2  # Rx Ry
    return torch.stack((w * c3 - z * s3, x * c3 + y * s3, y * c3 - x * s3, w * s3 + z * c3), dim=-1)


def dof_obs_size(group_sizes: Sequence[int]) -> int:
    return sum(6 if s == 3 else 1 for s in group_sizes)


def dof_to_obs(dof_pos: torch.Tensor, group_sizes: Sequence[int]) -> torch.Tensor:
    """Joint rotations: tangent and normal of each 3-dof joint (its x-y-z hinge angles), the angle of a 1-dof one.

    The 3-dof joints go through the rotation maths together, as one batch of (n x joints) rows: one op per step of
    the maths rather than one per joint keeps the compiled step's graph (and its compile time) small. The rows are
    the same element-wise arithmetic as a joint at a time."""
    starts = [sum(group_sizes[:g]) for g in range(len(group_sizes))]
    balls = [s for s, size in zip(starts, group_sizes) if size == 3]
    rows = iter(())
    if balls:
        n = dof_pos.shape[0]
        angles = torch.stack([dof_pos[:, s:s + 3] for s in balls], dim=1).reshape(n * len(balls), 3)
        rows = iter(tan_norm(xyz_euler_to_quat(angles)).view(n, len(balls), 6).unbind(1))
    cols = [next(rows) if size == 3 else dof_pos[:, s:s + size] for s, size in zip(starts, group_sizes)]
    return torch.cat(cols, dim=-1)


def heading_inverse(root_rot: torch.Tensor) -> torch.Tensor:
    """(n, 4) rotation by minus the heading (yaw of the root's x axis) about world z."""
    return quat_about_axis(-yaw_from_quat(root_rot), 2)


def humanoid_observation(root_pos: torch.Tensor, root_rot: torch.Tensor, root_vel: torch.Tensor,
                         root_ang_vel: torch.Tensor, dof_pos: torch.Tensor, dof_vel: torch.Tensor,
                         key_pos: torch.Tensor, group_sizes: Sequence[int], local_root_obs: bool) -> torch.Tensor:
    """(n, 1 + 6 + 3 + 3 + dof obs + dofs + 3 keys): the module's columns."""
    heading = heading_inverse(root_rot)
    rot = quat_mul(heading, root_rot) if local_root_obs else root_rot
    n, k = key_pos.shape[0], key_pos.shape[1]
    # the root's velocities and the keys relative to the root go into the heading frame as one batch of vectors
    vectors = torch.cat((root_vel.unsqueeze(1), root_ang_vel.unsqueeze(1), key_pos - root_pos.unsqueeze(1)), dim=1)
    local = quat_rotate(heading.repeat_interleave(k + 2, dim=0), vectors.reshape(n * (k + 2), 3)).view(n, 3 * (k + 2))
    return torch.cat((root_pos[:, 2:3], tan_norm(rot), local[:, :6], dof_to_obs(dof_pos, group_sizes), dof_vel,
                      local[:, 6:]), dim=-1)
