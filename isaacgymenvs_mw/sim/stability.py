"""Numerical stability of PD drives, and what to say when a world blows up anyway.

The criterion (docs/config.md, "Drive stability"). A position actuator on a joint (gear g) adds the force
``-kp g² (q - target) - kv g² q̇``. Around the initial pose, with every other degree of freedom free, that joint is a
mass-spring-damper of inertia ``I_eff = 1 / (M⁻¹)_ii``: MuJoCo's ``dof_invweight0``, the diagonal of the inverse
joint-space inertia at ``qpos0`` that ``mj_setConst`` computes at compile time (armature included). It is the
inertia the drive actually pushes against (on a floating robot the body recoils, so it is below ``M_ii``), and the
compiled model already holds it: no ``MjData`` or forward pass is needed.

MuJoCo's Euler-type integrators are semi-implicit: ``v' = v + h a``, ``q' = q + h v'``, with some velocity
derivatives taken at ``v'`` (implicit damping ``c_i``, per unit inertia) and the rest at ``v`` (explicit ``c_e``).
``implicitfast`` and ``implicit`` treat the actuator's ``kv`` and the joint's ``damping`` implicitly (c_i = (kv g² +
damping) / I_eff, c_e = 0); ``euler`` treats only the joint's ``damping`` implicitly (c_i = damping / I_eff) and the
actuator's ``kv`` explicitly (c_e = kv g² / I_eff). The one-step map of (q, v) then has determinant
``(1 - h c_e) / (1 + h c_i)`` and trace ``(2 - h c_e + h c_i - h² ω²) / (1 + h c_i)`` with ``ω² = kp g² / I_eff``;
both eigenvalues lie inside the unit circle (Jury's test) exactly when

    (h ω)² < 4 + 2 h (c_i - c_e)     and     h c_e < 2 + h c_i.

Without damping that is ``h ω < 2``; implicit damping raises the limit, explicit damping lowers it. ``rk4`` is
checked against its undamped limit ``h ω < 2√2`` (its stability region's extent along the imaginary axis).

The per-joint frequency is a lower bound on the fastest mode of the whole robot (coupled drives, other poses,
contacts and float32 arithmetic only make it faster), so a drive is reported when ``h ω`` exceeds ``SAFETY`` times
its limit, not only past it.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Collection
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from isaacgymenvs_mw.sim.simulator import DIVERGED_SPEED, Simulator

# A drive is reported when dt·ω exceeds this fraction of its integrator's limit (a factor 2 in frequency, 4 in kp).
SAFETY = 0.5


@dataclass(frozen=True)
class DriveStability:
    """One PD (position) drive against its integrator's stability limit at the model's timestep."""

    actuator: str
    joint: str
    kp: float  # joint-space stiffness, kp g² (N m/rad or N/m)
    kd: float  # joint-space actuator damping, kv g² (N m s/rad or N s/m)
    joint_damping: float  # the joint's passive damping (MuJoCo dof_damping)
    inertia: float  # I_eff = 1 / dof_invweight0 (kg m² or kg)
    dt: float
    integrator: str
    omega_dt: float  # dt * sqrt(kp / I_eff)
    limit: float  # the largest stable omega_dt for this integrator and damping

    @property
    def ratio(self) -> float:
        """omega_dt / limit: below 1 the linearised drive is stable, above 1 it diverges."""
        return self.omega_dt / self.limit if self.limit > 0 else math.inf

    @property
    def unstable(self) -> bool:
        """True when the drive is past ``SAFETY`` times its limit (reported at build time)."""
        return self.ratio > SAFETY


def stable_omega_dt(integrator: str, dt: float, implicit_rate: float, explicit_rate: float) -> float:
    """The largest stable dt·ω of a PD drive whose damping per unit inertia is ``implicit_rate`` (integrated at the
    new velocity) plus ``explicit_rate`` (at the old one); 0 when the explicit damping alone diverges."""
    if integrator == "rk4":
        return 2.0 * math.sqrt(2.0)
    hi, he = dt * implicit_rate, dt * explicit_rate
    if he >= 2.0 + hi:
        return 0.0
    return math.sqrt(max(4.0 + 2.0 * (hi - he), 0.0))


def _integrator_name(model: mujoco.MjModel) -> str:
    return mujoco.mjtIntegrator(int(model.opt.integrator)).name[len("mjINT_"):].lower()


def drive_stability(model: mujoco.MjModel) -> list[DriveStability]:
    """Every position actuator (kp > 0) on a hinge or slide joint of the compiled model, with its stability data."""
    integrator, dt = _integrator_name(model), float(model.opt.timestep)
    implicit_kv = integrator in ("implicitfast", "implicit")
    out = []
    for a in range(model.nu):
        if int(model.actuator_trntype[a]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            continue
        joint = int(model.actuator_trnid[a, 0])
        if int(model.jnt_type[joint]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            continue
        # A position actuator: gain kp, bias (0, -kp, -kv) (MuJoCo's <position>); anything else is not a PD drive.
        kp, bias_q, bias_v = (float(model.actuator_gainprm[a, 0]), float(model.actuator_biasprm[a, 1]),
                              float(model.actuator_biasprm[a, 2]))
        if kp <= 0.0 or bias_q != -kp:
            continue
        gear2 = float(model.actuator_gear[a, 0]) ** 2  # the joint sees gear * force of a length gear * q
        dof = int(model.jnt_dofadr[joint])
        inertia = 1.0 / float(model.dof_invweight0[dof])
        k, kd, b = kp * gear2, -bias_v * gear2, float(model.dof_damping[dof])
        implicit = (kd + b if implicit_kv else b) / inertia
        explicit = 0.0 if implicit_kv else kd / inertia
        out.append(DriveStability(
            actuator=mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"actuator{a}",
            joint=mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint), kp=k, kd=kd, joint_damping=b,
            inertia=inertia, dt=dt, integrator=integrator, omega_dt=dt * math.sqrt(k / inertia),
            limit=stable_omega_dt(integrator, dt, implicit, explicit)))
    return out


def warn_unstable_drives(model: mujoco.MjModel, yaml_drives: Collection[str] = ()) -> list[DriveStability]:
    """Warn once per PD drive past ``SAFETY`` times its stability limit; returns those drives.

    ``yaml_drives``: the joints whose drive the task YAML added (named by ``env.control.stiffness``/``damping``);
    other position actuators are the asset's own (their ``kp``/``kv`` are in the MJCF).
    """
    bad = [s for s in drive_stability(model) if s.unstable]
    for s in bad:
        if s.joint in yaml_drives and s.actuator == s.joint:
            gains = f"lower env.control.stiffness for '{s.joint}'"
        else:
            gains = f"lower the kp of the asset's actuator '{s.actuator}' (or its gear)"
        warnings.warn(
            f"PD drive of joint '{s.joint}' is numerically unstable at this timestep and will blow its worlds up: "
            f"kp={s.kp:.4g}, kd={s.kd:.4g}, I_eff={s.inertia:.4g} (1/dof_invweight0: the joint-space inertia the "
            f"drive moves at the initial pose, armature included), dt={s.dt:.4g} s: dt*sqrt(kp/I_eff)={s.omega_dt:.3g}"
            f" against the {s.integrator} integrator's limit {s.limit:.3g} for this damping (ratio {s.ratio:.3g}; "
            f"reported above {SAFETY}). Fix: {gains}, add rotor inertia (env.asset.armature), or lower sim.dt "
            "(raising env.controlFrequencyInv keeps the control rate); docs/config.md, 'Drive stability'.",
            RuntimeWarning,
            stacklevel=3,
        )
    return bad


# What usually makes a world blow up, with the keys that change it (the blow-up warning's second half).
BLOWUP_CAUSES = (
    "Likely causes: PD drive gains too stiff for the timestep (env.control.stiffness / damping; a build-time "
    "'PD drive ... numerically unstable' warning names such a drive), sim.dt too large (lower it; raising "
    "env.controlFrequencyInv keeps the policy rate), or wrong asset inertias (tiny or zero masses and inertias in the "
    "URDF <inertial> / MJCF; env.asset.armature adds rotor inertia to a joint); docs/config.md, 'Drive stability'."
)


class BlowupLog:
    """Which joint ran away in the worlds ``Simulator.reset_nonfinite`` resets, reported by a periodic host check.

    ``reset_nonfinite`` runs inside the step (device work only, capturable): it keeps each reset world's joint speeds
    from just before the reset. ``poll`` runs where the host already syncs (VecTask's periodic overflow check) and
    warns with the first blown-up world's fastest joint (a NaN/inf speed counts as the fastest).
    """

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self.speed = torch.zeros_like(sim.qvel)  # |qvel| of each world at its last blow-up
        self.seen = torch.zeros(sim.num_worlds, dtype=torch.bool, device=sim.device)  # blown up since the last poll
        model = sim.mj_model
        self._dof_labels = []  # how the warning names each dof
        for dof in range(model.nv):
            joint = int(model.dof_jntid[dof])
            label = f"'{mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint) or f'joint{joint}'}'"
            if int(model.jnt_type[joint]) == int(mujoco.mjtJoint.mjJNT_FREE):
                part = dof - int(model.jnt_dofadr[joint])
                label += f" (floating base, {'linear' if part < 3 else 'angular'} velocity {'xyz'[part % 3]})"
            self._dof_labels.append(label)

    def reset_nonfinite(self) -> torch.Tensor:
        """``sim.reset_nonfinite()``, keeping the reset worlds' joint speeds first; returns the reset mask."""
        speed = self.sim.qvel.abs()  # a copy: the reset zeroes qvel
        bad = self.sim.reset_nonfinite()
        self.speed.copy_(torch.where(bad.view(-1, 1), torch.nan_to_num(speed, nan=math.inf), self.speed))
        self.seen |= bad
        return bad

    def poll(self, interval: int | None = None) -> str | None:
        """Host-side check (syncs): warn when worlds blew up since the last poll, naming the first one's fastest joint;
        returns the message (None: none blew up). ``interval``: env steps since the last poll, for the text."""
        seen = self.seen.cpu().numpy().copy()  # a copy: on the CPU device numpy() shares memory with the zeroed flags
        if not seen.any():
            return None
        world = int(np.argmax(seen))
        speeds = self.speed[world].cpu().numpy().copy()
        dof = int(np.argmax(speeds))
        self.seen.zero_()
        since = f"in the last {interval} env steps" if interval else "since the last check"
        nonfinite = int(np.isinf(speeds).sum())
        speed = (f"|velocity| {speeds[dof]:.3g}" if not nonfinite else
                 "velocity NaN/inf" + (f", as were {nonfinite - 1} other dof(s)" if nonfinite > 1 else ""))
        message = (
            f"{int(seen.sum())} world(s) blew up {since} (NaN/inf state, or a joint speed above {DIVERGED_SPEED:.0e}) "
            f"and were reset to the initial pose. First diverging joint: {self._dof_labels[dof]} in world {world} "
            f"({speed} when it was reset). {BLOWUP_CAUSES}"
        )
        warnings.warn(message, RuntimeWarning, stacklevel=3)
        return message
