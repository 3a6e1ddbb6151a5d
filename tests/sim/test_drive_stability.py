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
import torch

from isaacgymenvs_mw.sim import JointDrive, ModelRequest, SolverOptions, build_model
from isaacgymenvs_mw.sim.stability import PROBE_STARTS, PROBE_STEPS, SAFETY, drive_stability, probe_divergence

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
    assert task.episode.blowups.poll() is None


# ------------------------------------------------------------------------------------------------ closed chains
# A two-link leg under a torso that slides vertically; its foot is pinned to the world by an equality connect
# constraint (IsaacGymEnvs' BallBalance pins its legs' feet the same way). Both leg joints carry YAML PD drives.
# With the pin the chain has one degree of freedom and the drives fight the constraint; the single-joint estimate
# (sim/stability.py) cannot see that.
LEG_MJCF = """<mujoco model="pinned_leg">
  <worldbody>
    <body name="torso" pos="0 0 0.5">
      <joint name="lift" type="slide" axis="0 0 1"/>
      <geom type="box" size="0.1 0.1 0.02" mass="1"/>
      <body name="upper">
        <joint name="hip" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 -0.2" size="0.02" mass="0.2"/>
        <body name="lower" pos="0.2 0 -0.2">
          <joint name="knee" type="hinge" axis="0 1 0"/>
          <geom type="capsule" fromto="0 0 0 -0.2 0 -0.2" size="0.02" mass="0.2"/>
        </body>
      </body>
    </body>
  </worldbody>
  {equality}
</mujoco>
"""
PIN = '<equality><connect name="foot_pin" body1="lower" anchor="-0.2 0 -0.2"/></equality>'
FOOT = np.array([-0.2, 0.0, -0.2])  # the pinned point in the lower leg's frame
LEG_DT = 0.01  # BallBalance's


def build_leg(tmp_path, kp: float, kd: float, integrator: str, armature: float = 0.0, joint_damping: float = 0.0,
              pinned: bool = True, probe: bool = True):
    path = tmp_path / "leg.xml"
    path.write_text(LEG_MJCF.replace("{equality}", PIN if pinned else ""))
    legs = ("hip", "knee")
    request = ModelRequest(
        asset_file=path, fix_base=True, keep_asset_contacts=True,
        drives={j: JointDrive("position", kp, kd) for j in legs},
        armature={j: armature for j in legs} if armature else {},
        joint_damping={j: joint_damping for j in legs} if joint_damping else {},
        options=SolverOptions(dt=LEG_DT, integrator=integrator, enable_contacts=False), stability_probe=probe)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = build_model(request)
    return model, [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]


def foot_drift(model: mujoco.MjModel, data: mujoco.MjData) -> float:
    """How far the foot is from where it was pinned (m), from the lower leg's pose: not from MuJoCo's residuals."""
    lower = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "lower")
    pinned = model.eq_data[0, 3:6]  # the pin's point in the world (body2 is the world), set by the compiler
    return float(np.linalg.norm(data.xpos[lower] + data.xmat[lower].reshape(3, 3) @ FOOT - pinned))


def leg_diverges_in_mujoco_c(model: mujoco.MjModel, seconds: float = 5.0) -> bool:
    """The reference: MuJoCo C steps the leg for ``seconds`` from its initial pose and from two poses 0.01 rad off,
    the drives holding the initial pose; diverged: non-finite, a speed above 1e3, or the foot 0.1 m off its pin."""
    for offset in (0.0, 0.01, -0.01):
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        data.ctrl[:] = data.actuator_length  # targets: the initial joint angles
        data.qpos[model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "knee")]] += offset
        for _ in range(int(seconds / model.opt.timestep)):
            mujoco.mj_step(model, data)
            if (not np.isfinite(data.qpos).all() or np.abs(data.qvel).max() > 1e3
                    or data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number):
                return True
            if model.neq and foot_drift(model, data) > 0.1:
                return True
    return False


@pytest.mark.parametrize("integrator, kd, joint_damping", [
    ("implicitfast", 100.0, 0.0),  # the actuator's kv, integrated implicitly (the default integrator)
    ("euler", 0.0, 100.0),  # the joints' own damping: implicit under euler too
])
def test_closed_chain_that_the_estimate_passes_is_told_it_will_blow_up(tmp_path, integrator, kd, joint_damping):
    """BallBalance's gains, kp 4000 and damping 100: the single-joint estimate sees ratio ~0.44 (below SAFETY: no
    warning before the probe), MuJoCo C diverges within a second with the foot pinned, and the probe says so."""
    model, messages = build_leg(tmp_path, 4000.0, kd, integrator, joint_damping=joint_damping)
    ratios = [d.ratio for d in drive_stability(model)]
    assert len(ratios) == 2 and all(0.4 < r < SAFETY for r in ratios), ratios
    assert leg_diverges_in_mujoco_c(model)
    (message,) = messages
    assert message.startswith("This model will blow its worlds up: a build-time probe in MuJoCo C diverged: ")
    for part in ("'hip'", "'knee'", "ratio 0.44", "closed chains", "env.control.stiffness", "env.asset.armature",
                 "sim.dt"):
        assert part in message, (part, message)
    # The coupling is the cause: the same drives on the same leg with its foot free do not diverge.
    free, messages = build_leg(tmp_path, 4000.0, kd, integrator, joint_damping=joint_damping, pinned=False)
    assert not leg_diverges_in_mujoco_c(free) and messages == []


def test_closed_chain_the_estimate_flags_but_that_runs_stable_is_not_told_it_will(tmp_path):
    """The reverse: euler, kp 1000, kd 10, armature 0.1 (the issue's stable BallBalance port) has ratios ~0.6 and 0.7
    (past SAFETY: reported), runs stable in MuJoCo C, and is told it "may" be unstable, not that it will blow up."""
    model, messages = build_leg(tmp_path, 1000.0, 10.0, "euler", armature=0.1)
    ratios = sorted(d.ratio for d in drive_stability(model))
    assert SAFETY < ratios[0] < ratios[1] < 1.0, ratios
    assert not leg_diverges_in_mujoco_c(model)
    assert len(messages) == 2
    for message in messages:
        assert "may be numerically unstable" in message and "will" not in message, message
        assert "stayed stable" in message


def test_probe_can_be_switched_off(tmp_path):
    """sim.stabilityProbe: False skips the probe: the diverging leg gets no "will" (only the estimate speaks)."""
    _, messages = build_leg(tmp_path, 4000.0, 100.0, "implicitfast", probe=False)
    assert messages == []
    _, messages = build_leg(tmp_path, 1000.0, 10.0, "euler", armature=0.1, probe=False)
    assert len(messages) == 2 and all("sim.stabilityProbe: False" in m and "may be" in m for m in messages)


def test_probe_is_quick_on_the_leg(tmp_path):
    model, _ = build_leg(tmp_path, 1000.0, 10.0, "euler", armature=0.1, probe=False)
    result = probe_divergence(model)
    assert not result.diverged and result.steps == PROBE_STEPS * PROBE_STARTS
    assert result.seconds < 1.0


def test_run_time_check_resets_a_world_whose_pinned_foot_drifted(tmp_path):
    """A world whose foot is 0.5 m off its pin at modest, finite speeds is reset (the NaN/speed check alone would
    keep it); one 1 cm off is not. The reference drift comes from MuJoCo C's kinematics of the same states."""
    from isaacgymenvs_mw.sim import Simulator
    from isaacgymenvs_mw.sim.divergence import EQUALITY_DIVERGED
    from isaacgymenvs_mw.sim.blowup import BlowupLog

    model, _ = build_leg(tmp_path, 1000.0, 10.0, "euler", armature=0.1, probe=False)
    sim = Simulator(model, 3, "cpu")
    blowups = BlowupLog(sim)
    lift = model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "lift")]
    offsets = [0.0, 0.5, 0.01]  # the torso lifted this far: the foot leaves its pin by as much
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    sim.ctrl[:] = torch.as_tensor(data.actuator_length, dtype=sim.ctrl.dtype)  # hold the initial angles
    drift = []
    for world, offset in enumerate(offsets):
        sim.qpos[world, lift] += offset
        data.qpos[:] = sim.qpos[world].double().numpy()
        mujoco.mj_kinematics(model, data)
        drift.append(foot_drift(model, data))
    assert drift[1] == pytest.approx(0.5, abs=1e-3) and drift[2] == pytest.approx(0.01, abs=1e-3)

    sim.simulate()
    assert torch.isfinite(sim.qvel).all() and float(sim.qvel.abs().max()) < 1e3  # the old check keeps them all
    violation, equality = sim.equality_violation()
    assert violation.tolist() == pytest.approx([0.0, 0.5, 0.01], abs=2e-3)  # the residual of the step's start state
    assert equality.tolist()[1] == 0
    bad = blowups.reset_nonfinite()
    assert bad.tolist() == [d > EQUALITY_DIVERGED for d in drift] == [False, True, False]
    with pytest.warns(RuntimeWarning, match="blew up"):
        message = blowups.poll(1)
    assert message.startswith("1 world(s) blew up in the last 1 env steps (NaN/inf state, a joint speed above "
                              "1e+04, or an equality constraint violated by more than 0.1)")
    assert "First diverging: equality constraint 'foot_pin' in world 1 (violated by 0.5" in message


def test_run_time_check_catches_the_closed_chain_that_drifts_apart(tmp_path):
    """BallBalance's gains on the pinned leg in MuJoCo Warp: the worlds are reset for the broken pin within a
    second, before any speed reaches 1e4 (MuJoCo C diverges the same way: test above)."""
    from isaacgymenvs_mw.sim import Simulator
    from isaacgymenvs_mw.sim.blowup import BlowupLog

    model, _ = build_leg(tmp_path, 4000.0, 100.0, "implicitfast", probe=False)
    sim = Simulator(model, 2, "cpu")
    blowups = BlowupLog(sim)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    sim.ctrl[:] = torch.as_tensor(data.actuator_length, dtype=sim.ctrl.dtype)
    sim.qvel[1] += 0.1  # a second world slightly off equilibrium
    for step in range(100):
        sim.simulate()
        if bool(blowups.reset_nonfinite().any()):
            break
    else:
        pytest.fail("no world was reset in 1 s")
    with pytest.warns(RuntimeWarning, match="blew up"):
        message = blowups.poll()
    assert "First diverging: equality constraint 'foot_pin'" in message, message
