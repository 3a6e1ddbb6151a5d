"""How a hand's servos and coupled joints are wired in its MuJoCo model, read from the compiled model.

The in-hand tasks map actions to servo targets through the servos' transmissions (joint servos, and servos on fixed
tendons that sum several joints) and draw reset poses that respect joint equalities (a distal joint that follows its
middle joint). Both are MuJoCo model structure, so they are read here, in the simulator layer.
"""

from __future__ import annotations

import mujoco
import numpy as np

from isaacgymenvs_mw.utils.errors import ConfigError


def servo_transmission(m: mujoco.MjModel, joint_ids: list[int], num_servos: int) -> np.ndarray:
    """(servos, joints): each of the first ``num_servos`` actuators' length per radian of each hand joint, for
    joint servos (gear) and servos on fixed tendons (gear x the tendon's coefficients); its length at a pose q is
    ``transmission @ q``."""
    column = {j: c for c, j in enumerate(joint_ids)}
    out = np.zeros((num_servos, len(joint_ids)))
    for a in range(num_servos):
        target, gear = int(m.actuator_trnid[a, 0]), float(m.actuator_gear[a, 0])
        kind = int(m.actuator_trntype[a])
        if kind == int(mujoco.mjtTrn.mjTRN_JOINT):
            wraps = [(target, 1.0)]
        elif kind == int(mujoco.mjtTrn.mjTRN_TENDON):
            first = int(m.tendon_adr[target])
            joint_wrap = int(mujoco.mjtWrap.mjWRAP_JOINT)  # a fixed tendon: a sum of joints (else: not one)
            wraps = [(int(m.wrap_objid[w]), float(m.wrap_prm[w])) if int(m.wrap_type[w]) == joint_wrap else (-1, 0.0)
                     for w in range(first, first + int(m.tendon_num[target]))]
        else:
            wraps = [(-1, 0.0)]
        if not wraps or any(joint not in column for joint, _ in wraps):
            raise ConfigError(f"env.asset: actuator {m.actuator(a).name!r} drives neither a hand joint nor a fixed "
                              "tendon of hand joints; the in-hand tasks' servos must")
        for joint, coef in wraps:
            out[a, column[joint]] += gear * coef
    return out


def joint_couplings(m: mujoco.MjModel, joint_ids: list[int]) -> list[tuple[int, int, float, float]]:
    """(follower, leader, offset, ratio) hand-joint columns of each active joint equality that says
    follower = offset + ratio x leader (MuJoCo's polycoef, whose higher terms must be 0)."""
    column = {j: c for c, j in enumerate(joint_ids)}
    out = []
    for e in range(m.neq):
        if int(m.eq_type[e]) != int(mujoco.mjtEq.mjEQ_JOINT) or not m.eq_active0[e]:
            continue
        follower, leader = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
        poly = m.eq_data[e, :5]
        if follower not in column or leader not in column or np.any(poly[2:] != 0.0):
            raise ConfigError(f"env.asset: joint equality {m.equality(e).name!r} is not a linear coupling of two "
                              "hand joints (polycoef c0 c1 0 0 0); the in-hand tasks can draw only those")
        out.append((column[follower], column[leader], float(poly[0]), float(poly[1])))
    return out
