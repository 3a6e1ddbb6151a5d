"""Ant and Humanoid (IsaacGymEnvs' locomotion tasks on this project's MJCFs): model, observation layout and values,
reward formulas (a numpy re-implementation written here), falls and resets, physics against MuJoCo C, bad input."""

from __future__ import annotations

import math
import re

import mujoco
import numpy as np
import pytest
import torch

import isaacgymenvs_mw
from isaacgymenvs_mw.tasks.base.metrics import PER_STEP
from conftest import REPO_ROOT

ASSETS = REPO_ROOT / "assets" / "mjcf"
# IsaacGymEnvs' layouts: compute_ant_observations / compute_humanoid_observations.
IGE_LAYOUT = {
    "Ant": [("torso_height", 1), ("lin_vel", 3), ("ang_vel", 3), ("yaw", 1), ("roll", 1), ("angle_to_target", 1),
            ("up_proj", 1), ("heading_proj", 1), ("dof_pos_scaled", 8), ("dof_vel", 8), ("foot_forces", 24),
            ("actions", 8)],
    "Humanoid": [("torso_height", 1), ("lin_vel", 3), ("ang_vel", 3), ("yaw", 1), ("roll", 1),
                 ("angle_to_target", 1), ("up_proj", 1), ("heading_proj", 1), ("dof_pos_scaled", 21),
                 ("dof_vel", 21), ("dof_force", 21), ("foot_forces", 12), ("actions", 21)],
}
# Published motor gears (IsaacGymEnvs' nv_ant.xml / nv_humanoid.xml), by joint.
GEARS = {
    "Ant": {f"{j}_{i}": 15.0 for j in ("hip", "ankle") for i in range(1, 5)},
    "Humanoid": {"abdomen_x": 67.5, "abdomen_y": 67.5, "abdomen_z": 67.5, "right_hip_x": 45.0, "right_hip_z": 45.0,
                 "right_hip_y": 135.0, "right_knee": 90.0, "right_ankle_x": 22.5, "right_ankle_y": 22.5,
                 "right_shoulder1": 67.5, "right_shoulder2": 67.5, "right_elbow": 45.0},
}
GEARS["Humanoid"].update({k.replace("right", "left"): v for k, v in GEARS["Humanoid"].items() if "right" in k})


def make(name: str, num_envs: int = 4, overrides=()):
    return isaacgymenvs_mw.make(name, num_envs=num_envs, sim_device="cpu", rl_device="cpu", headless=True,
                                overrides=list(overrides))


@pytest.fixture(scope="module")
def ant():
    return make("Ant")


@pytest.fixture(scope="module")
def humanoid():
    return make("Humanoid")


def task_of(request, name):
    return request.getfixturevalue(name.lower())


def reset_with_reference(request, name, seed: int):
    """The module's task, reset, with its numpy reference and a seeded action generator."""
    task = task_of(request, name)
    task.reset()
    return task, Reference(task), torch.Generator().manual_seed(seed)


# ------------------------------------------------------------------------------------------ reference helpers
def rotation(q: np.ndarray) -> np.ndarray:
    """World-from-body rotation matrix of a (w, x, y, z) quaternion, by MuJoCo C."""
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, q.astype(np.float64))
    return mat.reshape(3, 3)


def wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


class Reference:
    """The task's quantities recomputed in numpy from qpos / qvel / sensordata and the YAML (start pose identity)."""

    def __init__(self, task):
        m, env = task.sim.mj_model, task.cfg["env"]
        self.task, self.env, self.m = task, env, m
        self.dofs = task.sim.dof_names
        ids = [m.joint(d).id for d in self.dofs]
        self.lo, self.hi = m.jnt_range[ids, 0], m.jnt_range[ids, 1]
        self.qadr = m.jnt_qposadr[ids]
        self.vadr = m.jnt_dofadr[ids]
        self.act_dof = [self.dofs.index(m.joint(m.actuator_trnid[a, 0]).name) for a in range(m.nu)]
        gear = m.actuator_gear[:, 0]
        self.act_ratio = gear / gear.max()
        self.dof_ratio = np.zeros(len(self.dofs))
        self.dof_ratio[self.act_dof] = self.act_ratio
        self.target = np.array(env["target"], dtype=np.float64)
        self.dt = m.opt.timestep * env["controlFrequencyInv"]
        self.feet = [m.sensor(s) for s in env["footContactSensors"]]

    def dist(self, qpos: np.ndarray) -> float:
        return float(np.hypot(*(self.target[:2] - qpos[:2])))

    def scaled_dofs(self, qpos: np.ndarray) -> np.ndarray:
        q = qpos[self.qadr]
        return (q - (self.lo + self.hi) / 2) / ((self.hi - self.lo) / 2)

    def observation(self, qpos, qvel, sensordata, qfrc_actuator, actions) -> dict[str, np.ndarray]:
        e = self.env
        rot = rotation(qpos[3:7])
        to_target = self.target - qpos[:3]
        to_target[2] = 0.0
        yaw = math.atan2(rot[1, 0], rot[0, 0])
        out = {
            "torso_height": [qpos[2]],
            "lin_vel": rot.T @ qvel[:3],
            "ang_vel": qvel[3:6] * e["angularVelocityScale"],  # MuJoCo: already in the body frame
            "yaw": [yaw],
            "roll": [math.atan2(rot[2, 1], rot[2, 2])],
            "angle_to_target": [wrap(math.atan2(to_target[1], to_target[0]) - yaw)],
            "up_proj": [rot[2, 2]],
            "heading_proj": [rot[:, 0] @ to_target / np.linalg.norm(to_target)],
            "dof_pos_scaled": self.scaled_dofs(qpos),
            "dof_vel": qvel[self.vadr] * e["dofVelocityScale"],
            "dof_force": qfrc_actuator[self.vadr] * e["contactForceScale"],
            "foot_forces": np.concatenate([sensordata[s.adr[0]:s.adr[0] + 6] for s in self.feet])
            * e["contactForceScale"],
            "actions": actions,
        }
        return {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}

    def reward(self, qpos_before, qpos, qvel, actions, humanoid: bool) -> tuple[float, bool]:
        """IsaacGymEnvs' compute_ant_reward / compute_humanoid_reward, written out for one env and one step."""
        e = self.env
        rot = rotation(qpos[3:7])
        to_target = self.target - qpos[:3]
        to_target[2] = 0.0
        heading_proj = rot[:, 0] @ to_target / np.linalg.norm(to_target)
        progress = (self.dist(qpos_before) - self.dist(qpos)) / self.dt
        up = e["upWeight"] if rot[2, 2] > e["upThreshold"] else 0.0
        hw, ht = e["headingWeight"], e["headingThreshold"]
        heading = hw if heading_proj > ht else hw * heading_proj / ht
        action_cost = e["actionsCost"] * np.sum(actions ** 2)
        vel = qvel[self.vadr][self.act_dof] * e["dofVelocityScale"]
        energy = e["energyCost"] * np.sum(np.abs(actions * vel) * self.act_ratio)
        scaled, thr = np.abs(self.scaled_dofs(qpos)), e["jointsAtLimitThreshold"]
        if humanoid:
            limit = e["jointsAtLimitCost"] * np.sum((scaled > thr) * (scaled - thr) / (1 - thr) * self.dof_ratio)
        else:
            limit = e["jointsAtLimitCost"] * np.sum(scaled > thr)
        total = progress + e["aliveReward"] + up + heading - action_cost - energy - limit
        fallen = qpos[2] < e["terminationHeight"]
        if fallen:
            total = e["deathCost"]
        return total, bool(fallen)


def state(task) -> tuple[np.ndarray, ...]:
    s = task.sim
    return (s.qpos.numpy().astype(np.float64).copy(), s.qvel.numpy().astype(np.float64).copy(),
            s.sensordata.numpy().astype(np.float64).copy(), s.qfrc_actuator.numpy().astype(np.float64).copy())


# ------------------------------------------------------------------------------------------------ model
@pytest.mark.parametrize("name, nu", [("Ant", 8), ("Humanoid", 21)])
def test_assets_compile_with_their_own_motors(name, nu):
    """The shipped MJCFs load in MuJoCo C as written: floating base, one motor per hinge, published gears."""
    m = mujoco.MjModel.from_xml_path(str(ASSETS / f"{name.lower()}.xml"))
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    assert m.njnt - 1 == m.nu == nu
    gears = {m.joint(m.actuator_trnid[a, 0]).name: m.actuator_gear[a, 0] for a in range(m.nu)}
    assert gears == pytest.approx(GEARS[name])
    np.testing.assert_array_equal(m.actuator_ctrlrange, np.tile([-1.0, 1.0], (nu, 1)))
    assert m.jnt_limited[1:].all()


@pytest.mark.parametrize("name", ["Ant", "Humanoid"])
def test_task_keeps_the_asset_motors_and_declares_igs_layout(request, name):
    task = task_of(request, name)
    m, ref = task.sim.mj_model, mujoco.MjModel.from_xml_path(str(ASSETS / f"{name.lower()}.xml"))
    assert m.nu == ref.nu == task.num_actions
    np.testing.assert_array_equal(m.actuator_gear, ref.actuator_gear)
    assert [(t.name, t.size) for t in task.observations.obs_layout.terms] == IGE_LAYOUT[name]
    assert task.num_obs == sum(size for _, size in IGE_LAYOUT[name]) == {"Ant": 60, "Humanoid": 108}[name]
    # the start pose comes from env.baseInitState
    np.testing.assert_allclose(m.qpos0[:7], task.cfg["env"]["baseInitState"]["pos"] + [1.0, 0.0, 0.0, 0.0])


@pytest.mark.parametrize("name", ["Ant", "Humanoid"])
def test_actions_become_motor_commands(request, name):
    task = task_of(request, name)
    task.reset()
    actions = torch.rand(task.num_envs, task.num_actions) * 4.0 - 2.0  # beyond clipActions = 1
    task.step(actions)
    clipped = actions.clamp(-1.0, 1.0) * task.cfg["env"]["powerScale"]
    torch.testing.assert_close(task.sim.ctrl, clipped)
    # MuJoCo applies gear x command at each actuator's joint
    gear = torch.tensor(task.sim.mj_model.actuator_gear[:, 0], dtype=torch.float)
    dof_of = [task.sim.dof_names.index(j) for j in task.sim.actuator_joints]
    torch.testing.assert_close(task.sim.qfrc_actuator[:, 6:][:, dof_of], clipped * gear, rtol=1e-5, atol=1e-4)


# --------------------------------------------------------------------------------------------- observation
@pytest.mark.parametrize("name", ["Ant", "Humanoid"])
def test_observation_terms_match_a_numpy_reference(request, name):
    task, ref, gen = reset_with_reference(request, name, seed=1)
    for _ in range(6):
        actions = torch.rand(task.num_envs, task.num_actions, generator=gen) * 2 - 1
        obs, _, reset, _ = task.step(actions)
    qpos, qvel, sens, qfrc = state(task)
    checked = 0
    for i in range(task.num_envs):
        if reset[i]:
            continue
        expected = ref.observation(qpos[i], qvel[i], sens[i], qfrc[i], actions[i].numpy())
        for term in task.observations.obs_layout.terms:
            got = obs["obs"][i, task.observations.obs_layout.slices[term.name]].numpy()
            np.testing.assert_allclose(got, expected[term.name], rtol=1e-4, atol=2e-4, err_msg=f"{name} {term.name}")
        checked += 1
    assert checked >= 2
    # foot sensors saw contact somewhere: the forces term is not a column of zeros
    assert np.abs(obs["obs"][:, task.observations.obs_layout.slices["foot_forces"]].numpy()).max() > 0


@pytest.mark.parametrize("name", ["Ant", "Humanoid"])
def test_the_observation_reset_returns_describes_the_new_state(request, name):
    # The policy's first action of every test episode comes from this observation; built from the torso state of
    # before the reset (zeros in a new task: "lying down"), it made 10-30 % of first episodes fall.
    task = task_of(request, name)
    task.step(torch.rand(task.num_envs, task.num_actions, generator=torch.Generator().manual_seed(4)) * 2 - 1)
    obs = task.reset()["obs"]
    ref = Reference(task)
    qpos, qvel, sens, _ = state(task)
    for i in range(task.num_envs):
        # a new episode shows no actuator force yet and no last action
        expected = ref.observation(qpos[i], qvel[i], sens[i], np.zeros_like(qvel[i]), np.zeros(task.num_actions))
        for term in task.observations.obs_layout.terms:
            got = obs[i, task.observations.obs_layout.slices[term.name]].numpy()
            np.testing.assert_allclose(got, expected[term.name], rtol=1e-4, atol=2e-4, err_msg=f"{name} {term.name}")
    assert np.allclose(obs[:, task.observations.obs_layout.slices["up_proj"]].numpy(), 1.0, atol=0.05)  # upright at the start


# ------------------------------------------------------------------------------------------------- reward
@pytest.mark.parametrize("name", ["Ant", "Humanoid"])
def test_reward_matches_the_ige_formula_in_numpy(request, name):
    task, ref, gen = reset_with_reference(request, name, seed=2)
    compared, at_limit = 0, False
    for step in range(8):
        before = state(task)[0]
        # large actions push joints to their limits, so the joints-at-limit term is exercised too
        actions = (torch.rand(task.num_envs, task.num_actions, generator=gen) * 2 - 1) * 1.5
        _, rew, reset, _ = task.step(actions)
        at_limit |= bool((task._reward_joints_at_limit()[reset == 0] != 0).any())
        qpos, qvel, _, _ = state(task)
        for i in range(task.num_envs):
            if reset[i]:
                continue
            expected, fallen = ref.reward(before[i], qpos[i], qvel[i], actions[i].clamp(-1, 1).numpy(),
                                          humanoid=name == "Humanoid")
            assert not fallen
            assert float(rew[i]) == pytest.approx(expected, rel=1e-4, abs=1e-5), f"{name} step {step} env {i}"
            compared += 1
    assert compared >= task.num_envs * 4
    assert at_limit  # the joints-at-limit term took part in the comparison


@pytest.mark.parametrize("name", ["Ant", "Humanoid"])
def test_a_fall_earns_the_death_cost_and_resets_to_the_start_pose(request, name):
    task = task_of(request, name)
    env = task.cfg["env"]
    task.reset()
    mask = torch.tensor([True] + [False] * (task.num_envs - 1))
    low = task.sim.root_pos.clone()
    low[:, 2] = env["terminationHeight"] - 0.2
    task.sim.write_state(mask, root_pos=low)
    obs, rew, reset, extras = task.step(torch.zeros(task.num_envs, task.num_actions))
    assert reset[0] == 1 and not reset[1:].any()
    assert float(rew[0]) == pytest.approx(env["deathCost"])
    assert extras["time_outs"][0] == 0
    # the observation of env 0 is its new episode's first state
    layout = task.observations.obs_layout
    assert float(obs["obs"][0, layout.slices["torso_height"]]) == pytest.approx(env["baseInitState"]["pos"][2])
    assert not obs["obs"][0, layout.slices["actions"]].any()
    scaled = obs["obs"][0, layout.slices["dof_pos_scaled"]]
    assert bool((scaled.abs() <= 1.0 + 1e-6).all())
    initial = (2 * task.initial_dof_pos - task.dof_upper - task.dof_lower) / (task.dof_upper - task.dof_lower)
    half_range = (task.dof_upper - task.dof_lower) / 2
    assert bool(((scaled - initial).abs() <= env["resetDofPosNoise"] / half_range + 1e-5).all())
    # the first step of the new episode measures progress from the start position, not from where it fell
    start = task.sim.root_pos[0].clone()
    task.step(torch.zeros(task.num_envs, task.num_actions))
    target = torch.tensor(env["target"])
    moved = (torch.norm((target - start)[:2]) - torch.norm((target - task.sim.root_pos[0])[:2])) / task.control_dt
    assert float(task.progress_speed[0]) == pytest.approx(float(moved), abs=1e-3)


def test_a_blown_up_world_is_reset_by_the_task_and_reports_its_episode(ant):
    """VecTask puts a world with a NaN state back in the model's initial pose; the task resets it in the same step,
    so its episode's sums are reported and cleared (before, they ran on into the next episode)."""
    task = ant
    task.reset()
    for _ in range(3):
        task.step(torch.zeros(task.num_envs, task.num_actions))
    before = task.rewards.episode_sums.clone()
    bad = 2
    task.sim.qvel[bad, 0] = float("nan")
    _, rew, reset, extras = task.step(torch.zeros(task.num_envs, task.num_actions))
    assert bool(extras["nonfinite_resets"][bad]) and int(reset[bad]) == 1 and float(rew[bad]) == 0.0
    assert not reset[torch.arange(task.num_envs) != bad].any()
    reported = torch.stack(list(extras["episode_terms"].values()))
    assert torch.allclose(reported, before[bad]) and not task.rewards.episode_sums[bad].any()
    assert int(task.progress_buf[bad]) == 0 and torch.isfinite(task.sim.qvel).all()


def test_episode_times_out_at_episode_length():
    task = make("Ant", num_envs=2, overrides=["task.env.episodeLength_s=0.0833"])  # 5 steps of 2 x 0.00833 s
    task.reset()
    for step in range(1, 5):
        _, _, reset, extras = task.step(torch.zeros(2, 8))
        assert bool(reset.all()) == (step == 4), step
    assert extras["time_outs"].all()


def test_test_mode_reports_forward_speed(ant):
    ant.reset()
    ant.metrics.evaluate()
    try:
        _, _, reset, extras = ant.step(torch.rand(ant.num_envs, 8) * 2 - 1)
        speed = ant.metrics.recorded(PER_STEP)["forward_speed"]
        live = reset == 0
        torch.testing.assert_close(speed[live], ant.sim.root_lin_vel[live, 0])
    finally:
        ant.metrics.evaluate(False)


# ------------------------------------------------------------------------------------------ MuJoCo C
@pytest.mark.parametrize("name", ["Ant", "Humanoid"])
def test_controlled_steps_match_mujoco_c(name):
    """A few env steps with fixed actions give MuJoCo C's mj_step trajectory (and foot sensor readings) on the
    task's own compiled model. The solver runs to convergence here: with the shipped 4 Newton iterations the float32
    and float64 solves stop at different points once several contacts share a foot (Humanoid: ~3 % of the force)."""
    task = make(name, overrides=["task.sim.iterations=50", "task.sim.ls_iterations=50"])
    m = task.sim.mj_model
    task.reset()
    for _ in range(8):  # land on the feet, so that contacts and the foot sensors take part
        task.step(torch.zeros(task.num_envs, task.num_actions))
    d = mujoco.MjData(m)
    world = 1
    saved = {k: v[world].numpy().astype(np.float64) for k, v in task.sim.save_state().items()}
    d.qpos[:], d.qvel[:], d.qacc_warmstart[:] = saved["qpos"], saved["qvel"], saved["qacc_warmstart"]
    gen = torch.Generator().manual_seed(3)
    contacts = 0
    for step in range(3):
        actions = torch.rand(task.num_envs, task.num_actions, generator=gen) * 2 - 1
        _, _, reset, _ = task.step(actions)
        assert not reset[world]
        d.ctrl[:] = actions[world].numpy()
        for _ in range(task.control_freq_inv):
            mujoco.mj_step(m, d)
        contacts += d.ncon
        msg = f"{name} step {step}"
        np.testing.assert_allclose(task.sim.qpos[world].numpy(), d.qpos, atol=5e-5, err_msg=msg)
        np.testing.assert_allclose(task.sim.qvel[world].numpy(), d.qvel, atol=2e-3, err_msg=msg)
        np.testing.assert_allclose(task.sim.sensordata[world].numpy(), d.sensordata, atol=0.05, rtol=1e-3,
                                   err_msg=msg)
    assert contacts > 0


# ----------------------------------------------------------------------------------------------- bad input
def write_variant(tmp_path, name: str, edit) -> str:
    text = (ASSETS / f"{name.lower()}.xml").read_text()
    (tmp_path / "robot.xml").write_text(edit(text))
    return f"task.env.asset.assetRoot={tmp_path}"


def test_mjcf_without_actuators_fails_naming_the_fix(tmp_path):
    root = write_variant(tmp_path, "Ant", lambda t: re.sub(r"<actuator>.*</actuator>", "", t, flags=re.S))
    with pytest.raises(ValueError, match=r"numActions=8 but the model has no actuators"):
        make("Ant", overrides=[root, "task.env.asset.assetFileName=robot.xml"])


def test_actuator_count_must_equal_num_actions():
    with pytest.raises(ValueError, match=r"env.numActions=7 but the model has 8 actuators.*set task.env.numActions: 8"):
        make("Ant", overrides=["task.env.numActions=7"])


def test_a_joint_without_a_motor_fails_naming_it(tmp_path):
    root = write_variant(tmp_path, "Ant", lambda t: t.replace('<motor name="ankle_4" joint="ankle_4"/>', ""))
    with pytest.raises(ValueError, match=r"joints without one: \['ankle_4'\]"):
        make("Ant", overrides=[root, "task.env.asset.assetFileName=robot.xml", "task.env.numActions=7"])


def test_gear_override_on_an_unknown_joint_fails_naming_the_key():
    with pytest.raises(ValueError, match=r"env.control.gear: 'knee_9' matches no actuator"):
        make("Ant", overrides=["+task.env.control.gear={knee_9: 30.0}"])


def test_gear_override_changes_the_motor_and_the_effort_weights():
    task = make("Humanoid", num_envs=2, overrides=["+task.env.control.gear={right_knee: 180.0}"])
    gears = dict(zip(task.sim.actuator_names, task.sim.mj_model.actuator_gear[:, 0]))
    assert gears["right_knee"] == 180.0 and gears["left_knee"] == 90.0
    ratio = dict(zip(task.sim.actuator_names, task.motor_effort_ratio.tolist()))
    assert ratio["right_knee"] == 1.0 and ratio["right_hip_y"] == pytest.approx(135.0 / 180.0)


def test_unknown_foot_sensor_fails_listing_the_sensors():
    with pytest.raises(ValueError, match=r"env.footContactSensors: 'paw' is not a sensor.*front_left_foot_contact"):
        make("Ant", overrides=["task.env.footContactSensors=[paw]"])


def test_missing_reward_key_fails_naming_it():
    with pytest.raises(ValueError, match=r"lacks \['deathCost'\]"):
        make("Ant", overrides=["~task.env.deathCost"])


def test_fixed_base_is_refused():
    with pytest.raises(ValueError, match=r"free joint.*fixBaseLink is True"):
        make("Ant", overrides=["task.env.asset.fixBaseLink=True"])
