"""What counts as a blown-up world: the thresholds that the run-time check (``Simulator.reset_nonfinite``), its log
(sim/blowup.py) and the build-time probe (sim/stability.py) share, so that the probe warns about what the step
would reset."""

from __future__ import annotations

import mujoco

# A world with any joint speed above this (m/s or rad/s) has diverged and is reset as a NaN one is. Such speeds are
# physically meaningless at millisecond steps (50 m per 5 ms step), and a world one step from NaN can hold 1e7: its
# squared penalty (dof_acc) pushed a logged per-episode mean to -1.5e7 on the GPU and spiked PPO's value loss.
DIVERGED_SPEED = 1.0e4
# A world with an equality constraint (a pinned foot, a closed chain) violated by more than this has diverged too:
# MuJoCo's constraint residual of any one equality row (efc_pos: m for connect and weld positions, rad for weld
# orientations and joint equalities). Soft constraints under load give millimetres; a closed chain whose drives
# diverge can drift metres apart at finite, modest speeds (sim/stability.py).
EQUALITY_DIVERGED = 0.1
# The constraint type of an equality row, as a plain int read once: the compiled step must not convert MuJoCo's enum
# itself (torch.compile's tracing of int() on it recursed without end under torch 2.13).
EQUALITY_ROW = int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)


def object_name(model: mujoco.MjModel, obj: mujoco.mjtObj, i: int, fallback: str) -> str:
    """The name of object ``i`` of kind ``obj``, or ``<fallback><i>`` for an unnamed one (as the warnings name it)."""
    return mujoco.mj_id2name(model, obj, i) or f"{fallback}{i}"
