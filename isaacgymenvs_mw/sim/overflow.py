"""MuJoCo Warp's overflow flags: it drops contacts and constraint rows beyond ``nconmax``/``njmax`` silently and
sets ``d.overflow``; the simulator records the bits on the device and a periodic host check warns with the task YAML
key that fixes each. ``OverflowWatch`` is a part of ``Simulator`` (sim/simulator.py), which binds ``overflow`` and
``_overflow_seen`` (the bits of worlds reset since the last poll, folded in by ``reset_worlds``).
"""

from __future__ import annotations

import warnings

import numpy as np
import torch

import mujoco_warp as mjw


# Overflow bits we report, and the task YAML key that fixes each.
_OVERFLOW_KEYS = {
    int(mjw.OverflowType.NEFC): "sim.njmax",
    int(mjw.OverflowType.BROADPHASE): "sim.nconmax",
    int(mjw.OverflowType.NARROWPHASE): "sim.nconmax",
    int(mjw.OverflowType.CONTACT_MATCH): "sim.nconmax",
    # More heightfield prisms touch one geom than MuJoCo keeps per pair: a coarser terrain grid has fewer.
    int(mjw.OverflowType.HFIELD): "env.terrain.horizontalScale",
}


class OverflowWatch:
    """The periodic host check of the overflow bits."""

    # ------------------------------------------------------------- overflow
    def poll_overflow(self) -> list[str]:
        """Host-side check (syncs): warn once per bit seen since the last poll; returns the YAML keys named."""
        seen = self._overflow_seen | self.overflow
        bits = _or_all(seen)
        self._overflow_seen.zero_()
        keys = []
        for bit, key in _OVERFLOW_KEYS.items():
            if bits & bit and key not in keys:
                keys.append(key)
        if keys:
            # Only the bits that drop data: ITERATIONS/LS_ITERATIONS (solver stopped at its iteration limit) are
            # set by every RL-sized iteration count and would read as a cause here.
            dropped = bits & sum(_OVERFLOW_KEYS)
            warnings.warn(
                "MuJoCo Warp dropped contacts or constraint rows (overflow bits "
                f"{mjw.OverflowType(dropped)!r}); physics in the affected worlds is wrong. "
                f"Raise {', '.join(keys)} in the task YAML.",
                RuntimeWarning,
                stacklevel=2,
            )
        return keys


def _or_all(values: torch.Tensor) -> int:
    out = 0
    for v in np.unique(values.cpu().numpy()):
        out |= int(v)
    return out
