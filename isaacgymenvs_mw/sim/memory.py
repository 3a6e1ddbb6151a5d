"""Whether ``num_worlds`` copies of a model's simulator state fit the device, told before allocating them.

Allocating a billion worlds fails only after tens of seconds, deep inside Warp, with the bytes it wanted; the
estimate here takes milliseconds. It is measured rather than computed from a formula: MuJoCo Warp's ``make_data``
on the host for one world and for two, the sum of their arrays' sizes, and the difference is what each further
world adds (state, contacts up to ``nconmax``, constraint rows up to ``njmax``, solver scratch). The task's own torch
buffers (observations, rewards, the learner's rollout storage) come on top, so the estimate is a floor.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np
import warp as wp

import mujoco_warp as mjw
from isaacgymenvs_mw.utils.errors import ConfigError

# Below this many worlds no model this project ships comes near a device's memory; the check is skipped (it costs a
# host allocation of two worlds).
CHECK_ABOVE_WORLDS = 4096


def _array_bytes(obj) -> int:
    """Bytes of every Warp array held by ``obj`` (a MuJoCo Warp Data) and by its nested structs."""
    total = 0
    for value in vars(obj).values():
        if isinstance(value, wp.array):
            total += int(np.prod(value.shape)) * wp.types.type_size_in_bytes(value.dtype)
        elif hasattr(value, "__dict__") and not isinstance(value, (type, np.ndarray)):
            total += _array_bytes(value)
    return total


def bytes_per_world(mj_model: mujoco.MjModel, nconmax: int | None, njmax: int | None) -> int:
    """What one more world of ``mj_model`` adds to MuJoCo Warp's simulator state, in bytes (measured on the host)."""
    with wp.ScopedDevice("cpu"):
        one = _array_bytes(mjw.make_data(mj_model, nworld=1, nconmax=nconmax, njmax=njmax))
        two = _array_bytes(mjw.make_data(mj_model, nworld=2, nconmax=nconmax, njmax=njmax))
    return max(two - one, 1)


def free_bytes(device: wp.context.Device) -> int | None:
    """Memory free for new allocations on ``device`` (the host's available memory for the CPU), None if unknown."""
    if device.is_cuda:
        return int(device.free_memory)
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _gib(n: float) -> str:
    return f"{n / 2**30:,.1f} GiB" if n >= 2**30 else f"{n / 2**20:,.1f} MiB"


def check_worlds_fit(mj_model: mujoco.MjModel, num_worlds: int, device: wp.context.Device, nconmax: int | None,
                     njmax: int | None) -> None:
    """Fail with the estimate when ``num_worlds`` worlds' simulator state alone would not fit ``device``."""
    if num_worlds <= CHECK_ABOVE_WORLDS:
        return
    free = free_bytes(device)
    if free is None:
        return
    per_world = bytes_per_world(mj_model, nconmax, njmax)
    needed = per_world * num_worlds
    if needed > free:
        raise ConfigError(
            f"num_envs={num_worlds} needs at least {_gib(needed)} on {device.alias} for the simulator state alone "
            f"({per_world:,} bytes per world, measured from this model's MuJoCo Warp data), but {_gib(free)} is "
            f"free: give num_envs <= {free // per_world:,} (fewer, since the task and learner need memory too)")
