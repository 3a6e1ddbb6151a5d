"""The G1 humanoid (assets/mjcf/g1.xml, cfg/task/G1.yaml): the model against Unitree's published figures, standing,
the biped reward terms against numpy, body velocities against MuJoCo C, the observation layout, G1Terrain.

Expected values come from outside the package: figures typed from Unitree's files (named per entry), formulas
written here in numpy, MuJoCo C (``mj_objectVelocity``, ``mj_step``) on the task's compiled host model.
"""

from __future__ import annotations

import math
import re

import mujoco
import numpy as np
import pytest
import torch

import isaacgymenvs_mw
from conftest import REPO_ROOT

N = 2
ASSET = REPO_ROOT / "assets" / "mjcf" / "g1.xml"
CONTROL_DT = 0.005 * 4  # cfg/legged/base.yaml sim.dt, env.controlFrequencyInv

# unitreerobotics/unitree_mujoco unitree_robots/g1/g1_23dof.xml (commit cff46dd): joint ranges (rad) and motor
# torque limits (N m, actuatorfrcrange) per joint; the left and right sides mirror the roll ranges.
FIGURES = {
    "hip_pitch": (-2.5307, 2.8798, 88.0),
    "left_hip_roll": (-0.5236, 2.9671, 88.0),
    "right_hip_roll": (-2.9671, 0.5236, 88.0),
    "hip_yaw": (-2.7576, 2.7576, 88.0),
    "knee": (-0.087267, 2.8798, 139.0),
    "ankle_pitch": (-0.87267, 0.5236, 50.0),
    "ankle_roll": (-0.2618, 0.2618, 50.0),
    "waist_yaw": (-2.618, 2.618, 88.0),
    "shoulder_pitch": (-3.0892, 2.6704, 25.0),
    "left_shoulder_roll": (-1.5882, 2.2515, 25.0),
    "right_shoulder_roll": (-2.2515, 1.5882, 25.0),
    "shoulder_yaw": (-2.618, 2.618, 25.0),
    "elbow": (-1.0472, 2.0944, 25.0),
    "wrist_roll": (-1.97222, 1.97222, 25.0),
}
# The same file's link masses (kg): pelvis, one leg (hip pitch, hip roll, hip yaw, knee, ankle pitch, ankle roll),
# torso (waist roll/pitch links locked into it), one arm (shoulder pitch, roll, yaw, elbow, wrist + rubber hand).
MASSES = {"pelvis": 3.813, "leg": 1.35 + 1.52 + 1.702 + 1.932 + 0.074 + 0.608, "torso": 9.842,
          "arm": 0.718 + 0.643 + 0.734 + 0.6 + 0.356929}
UNITREE_ORDER = [  # the 23-DoF G1's motor order (g1_23dof.xml actuators without the six locked joints)
    *(f"left_{j}_joint" for j in ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll")),
    *(f"right_{j}_joint" for j in ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll")),
    "waist_yaw_joint",
    *(f"left_{j}_joint" for j in ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "wrist_roll")),
    *(f"right_{j}_joint" for j in ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "wrist_roll")),
]
# cfg/task/G1.yaml defaultJointAngles, written out by joint-name fragment.
DEFAULT_POSE = {"hip_pitch": -0.1, "knee": 0.3, "ankle_pitch": -0.2, "shoulder_pitch": 0.2,
                "left_shoulder_roll": 0.2, "right_shoulder_roll": -0.2, "elbow": 0.9}

QUIET = ["task.task.randomize=False"]
AT_REST = ["task.env.resetDofPosScale=[1.0,1.0]"]  # G1.yaml already starts at rest (resetRootVelocityRange 0)


def default_angle(joint: str) -> float:
    """The joint's angle in DEFAULT_POSE: the longest fragment of its name that has one, else 0."""
    return figure(joint, DEFAULT_POSE) if any(k in joint for k in DEFAULT_POSE) else 0.0


def figure(joint: str, table: dict):
    """The entry of ``table`` whose key is the longest fragment of the joint's name."""
    keys = [k for k in table if k in joint]
    assert keys, joint
    return table[max(keys, key=len)]


@pytest.fixture(scope="module")
def g1():
    return isaacgymenvs_mw.make("G1", num_envs=N, sim_device="cpu", rl_device="cpu", headless=True,
                                overrides=QUIET + AT_REST)


# ------------------------------------------------------------------------------------------------------- model
def test_model_matches_unitree_figures():
    m = mujoco.MjModel.from_xml_path(str(ASSET))
    hinges = [m.joint(j).name for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    assert hinges == UNITREE_ORDER  # 23 joints, in Unitree's motor order
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE and m.nu == 0  # floating base; drives come from the YAML
    total = MASSES["pelvis"] + 2 * MASSES["leg"] + MASSES["torso"] + 2 * MASSES["arm"]
    assert m.body_subtreemass[0] == pytest.approx(total, abs=1e-9)
    assert 33.0 < total < 36.0  # Unitree's product page: about 35 kg
    for name in hinges:
        lo, hi, effort = figure(name, FIGURES)
        j = m.joint(name)
        assert tuple(j.range) == pytest.approx((lo, hi), abs=1e-9), name
        assert m.jnt_actfrclimited[j.id] and tuple(m.jnt_actfrcrange[j.id]) == pytest.approx((-effort, effort)), name
    assert m.body_mass[m.body("torso_link").id] == pytest.approx(MASSES["torso"])
    assert m.body_mass[m.body("left_wrist_roll_rubber_hand").id] == pytest.approx(0.356929)


def test_locked_default_pose_stands_on_its_soles():
    """The default pose welded rigid (joints removed, MuJoCo C): the soles carry it for 2 s, so masses, centre of
    mass and contact points agree; what topples the jointed robot is its joint compliance (tests below)."""
    spec = mujoco.MjSpec.from_file(str(ASSET))
    for joint in [j for j in spec.joints if j.type == mujoco.mjtJoint.mjJNT_HINGE]:
        angle = default_angle(joint.name)
        turn = np.zeros(4)
        mujoco.mju_axisAngle2Quat(turn, np.asarray(joint.axis, dtype=float), angle)
        quat = np.zeros(4)
        mujoco.mju_mulQuat(quat, np.asarray(joint.parent.quat, dtype=float), turn)
        joint.parent.quat = quat
        spec.delete(joint)
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
    spec.option.timestep = 0.005
    m = spec.compile()
    d = mujoco.MjData(m)
    d.qpos[2] = 0.79
    for _ in range(400):
        mujoco.mj_step(m, d)
    assert d.qpos[2] == pytest.approx(0.784, abs=0.005)  # G1.yaml: the default pose stands at 0.784 m
    assert np.abs(d.qvel).max() < 1e-3 and d.ncon == 8  # at rest on the eight sole spheres


def ankle_stiffness_bound() -> tuple[float, float]:
    """(m g h / 2, CoM lead): the least stiffness per ankle-pitch drive for which the default pose, feet flat, is
    not an inverted pendulum. Leaning the rigid body by theta about the two ankle-pitch axes moves its centre of
    mass by h theta: gravity pushes on with m g h theta, the two drives pull back with 2 kp theta, so kp < m g h / 2
    falls whatever the damping (any compliance of knees and hips only adds to the lean). The lead is the centre of
    mass's horizontal distance in front of the ankle axes, which the drives must also hold (m g lead)."""
    m = mujoco.MjModel.from_xml_path(str(ASSET))
    d = mujoco.MjData(m)
    d.qpos[2] = 0.784  # upright, standing on the soles
    for j in range(1, m.njnt):
        d.qpos[m.jnt_qposadr[j]] = default_angle(m.joint(j).name)
    mujoco.mj_forward(m, d)
    axes = np.mean([d.xanchor[m.joint(f"{s}_ankle_pitch_joint").id] for s in ("left", "right")], axis=0)
    com = d.subtree_com[m.body("pelvis").id]
    mass = m.body_subtreemass[m.body("pelvis").id]
    return mass * 9.81 * (com[2] - axes[2]) / 2.0, com[0] - axes[0]


def test_default_pose_needs_stiffer_ankles_than_the_published_gains(g1):
    """Why the G1 cannot stand on PD alone with any published gain set: the bound m g h / 2 is about 109 N m/rad
    per ankle, and unitree_rl_gym gives 40 (menagerie's g1_mjx 20, mjlab's armature x (2 pi 10 Hz)^2 28.5). The
    default pose also carries its centre of mass ~3.7 cm in front of the ankle axes (over the middle of the soles,
    which reach 12 cm forward of the axes), a steady 12 N m that the drives hold."""
    bound, lead = ankle_stiffness_bound()
    assert 100.0 < bound < 120.0
    assert 0.03 < lead < 0.045
    gains = g1.sim.joint_pd_gains()
    assert gains["left_ankle_pitch_joint"][0] == gains["right_ankle_pitch_joint"][0] == 40.0  # cfg/task/G1.yaml
    assert gains["left_ankle_pitch_joint"][0] < bound / 2


def test_zero_actions_with_the_published_gains_topple_forward(g1):
    """Zero actions from rest with G1.yaml's gains: the first 0.5 s hold the pose, then the body leans forward
    about the ankles, as the bound says, and the episode ends before 2 s: the policy has to balance from the
    first step. MuJoCo C's mj_step on the same model falls too (the pelvis below terminationHeight within 2 s;
    the trajectories part once the feet rock, so only the outcome is compared)."""
    g1.reset_envs(torch.arange(N))
    m = g1.sim.mj_model
    d = mujoco.MjData(m)
    d.qpos[:] = g1.sim.qpos[0].numpy()
    d.ctrl[:] = g1.default_dof_pos.reshape(-1).numpy()
    while d.time < 2.0 and d.qpos[2] > 0.4:  # G1.yaml terminationHeight
        mujoco.mj_step(m, d)
    assert d.qpos[2] < 0.4
    for _ in range(int(0.5 / CONTROL_DT)):
        g1.step(g1.zero_actions())
        assert not bool(g1.reset_buf.any())
    assert torch.all((g1.sim.root_pos[:, 2] - 0.78).abs() < 0.03)
    assert torch.all((g1.sim.dof_pos - g1.default_dof_pos).abs() < 0.15)
    assert torch.all(g1.projected_gravity[:, 2] < -0.99)  # within 8 degrees of upright
    assert bool(g1._feet_contact().all())
    lead = []
    for _ in range(int(1.5 / CONTROL_DT)):
        lead.append(g1.sim.root_pos[:, 0].clone())
        g1.step(g1.zero_actions())
        if bool(g1.reset_buf.all()):
            break
    assert bool(g1.reset_buf.all()) and bool(g1.terminated.all())  # fell (not a timeout) before 2 s
    assert torch.all(lead[-1] > 0.1)  # forward, over the toes


def test_zero_actions_stand_2s_with_ankles_above_the_bound():
    """The issue's "stands 2 s with zero actions (PD at the default pose)" where physics allows it: the ankle
    drives set to 300 N m/rad (> 2.5 x the bound; every other figure as G1.yaml) hold the default pose for 2 s in
    MuJoCo Warp, and MuJoCo C's mj_step on the same model agrees. The physics step is 2.5 ms (8 per 20 ms policy
    step): at G1.yaml's 5 ms these stiff ankles make the light feet rock heel to toe (ankle velocities reversing
    every step), and whether the robot falls then depends on the damping and on rounding."""
    bound, _ = ankle_stiffness_bound()
    assert 300.0 > 2.5 * bound
    task = isaacgymenvs_mw.make("G1", num_envs=1, sim_device="cpu", rl_device="cpu", headless=True,
                                overrides=QUIET + AT_REST + ["task.env.control.stiffness={.*_ankle_.*:300.0}",
                                                             "task.sim.dt=0.0025", "task.env.controlFrequencyInv=8"])
    task.reset_envs(torch.arange(1))
    m = task.sim.mj_model
    assert m.opt.timestep == 0.0025 and task.control_dt == pytest.approx(CONTROL_DT)
    d = mujoco.MjData(m)
    d.qpos[:] = task.sim.qpos[0].numpy()
    d.ctrl[:] = task.default_dof_pos.reshape(-1).numpy()
    for _ in range(int(2.0 / CONTROL_DT)):
        task.step(task.zero_actions())
        assert not bool(task.reset_buf.any())
        assert abs(float(task.sim.root_pos[0, 2]) - 0.784) < 0.02  # the standing height of the locked pose
    for _ in range(int(2.0 / CONTROL_DT) * 8):
        mujoco.mj_step(m, d)
    np.testing.assert_allclose(task.sim.qpos[0].numpy(), d.qpos, atol=1e-4)
    assert float((task.sim.dof_pos - task.default_dof_pos).abs().max()) < 0.05
    assert float(task.projected_gravity[0, 2]) < -0.995  # within 6 degrees of upright
    assert float(task.sim.qvel[0].abs().max()) < 0.05  # at rest, not falling slowly
    assert bool(task._feet_contact().all())


def test_task_model_drives_and_layout(g1):
    m = g1.sim.mj_model
    assert g1.sim.dof_names == UNITREE_ORDER and g1.num_actions == 23
    gains = g1.sim.joint_pd_gains()
    yaml_kp = {"hip": 100.0, "knee": 150.0, "ankle": 40.0, "waist": 75.0, "shoulder": 75.0, "elbow": 75.0,
               "wrist": 20.0}  # cfg/task/G1.yaml env.control.stiffness
    for name in UNITREE_ORDER:
        assert gains[name][0] == pytest.approx(figure(name, yaml_kp)), name
    assert g1.feet == ["left_ankle_roll_link", "right_ankle_roll_link"]
    assert g1.terminate_bodies == ["pelvis", "torso_link"]
    expected = torch.tensor([default_angle(n) for n in UNITREE_ORDER])
    assert torch.allclose(g1.default_dof_pos, expected)
    # Observation: 12 + 3 x 23 (the legged terms scale with the joint count); critic: + 5 (2 feet).
    sizes = {t.name: t.size for t in g1.observations.obs_layout.terms}
    assert sizes == {"base_lin_vel": 3, "base_ang_vel": 3, "projected_gravity": 3, "commands": 3, "dof_pos": 23,
                     "dof_vel": 23, "actions": 23}
    assert g1.observations.obs_layout.size == 81 == g1.obs_buf.shape[1]
    assert g1.observations.state_layout.size == 86 == g1.states_buf.shape[1]
    assert g1.observations.state_layout.slices["feet_contact"] == slice(84, 86)
    assert m.nu == 23


# ------------------------------------------------------------------------------------------------ reward terms
def scaled_terms(task, names):
    return {n: getattr(task, f"_reward_{n}")() for n in names}


def test_feet_air_time_biped_against_numpy(g1):
    rng = np.random.default_rng(0)
    steps = 40
    contacts = rng.random((steps, N, 2)) < 0.6
    g1.commands[:] = torch.tensor([[0.5, 0.0, 0.0], [0.05, 0.0, 0.3]])  # env 1: standing command, no reward
    g1.feet_swing_time.zero_()
    g1.feet_stance_time.zero_()
    stance, swing = np.zeros((N, 2)), np.zeros((N, 2))
    cap = 0.4  # cfg/task/G1.yaml feetAirTimeTarget
    for k in range(steps):
        forces = np.where(contacts[k], 50.0, 0.0)
        g1.contact_force_norm[:, g1._feet_idx] = torch.tensor(forces, dtype=torch.float)
        got = g1._reward_feet_air_time_biped().numpy()
        stance = np.where(contacts[k], stance + CONTROL_DT, 0.0)
        swing = np.where(contacts[k], 0.0, swing + CONTROL_DT)
        want = np.zeros(N)
        for e in range(N):
            if contacts[k, e].sum() == 1:
                phase = [stance[e, f] if contacts[k, e, f] else swing[e, f] for f in range(2)]
                want[e] = min(min(phase), cap)
        want *= np.array([1.0, 0.0])
        np.testing.assert_allclose(got, want, atol=1e-6)


def test_feet_slip_clearance_alive_and_deviation_against_numpy(g1):
    rng = np.random.default_rng(1)
    contact = np.array([[True, False], [False, False]])
    g1.contact_force_norm[:, g1._feet_idx] = torch.tensor(np.where(contact, 20.0, 0.0), dtype=torch.float)
    vel = rng.normal(size=(N, 2, 3))
    g1._feet_lin_vel = lambda: torch.tensor(vel, dtype=torch.float)  # instance override: the formula alone
    try:
        slip = g1._reward_feet_slip().numpy()
    finally:
        del g1._feet_lin_vel
    np.testing.assert_allclose(slip, (np.linalg.norm(vel[..., :2], axis=-1) * contact).sum(1), rtol=1e-6)

    heights = np.array([[0.02, 0.11], [0.05, 0.30]])
    g1.sim.xpos[:, g1._feet_body_ids, 2] = torch.tensor(heights, dtype=torch.float)
    want = (np.square(heights - 0.08) * ~contact).sum(1)  # G1.yaml feetClearanceTarget 0.08
    np.testing.assert_allclose(g1._reward_feet_clearance().numpy(), want, rtol=1e-6)

    g1.terminate_buf[:] = torch.tensor([True, False])
    g1.timeout_buf.zero_()
    np.testing.assert_array_equal(g1._reward_alive().numpy(), [0.0, 1.0])

    q = g1.default_dof_pos.numpy() + rng.normal(scale=0.3, size=(N, 23))
    g1.sim.dof_pos[:] = torch.tensor(q, dtype=torch.float)
    dev = np.abs(q - g1.default_dof_pos.numpy())
    hips = [bool(re.search("hip_roll|hip_yaw", n)) for n in UNITREE_ORDER]  # G1.yaml jointDeviationJoints
    upper = [bool(re.search("waist|shoulder|elbow|wrist", n)) for n in UNITREE_ORDER]  # upperBodyJoints
    assert sum(hips) == 4 and sum(upper) == 11
    np.testing.assert_allclose(g1._reward_joint_deviation().numpy(), dev[:, hips].sum(1), rtol=1e-5)
    np.testing.assert_allclose(g1._reward_upper_body_posture().numpy(), dev[:, upper].sum(1), rtol=1e-5)


def test_termination_below_termination_height(g1):
    g1.reset_envs(torch.arange(N))
    g1.progress_buf.zero_()
    g1.contact_force_norm.zero_()
    g1.sim.root_pos[:, 2] = torch.tensor([0.39, 0.41])  # cfg/task/G1.yaml terminationHeight 0.4
    assert g1.check_termination().tolist() == [True, False]
    g1.reset_envs(torch.arange(N))


def test_foot_velocity_matches_mujoco_c(g1):
    """Simulator.body_lin_vel (cvel and subtree_com) against MuJoCo C's mj_objectVelocity on the same state."""
    g1.reset_envs(torch.arange(N))
    torch.manual_seed(3)
    for _ in range(5):
        g1.step(torch.randn(N, 23))
    g1.sim.forward()  # velocities and poses of the current qpos / qvel (a step leaves those of its start)
    got = g1._feet_lin_vel().numpy()
    m = g1.sim.mj_model
    d = mujoco.MjData(m)
    for env in range(N):
        d.qpos[:] = g1.sim.qpos[env].numpy()
        d.qvel[:] = g1.sim.qvel[env].numpy()
        mujoco.mj_forward(m, d)
        for i, body in enumerate(g1.feet):
            v = np.zeros(6)
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_XBODY, m.body(body).id, v, 0)  # origin, world axes
            np.testing.assert_allclose(got[env, i], v[3:], atol=1e-4)
        assert np.abs(got[env]).max() > 0.05  # the feet do move: the comparison is not 0 == 0


# ---------------------------------------------------------------------------------------------------- terrain
def test_g1_terrain_builds_and_steps():
    task = isaacgymenvs_mw.make(
        "G1Terrain", num_envs=N, sim_device="cpu", rl_device="cpu", headless=True,
        overrides=["task.env.terrain.numLevels=2", "task.env.terrain.numTerrains=2", "task.env.terrain.maxInitLevel=1",
                   "task.env.terrain.borderSize=2.0"])
    obs = task.reset()
    assert obs["obs"].shape == (N, 81 + 187) and obs["states"].shape == (N, 86 + 187)
    for _ in range(20):
        obs, rew, done, _ = task.step(0.3 * torch.randn(N, 23))
    assert torch.isfinite(obs["obs"]).all() and torch.isfinite(rew).all()
    # On terrain the base height is measured above the ground under the base.
    ground = task.ground.height_map(task.sim.root_pos[:, 0], task.sim.root_pos[:, 1])
    assert torch.allclose(task._base_height(), task.sim.root_pos[:, 2] - ground)
    assert math.isclose(task.feet_clearance_target, 0.08)
