"""Numerical stability of PD drives, checked when the model is built (sim/builder.py); the run-time log of worlds
that blow up anyway is sim/blowup.py.

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

The estimate does not hold once constraints couple the joints: it sees one joint with the others free, not the
constraint that ties them. On a closed chain (a leg whose foot an equality constraint pins) the rule "implicit
damping raises the limit" fails in MuJoCo C: IsaacGymEnvs' BallBalance gains (kp 4000, damping 100 at dt 0.01) give
ratio 0.44 under implicitfast (kv) and under euler (joint damping), and the foot still leaves its pin within a
second, while the same leg with its foot free stays stable (tests/sim/test_drive_stability.py). Hence the
build-time probe (``probe_divergence``): MuJoCo C steps one world of the compiled model from its initial state and
from a few perturbed ones, the drives holding the initial pose, and looks for what the run-time check resets (a
NaN/inf state, a joint speed above ``DIVERGED_SPEED``, an equality constraint violated by more than
``EQUALITY_DIVERGED``). The wording is graded by certainty: "will blow its worlds up" only when the probe diverged;
"may be numerically unstable" when only the single-joint estimate says so; nothing when neither does.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Collection
from dataclasses import dataclass

import mujoco
import numpy as np

from isaacgymenvs_mw.sim.divergence import DIVERGED_SPEED, EQUALITY_DIVERGED, object_name

# A drive is reported when dt·ω exceeds this fraction of its integrator's limit (a factor 2 in frequency, 4 in kp).
SAFETY = 0.5

# The build-time probe: MuJoCo C steps one world PROBE_STEPS times from each of PROBE_STARTS states: the initial
# state, then states with random joint speeds (normal, PROBE_SPEED rad/s or m/s): an equilibrium at rest need not
# excite the mode that diverges. 300 steps are 3 s of a 0.01 s step; the closed chains of the tests diverge within
# 0.6 s. The shipped tasks' probes take 0.01-0.07 s on a 2-core CPU (docs/config.md, "Drive stability").
PROBE_STEPS = 300
PROBE_STARTS = 3
PROBE_SPEED = 0.1


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


@dataclass(frozen=True)
class ProbeResult:
    """What the build-time probe saw: whether one MuJoCo C world of the model diverged, and how."""

    diverged: bool
    steps: int  # MuJoCo C steps taken in all
    seconds: float  # wall time of the probe
    start: int = 0  # the start that diverged: 0 the initial state, k > 0 the k-th one with random joint speeds
    time: float = 0.0  # simulated seconds into that start when it was seen
    reason: str = ""  # what diverged, in words (a joint, a constraint)


def _position_servo(model: mujoco.MjModel, a: int) -> bool:
    """An actuator whose force is kp (ctrl - length) - kv velocity: MuJoCo's <position>, or a YAML position drive."""
    kp = float(model.actuator_gainprm[a, 0])
    return kp > 0.0 and float(model.actuator_biasprm[a, 1]) == -kp


def _divergence(model: mujoco.MjModel, data: mujoco.MjData) -> str:
    """What the run-time check (``Simulator.reset_nonfinite``) would reset this world for, in words; '' if nothing."""
    bad_acc = data.warning[int(mujoco.mjtWarning.mjWARN_BADQACC)]
    if bad_acc.number > 0:  # MuJoCo C reset the data itself: the acceleration was NaN/inf or above 1e10
        joint = int(model.dof_jntid[min(int(bad_acc.lastinfo), model.nv - 1)]) if model.nv else 0
        name = object_name(model, mujoco.mjtObj.mjOBJ_JOINT, joint, "joint")
        return f"NaN/inf or huge acceleration at joint '{name}'"
    if not (np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all()):
        return "NaN/inf state"
    if model.nv and np.abs(data.qvel).max() > DIVERGED_SPEED:
        dof = int(np.argmax(np.abs(data.qvel)))
        joint = object_name(model, mujoco.mjtObj.mjOBJ_JOINT, int(model.dof_jntid[dof]), "joint")
        return f"joint '{joint}' at speed {abs(data.qvel[dof]):.3g} (above {DIVERGED_SPEED:.0e})"
    rows = data.efc_type[:data.nefc] == int(mujoco.mjtConstraint.mjCNSTR_EQUALITY)
    if rows.any():
        pos = np.abs(data.efc_pos[:data.nefc]) * rows
        row = int(np.argmax(pos))
        if pos[row] > EQUALITY_DIVERGED:
            eq = object_name(model, mujoco.mjtObj.mjOBJ_EQUALITY, int(data.efc_id[row]), "equality")
            return f"equality constraint '{eq}' violated by {pos[row]:.3g} (above {EQUALITY_DIVERGED})"
    return ""


def probe_divergence(model: mujoco.MjModel, steps: int = PROBE_STEPS, starts: int = PROBE_STARTS,
                     seed: int = 0) -> ProbeResult:
    """Step one MuJoCo C world of ``model`` ``steps`` times from each of ``starts`` states, every position servo
    holding the initial pose (its target the actuator's length at ``qpos0``; other actuators' controls 0), and
    report the first divergence the run-time check would reset a world for (``_divergence``).

    Start 0 is the model's initial state (``qpos0`` at rest: where ``Simulator.reset_worlds`` puts a world), the
    others add normal joint speeds of ``PROBE_SPEED`` drawn from ``seed``: deterministic, so a build warns the same
    way every time. MuJoCo's own "simulation is unstable" message is caught, not printed.
    """
    began = time.perf_counter()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    ctrl = np.zeros(model.nu)
    for a in range(model.nu):
        if _position_servo(model, a):
            ctrl[a] = data.actuator_length[a]
            if model.actuator_ctrllimited[a]:
                ctrl[a] = np.clip(ctrl[a], *model.actuator_ctrlrange[a])
    rng = np.random.default_rng(seed)
    taken = 0
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda text: None)  # the warning counter below tells us; the text would be noise
    try:
        for start in range(starts):
            mujoco.mj_resetData(model, data)
            if start:
                data.qvel[:] = PROBE_SPEED * rng.standard_normal(model.nv)
            for step in range(steps):
                data.ctrl[:] = ctrl
                mujoco.mj_step(model, data)
                taken += 1
                reason = _divergence(model, data)
                if reason:
                    return ProbeResult(True, taken, time.perf_counter() - began, start,
                                       (step + 1) * float(model.opt.timestep), reason)
    finally:
        mujoco.set_mju_user_warning(previous)
    return ProbeResult(False, taken, time.perf_counter() - began)


def warn_unstable_drives(model: mujoco.MjModel, yaml_drives: Collection[str] = (),
                         probe: bool = True) -> tuple[list[DriveStability], ProbeResult | None]:
    """Warn about PD drives that are or may be numerically unstable; returns the drives past ``SAFETY`` times their
    single-joint limit, and the probe's result (None when ``probe`` is False: ``sim.stabilityProbe``).

    The wording follows what is known. The probe diverged: each reported drive "will blow its worlds up" (and with
    none reported, one warning says the model will, naming what diverged: coupled joints are faster than the
    single-joint estimate). Only the estimate is past its margin: each such drive "may be numerically unstable".
    ``yaml_drives``: the joints whose drive the task YAML added (named by ``env.control.stiffness``/``damping``);
    other position actuators are the asset's own (their ``kp``/``kv`` are in the MJCF).
    """
    bad = [s for s in drive_stability(model) if s.unstable]
    result = probe_divergence(model) if probe else None
    if result is None:
        seen = "the build-time probe is off (sim.stabilityProbe: False)"
    elif result.diverged:
        seen = (f"a build-time probe in MuJoCo C diverged: {result.reason}, {result.time:.3g} s after "
                + ("the initial state" if result.start == 0 else "a start with small random joint speeds")
                + " with the drives holding the initial pose")
    else:
        seen = (f"a build-time probe of {result.steps} steps in MuJoCo C, from the initial state and "
                f"{PROBE_STARTS - 1} perturbed ones, stayed stable; a different pose or large actions may not")
    for s in bad:
        if s.joint in yaml_drives and s.actuator == s.joint:
            gains = f"lower env.control.stiffness for '{s.joint}'"
        else:
            gains = f"lower the kp of the asset's actuator '{s.actuator}' (or its gear)"
        verdict = ("is numerically unstable at this timestep and will blow its worlds up" if result and result.diverged
                   else "may be numerically unstable at this timestep")
        warnings.warn(
            f"PD drive of joint '{s.joint}' {verdict}: "
            f"kp={s.kp:.4g}, kd={s.kd:.4g}, I_eff={s.inertia:.4g} (1/dof_invweight0: the joint-space inertia the "
            f"drive moves at the initial pose, armature included), dt={s.dt:.4g} s: dt*sqrt(kp/I_eff)={s.omega_dt:.3g}"
            f" against the {s.integrator} integrator's limit {s.limit:.3g} for this damping (ratio {s.ratio:.3g}; "
            f"reported above {SAFETY}); {seen}. Fix: {gains}, add rotor inertia (env.asset.armature), or lower "
            "sim.dt (raising env.controlFrequencyInv keeps the control rate); docs/config.md, 'Drive stability'.",
            RuntimeWarning,
            stacklevel=3,
        )
    if result is not None and result.diverged and not bad:
        drives = sorted(drive_stability(model), key=lambda s: -s.ratio)[:3]
        ratios = ", ".join(f"'{s.joint}' kp={s.kp:.4g} kd={s.kd:.4g} ratio {s.ratio:.3g}" for s in drives)
        warnings.warn(
            f"This model will blow its worlds up: {seen}. No single PD drive is past {SAFETY} of its stability limit"
            + (f" (highest: {ratios})" if drives else "")
            + ", but joints coupled by constraints (closed chains, equality constraints) are faster than each "
            "joint alone. Fix: lower env.control.stiffness / damping of the coupled joints, add rotor inertia "
            "(env.asset.armature), lower sim.dt (raising env.controlFrequencyInv keeps the control rate), or check "
            "the asset's masses and constraints; docs/config.md, 'Drive stability'.",
            RuntimeWarning,
            stacklevel=3,
        )
    return bad, result
