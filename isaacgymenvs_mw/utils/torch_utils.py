"""IsaacGym ``torch_utils`` names porters look for, in one place: random draws and clamps, plus the rotations.

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

__all__ = ["quat_axis", "quat_conjugate", "quat_from_yaw", "quat_mul", "quat_rotate", "quat_rotate_inverse",
           "tensor_clamp", "torch_rand_float", "torch_random_dir_2", "wrap_to_pi", "yaw_from_quat"]


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
