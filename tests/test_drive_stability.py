"""PD drives too stiff for the timestep: the build-time warning, and the criterion behind it checked by simulating the
same compiled models in MuJoCo C (a drive past its limit diverges there, one below it does not).

The models are built by the sim layer from a one-joint URDF written here (a rotor of known inertia on a fixed base,
or on a floating base for the effective-inertia check); the inertia, the gains and the timestep are chosen so that
dt * sqrt(kp / I) lands just below or just above the limit, so a wrong limit or a wrong damping rule fails.
"""

from __future__ import annotations

import math
import warnings

import mujoco
import numpy as np
import pytest

from isaacgymenvs_mw.sim import JointDrive, ModelRequest, SolverOptions, build_model
from isaacgymenvs_mw.sim.stability import SAFETY, drive_stability

ROTOR_INERTIA = 0.01  # kg m² about the joint axis
DT = 0.01


def rotor_urdf(path, floating: bool = False) -> str:
    """A base link and one rotor on a continuous (hinge) joint about z through the rotor's centre of mass."""
    base_mass = "0.2" if floating else "1.0"
    text = f"""<robot name="rotor_test">
  <link name="base"><inertial><mass value="{base_mass}"/>
    <inertia ixx="0.002" iyy="0.002" izz="0.002" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="rotor"><inertial><origin xyz="0 0 0"/><mass value="0.1"/>
    <inertia ixx="0.005" iyy="0.005" izz="{ROTOR_INERTIA}" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="spin" type="continuous"><origin xyz="0.3 0 0"/><parent link="base"/><child link="rotor"/>
    <axis xyz="0 0 1"/></joint>
</robot>
"""
    path.write_text(text)
    return path


def build(tmp_path, kp: float, kd: float = 0.0, integrator: str = "implicitfast", joint_damping: float = 0.0,
          floating: bool = False, armature: float = 0.0):
    request = ModelRequest(
        asset_file=rotor_urdf(tmp_path / "rotor.urdf", floating), fix_base=not floating,
        drives={"spin": JointDrive("position", kp, kd)},
        joint_damping={"spin": joint_damping} if joint_damping else {},
        armature={"spin": armature} if armature else {},
        options=SolverOptions(dt=DT, gravity=(0.0, 0.0, 0.0), integrator=integrator, enable_contacts=False))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = build_model(request)
    return model, [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]


def diverges_in_mujoco_c(model: mujoco.MjModel, steps: int = 1000) -> bool:
    """Start 0.1 rad off the drive's target (0) at rest and step; diverged: non-finite or 1000x the start offset."""
    data = mujoco.MjData(model)
    hinge = model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "spin")]
    data.qpos[hinge] += 0.1
    for _ in range(steps):
        mujoco.mj_step(model, data)
        if not np.isfinite(data.qpos).all() or abs(data.qpos[hinge]) > 100.0:
            return True
    return False


def kp_at(omega_dt: float, inertia: float = ROTOR_INERTIA) -> float:
    """The stiffness that puts dt * sqrt(kp / I) at omega_dt."""
    return inertia * (omega_dt / DT) ** 2


# (integrator, dt*omega, kd, joint damping, diverges). Undamped limit 2. Damping d per unit inertia shifts it to
# sqrt(4 + 2 dt d) when integrated implicitly (implicitfast: kv and joint damping; euler: joint damping only) and to
# sqrt(4 - 2 dt d) when explicit (euler: the actuator's kv). kd = 0.88 gives dt d = 0.88: limits 2.4 and 1.5.
CASES = [
    ("implicitfast", 1.8, 0.0, 0.0, False),
    ("implicitfast", 2.2, 0.0, 0.0, True),
    ("implicitfast", 2.2, 0.88, 0.0, False),  # kv implicit: limit 2.4
    ("implicitfast", 2.6, 0.88, 0.0, True),
    ("euler", 1.8, 0.0, 0.0, False),
    ("euler", 2.2, 0.0, 0.0, True),
    ("euler", 2.2, 0.0, 0.88, False),  # joint damping implicit under euler too: limit 2.4
    ("euler", 1.8, 0.88, 0.0, True),  # the actuator's kv explicit under euler: limit 1.5
    ("euler", 1.3, 0.88, 0.0, False),
]


@pytest.mark.parametrize("integrator, omega_dt, kd, joint_damping, diverges", CASES)
def test_criterion_predicts_divergence_in_mujoco_c(tmp_path, integrator, omega_dt, kd, joint_damping, diverges):
    model, _ = build(tmp_path, kp_at(omega_dt), kd, integrator, joint_damping)
    (drive,) = drive_stability(model)
    assert drive.omega_dt == pytest.approx(omega_dt, rel=1e-6)
    assert diverges_in_mujoco_c(model) == diverges
    assert (drive.ratio > 1.0) == diverges, (drive.ratio, drive.limit)


def test_stable_drive_is_quiet_and_unstable_one_warns(tmp_path):
    _, quiet = build(tmp_path, kp=kp_at(0.3), kd=0.05)
    assert quiet == []
    model, (message,) = build(tmp_path, kp=kp_at(2.6), kd=0.0)  # exactly one warning: one drive
    assert diverges_in_mujoco_c(model)
    for part in ("'spin'", f"kp={kp_at(2.6):.4g}", "kd=0", f"I_eff={ROTOR_INERTIA:.4g}", f"dt={DT:.4g}",
                 "dt*sqrt(kp/I_eff)=2.6", "ratio 1.3", "env.control.stiffness", "sim.dt", "env.asset.armature"):
        assert part in message, (part, message)


def test_margin_warns_before_the_limit(tmp_path):
    """Between SAFETY and 1 the drive is still stable in MuJoCo C but is reported (the estimate is a lower bound)."""
    omega_dt = 2.0 * (SAFETY + 1.0) / 2.0
    model, messages = build(tmp_path, kp=kp_at(omega_dt))
    assert not diverges_in_mujoco_c(model) and len(messages) == 1
    _, messages = build(tmp_path, kp=kp_at(2.0 * SAFETY * 0.9))
    assert messages == []


def test_armature_adds_to_the_effective_inertia(tmp_path):
    """IGE's stiffness 1000 on a tiny rotor diverges; enough armature makes the same gains stable."""
    kp = 1000.0
    model, messages = build(tmp_path, kp=kp)
    assert len(messages) == 1 and diverges_in_mujoco_c(model)
    armature = 1.0  # I_eff 1.01: dt * sqrt(1000 / 1.01) = 0.31
    model, messages = build(tmp_path, kp=kp, armature=armature)
    (drive,) = drive_stability(model)
    assert drive.inertia == pytest.approx(ROTOR_INERTIA + armature, rel=1e-9)
    assert messages == [] and not diverges_in_mujoco_c(model)


def test_effective_inertia_on_a_floating_base_is_the_inverse_mass_matrix_diagonal(tmp_path):
    """On a floating base the body recoils: I_eff is 1 / (M^-1)_ii from MuJoCo C's full mass matrix, below M_ii."""
    model, _ = build(tmp_path, kp=1.0, floating=True)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    dof = model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "spin")]
    (drive,) = drive_stability(model)
    assert drive.inertia == pytest.approx(1.0 / np.linalg.inv(full)[dof, dof], rel=1e-6)
    assert drive.inertia < full[dof, dof] - 1e-6
    assert drive.omega_dt == pytest.approx(DT * math.sqrt(1.0 / drive.inertia), rel=1e-9)


# Cartpole with its pole hinge on a PD drive far too stiff for the 60 Hz step, its force uncapped (the URDF's effort
# limit would cap the spring, and the pole would chatter at the cap instead of diverging).
STIFF_POLE = ["task.env.numActions=2", "+task.env.control.driveMode.cart_to_pole=position",
              "+task.env.control.stiffness={cart_to_pole: 1e8}", "+task.env.control.effortLimit={cart_to_pole: 1e12}",
              "+task.sim.overflowCheckInterval=2"]


def test_blowup_warning_reaches_make_users_and_names_the_joint_mujoco_c_sees_diverge():
    import isaacgymenvs_mw

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # The check runs after every step here: the blow-ups it names are those of the first step. (The blown-up
        # worlds are then reset by the task, to a random start that may blow up again.)
        task = isaacgymenvs_mw.make("Cartpole", num_envs=3, sim_device="cpu", rl_device="cpu",
                                    overrides=[*STIFF_POLE[:-1], "+task.sim.overflowCheckInterval=1"])
        task.reset()
        start_q, start_v = task.sim.qpos[0].double().numpy(), task.sim.qvel[0].double().numpy()
        extras = task.step(task.zero_actions())[3]
        assert bool(extras["nonfinite_resets"].all())  # one step is enough to blow every world up
    messages = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert any("PD drive of joint 'cart_to_pole'" in m for m in messages)  # at build time
    (blowup,) = [m for m in messages if "blew up" in m]

    # Reference: MuJoCo C steps the same model once from env 0's reset state with the same (zero) commands.
    model = task.sim.mj_model
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = start_q, start_v
    mujoco.mj_step(model, data)
    dof = int(np.argmax(np.abs(data.qvel)))
    joint = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, int(model.dof_jntid[dof]))
    assert np.abs(data.qvel).max() > 1e4
    assert blowup.startswith("3 world(s) blew up in the last 1 env step")
    assert f"First diverging joint: '{joint}' in world 0 (|velocity| {abs(data.qvel[dof]):.3g} " in blowup
    for key in ("env.control.stiffness", "sim.dt", "env.controlFrequencyInv", "env.asset.armature"):
        assert key in blowup


def test_no_blowup_no_warning():
    import isaacgymenvs_mw

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        task = isaacgymenvs_mw.make("Cartpole", num_envs=2, sim_device="cpu", rl_device="cpu",
                                    overrides=["+task.sim.overflowCheckInterval=2"])
        task.reset()
        for _ in range(2):
            task.step(task.zero_actions())
    assert not [w for w in caught if "blew up" in str(w.message) or "PD drive" in str(w.message)]
    assert task.blowups.poll() is None
