"""IsaacGym ``torch_utils`` names porters look for, in one place: random draws and clamps, plus the rotations; and
IsaacGymEnvs' ``torch_jit_utils`` range and pose helpers (``scale_transform``, ``unscale_transform``, ``saturate``,
``quat_from_euler_xyz``, ``local_to_world_space``), written here from their definitions.

Rotations come from ``isaacgymenvs_mw.utils.rotations`` and take quaternions in MuJoCo's **(w, x, y, z)** order;
IsaacGym's are (x, y, z, w), so a quaternion copied from IsaacGym code or data needs ``q[..., [3, 0, 1, 2]]``.
"""

from __future__ import annotations

import math

import torch

from isaacgymenvs_mw.utils.rotations import (
    quat_axis,
    quat_conjugate,
    quat_from_yaw,
    quat_mul,
    quat_rotate,
    quat_rotate_inverse,
    wrap_to_pi,
    yaw_from_quat,
)

__all__ = ["local_to_world_space", "quat_axis", "quat_conjugate", "quat_from_euler_xyz", "quat_from_yaw", "quat_mul",
           "quat_rotate", "quat_rotate_inverse", "saturate", "scale_transform", "tensor_clamp", "torch_rand_float",
           "torch_random_dir_2", "unscale_transform", "wrap_to_pi", "yaw_from_quat"]


def torch_rand_float(lower: float | torch.Tensor, upper: float | torch.Tensor, shape: tuple[int, ...],
                     device: str | torch.device) -> torch.Tensor:
    """Uniform draws in [lower, upper) of ``shape`` on ``device``, from torch's global generator (seeded runs
    repeat), with IsaacGym's argument order so ported reset code reads the same."""
    return (upper - lower) * torch.rand(*shape, device=device) + lower


def torch_random_dir_2(shape: tuple[int, ...], device: str | torch.device) -> torch.Tensor:
    """Random 2-D unit vectors (cos θ, sin θ) with θ uniform in [-π, π), from torch's global generator: IsaacGym's
    ``torch_random_dir_2``. ``shape`` is the angles' shape, as there: a trailing 1 is dropped, so IGE's usual
    ``(n, 1)`` gives ``(n, 2)``; ``(n, k)`` gives ``(n, k, 2)``."""
    angle = torch_rand_float(-math.pi, math.pi, shape, device)
    if angle.dim() and angle.shape[-1] == 1:
        angle = angle.squeeze(-1)
    return torch.stack((torch.cos(angle), torch.sin(angle)), dim=-1)


def tensor_clamp(t: torch.Tensor, min_t: torch.Tensor | float, max_t: torch.Tensor | float) -> torch.Tensor:
    """Element-wise clamp of ``t`` between tensors (per-joint limits, for one); where min_t > max_t the result is
    min_t, as in IsaacGym's (the max is taken last)."""
    return torch.maximum(torch.minimum(t, torch.as_tensor(max_t, dtype=t.dtype, device=t.device)),
                         torch.as_tensor(min_t, dtype=t.dtype, device=t.device))


def scale_transform(x: torch.Tensor, lower: torch.Tensor | float, upper: torch.Tensor | float) -> torch.Tensor:
    """``x`` mapped linearly from [lower, upper] onto [-1, 1] (the midpoint to 0): 2 (x - (lower + upper) / 2) /
    (upper - lower). Values outside the range map outside [-1, 1]; nothing is clamped."""
    return 2.0 * (x - 0.5 * (lower + upper)) / (upper - lower)


def unscale_transform(x: torch.Tensor, lower: torch.Tensor | float, upper: torch.Tensor | float) -> torch.Tensor:
    """The inverse of ``scale_transform``: ``x`` in [-1, 1] mapped onto [lower, upper] (an action to a joint target,
    for one)."""
    return 0.5 * (lower + upper) + 0.5 * x * (upper - lower)


def saturate(x: torch.Tensor, lower: torch.Tensor | float, upper: torch.Tensor | float) -> torch.Tensor:
    """``x`` clamped element-wise into [lower, upper] (bounds broadcast against ``x``): ``tensor_clamp``."""
    return tensor_clamp(x, lower, upper)


def quat_from_euler_xyz(roll: torch.Tensor, pitch: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """The unit quaternion **(w, x, y, z)** of the rotation by ``roll`` about the world x axis, then ``pitch`` about
    world y, then ``yaw`` about world z (R = Rz(yaw) Ry(pitch) Rx(roll); MuJoCo's euler sequence "XYZ"). IsaacGym's
    function of this name returns the same rotation as (x, y, z, w)."""
    cr, sr = torch.cos(0.5 * roll), torch.sin(0.5 * roll)
    cp, sp = torch.cos(0.5 * pitch), torch.sin(0.5 * pitch)
    cy, sy = torch.cos(0.5 * yaw), torch.sin(0.5 * yaw)
    # The product qz(yaw) qy(pitch) qx(roll) of the three half-angle quaternions, expanded.
    return torch.stack((cy * cp * cr + sy * sp * sr,
                        cy * cp * sr - sy * sp * cr,
                        cy * sp * cr + sy * cp * sr,
                        sy * cp * cr - cy * sp * sr), dim=-1)


def local_to_world_space(pos_offset_local: torch.Tensor, pose_global: torch.Tensor) -> torch.Tensor:
    """The world position of a point given in a body's frame: ``pose_global`` is (N, 7), the body's world position
    then its orientation **(w, x, y, z)** (IsaacGym's pose is position then (x, y, z, w)); ``pos_offset_local`` is
    (N, 3) in the body's axes. Returns position + R(quat) offset."""
    return pose_global[..., 0:3] + quat_rotate(pose_global[..., 3:7], pos_offset_local)
