"""Quaternion helpers in MuJoCo's (w, x, y, z) order, batched over the leading dimension."""

from __future__ import annotations

import torch


def quat_rotate(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Rotate vectors v (N, 3) from the body frame to the world frame by unit quaternions q (N, 4)."""
    w, xyz = q[:, :1], q[:, 1:]
    t = 2.0 * torch.cross(xyz, v, dim=-1)
    return v + w * t + torch.cross(xyz, t, dim=-1)


def quat_rotate_inverse(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Rotate world-frame vectors v (N, 3) into the body frame of unit quaternions q (N, 4)."""
    w, xyz = q[:, :1], q[:, 1:]
    t = 2.0 * torch.cross(xyz, v, dim=-1)
    return v - w * t + torch.cross(xyz, t, dim=-1)


def yaw_from_quat(q: torch.Tensor) -> torch.Tensor:
    """Heading (rad, about world z) of quaternions q (N, 4); the form holds for unnormalised q too."""
    w, x, y, z = q.unbind(-1)
    return torch.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


def wrap_to_pi(angle: torch.Tensor) -> torch.Tensor:
    """Angles (rad) wrapped to [-pi, pi]."""
    return torch.atan2(torch.sin(angle), torch.cos(angle))


def quat_from_yaw(yaw: torch.Tensor) -> torch.Tensor:
    """(N, 4) rotations by ``yaw`` (N,) rad about world z."""
    return quat_about_axis(yaw, 2)


def quat_axis(q: torch.Tensor, axis: int = 0) -> torch.Tensor:
    """World direction (N, 3) of the body's x (0), y (1) or z (2) axis: IsaacGym's ``quat_axis``, but q is (w, x, y, z).

    Porting IsaacGym code: its quaternions are (x, y, z, w); pass ``q[..., [3, 0, 1, 2]]`` for one read from IGE.
    """
    if axis not in (0, 1, 2):
        raise ValueError(f"axis={axis!r} is invalid: give 0 (x), 1 (y) or 2 (z)")
    basis = torch.zeros(q.shape[0], 3, dtype=q.dtype, device=q.device)
    basis[:, axis] = 1.0
    return quat_rotate(q, basis)


def quat_from_matrix(r: torch.Tensor) -> torch.Tensor:
    """(N, 4) unit quaternions (w, x, y, z), w >= 0, of rotation matrices (N, 3, 3); stable for any angle."""
    m00, m11, m22 = r[:, 0, 0], r[:, 1, 1], r[:, 2, 2]
    # |w|, |x|, |y|, |z| from the diagonal, the signs of x, y, z from the off-diagonal differences (w >= 0).
    w = 0.5 * torch.sqrt(torch.clamp(1.0 + m00 + m11 + m22, min=0.0))
    x = 0.5 * torch.sqrt(torch.clamp(1.0 + m00 - m11 - m22, min=0.0))
    y = 0.5 * torch.sqrt(torch.clamp(1.0 - m00 + m11 - m22, min=0.0))
    z = 0.5 * torch.sqrt(torch.clamp(1.0 - m00 - m11 + m22, min=0.0))
    x = torch.copysign(x, r[:, 2, 1] - r[:, 1, 2])
    y = torch.copysign(y, r[:, 0, 2] - r[:, 2, 0])
    z = torch.copysign(z, r[:, 1, 0] - r[:, 0, 1])
    return torch.stack((w, x, y, z), dim=-1)


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton products a b of quaternions (..., 4): the rotation b, then a."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack((aw * bw - ax * bx - ay * by - az * bz,
                        aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw), dim=-1)


def quat_conjugate(q: torch.Tensor) -> torch.Tensor:
    """Conjugates (..., 4): the inverse rotations of unit quaternions."""
    return torch.cat((q[..., :1], -q[..., 1:]), dim=-1)


def quat_about_axis(angle: torch.Tensor, axis: int) -> torch.Tensor:
    """(N, 4) rotations by ``angle`` (N,) rad about the x (0), y (1) or z (2) axis."""
    half = 0.5 * angle
    q = torch.zeros(*angle.shape, 4, dtype=angle.dtype, device=angle.device)
    q[..., 0] = torch.cos(half)
    q[..., 1 + axis] = torch.sin(half)
    return q


def rotation_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Angle (rad, 0 ... pi) of the rotation between unit quaternions a and b (N, 4), IsaacGymEnvs' rot_dist:
    2 asin(|vector part of a b*|), clamped so that rounding never leaves asin's domain."""
    diff = quat_mul(a, quat_conjugate(b))
    return 2.0 * torch.asin(torch.clamp(torch.linalg.norm(diff[..., 1:], dim=-1), max=1.0))
