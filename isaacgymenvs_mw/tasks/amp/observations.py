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
    """(n, 6): the rotated x axis and the rotated z axis of unit quaternions (n, 4)."""
    n = q.shape[0]
    x = torch.zeros(n, 3, device=q.device, dtype=q.dtype)
    z = torch.zeros(n, 3, device=q.device, dtype=q.dtype)
    x[:, 0] = 1.0
    z[:, 2] = 1.0
    return torch.cat((quat_rotate(q, x), quat_rotate(q, z)), dim=-1)


def xyz_euler_to_quat(angles: torch.Tensor) -> torch.Tensor:
    """(n, 4) Rx(a) Ry(b) Rz(c) of angles (n, 3): three MuJoCo hinges about x, y, z in one body."""
    qx, qy, qz = (quat_about_axis(angles[:, i], i) for i in range(3))
    return quat_mul(quat_mul(qx, qy), qz)


def dof_obs_size(group_sizes: Sequence[int]) -> int:
    return sum(6 if s == 3 else 1 for s in group_sizes)


def dof_to_obs(dof_pos: torch.Tensor, group_sizes: Sequence[int]) -> torch.Tensor:
    """Joint rotations: tangent and normal of each 3-dof joint (its x-y-z hinge angles), the angle of a 1-dof one."""
    cols, i = [], 0
    for size in group_sizes:
        if size == 3:
            cols.append(tan_norm(xyz_euler_to_quat(dof_pos[:, i:i + 3])))
        else:
            cols.append(dof_pos[:, i:i + size])
        i += size
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
    rel = (key_pos - root_pos.unsqueeze(1)).reshape(n * k, 3)
    local_keys = quat_rotate(heading.repeat_interleave(k, dim=0), rel).reshape(n, 3 * k)
    return torch.cat((root_pos[:, 2:3], tan_norm(rot), quat_rotate(heading, root_vel),
                      quat_rotate(heading, root_ang_vel), dof_to_obs(dof_pos, group_sizes), dof_vel, local_keys), dim=-1)
