"""Legged locomotion tasks (Anymal, Go1): build and step, standing under PD, model facts against the URDF and
robots.md, training artefacts, reward bookkeeping and formulas, domain randomisation, observation layout,
bad input and time-outs.

Every expected value comes from outside the package: the URDF parsed here with xml.etree, numbers typed from
/work/shared/reference/robots.md or the task YAML (source named next to each), numpy rotation math written
here, or MuJoCo C on the task's compiled host model. Tasks are shared per robot through module-scoped fixtures;
each test that needs a particular state writes it itself, so test order does not matter.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

import isaacgymenvs_mw
from conftest import REPO_ROOT
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.tasks import get_task_class
from isaacgymenvs_mw.utils.config import compose_config

N = 4
ROBOTS = ["Anymal", "Go1"]
CONTROL_DT = 0.005 * 4  # task YAML: sim.dt 0.005, env.controlFrequencyInv 4 (both robots)
POLICY_OBS, NUM_STATES = 48, 55  # derived observation and critic-state sizes (both robots)

# No pushes, ground friction fixed at 1.0 and no observation noise: the robot's state is what the test wrote.
QUIET = [
    "~task.task.randomization_params.push",
    "task.task.randomization_params.actor_params.rigid_shape_properties.friction.range=[1.0,1.0]",
    "~task.task.randomization_params.observations",
    "task.env.rewards.penaltyCurriculum=null",  # full penalty scales from the first step (Anymal ramps them in)
]

# Facts typed from their sources (named per entry).
FACTS = {
    "Anymal": {
        "urdf": "assets/urdf/anymal_c/anymal_c.urdf",
        "base": "base",  # cfg/task/Anymal.yaml env.asset.baseBody
        "feet": ["LF_FOOT", "RF_FOOT", "LH_FOOT", "RH_FOOT"],  # cfg/task/Anymal.yaml footBodies '.*_FOOT'
        "base_init_pos": (0.0, 0.0, 0.6),  # cfg/task/Anymal.yaml baseInitState.pos
        # robots.md A6 / A2.3: ANY-D (ANYbotics anymal_c_simple_description URDF) DERIVED total 52.13485 kg.
        "total_mass_robots_md": 52.13485,
        # robots.md A1.4, ANY-D anymal.urdf: HAA -0.72..0.49 (left) / -0.49..0.72 (right); HFE, KFE
        # +-9.42477796077; effort 80 N m on every joint.
        "limits_robots_md": {
            "LF_HAA": (-0.72, 0.49, 80.0), "RF_HAA": (-0.49, 0.72, 80.0),
            "LH_HAA": (-0.72, 0.49, 80.0), "RH_HAA": (-0.49, 0.72, 80.0),
            **{f"{leg}_{j}": (-9.42477796077, 9.42477796077, 80.0)
               for leg in ("LF", "RF", "LH", "RH") for j in ("HFE", "KFE")},
        },
        # cfg/task/Anymal.yaml defaultJointAngles, written out per joint.
        "default_angles": {
            "LF_HAA": 0.0, "RF_HAA": 0.0, "LH_HAA": 0.0, "RH_HAA": 0.0,
            "LF_HFE": 0.4, "RF_HFE": 0.4, "LH_HFE": -0.4, "RH_HFE": -0.4,
            "LF_KFE": -0.8, "RF_KFE": -0.8, "LH_KFE": 0.8, "RH_KFE": 0.8,
        },
        # robots.md A4, row "LG AnymalCRoughCfg.init_state" (the same pose as the YAML defaults): DERIVED base z
        # with all four foot spheres (r 0.03) touching the ground, 0.54882 m, per foot.
        "contact_height_robots_md": {"LF_FOOT": 0.54882, "RF_FOOT": 0.54882, "LH_FOOT": 0.54882,
                                     "RH_FOOT": 0.54882},
        "foot_radius_robots_md": 0.03,
        "pd": {"kp": 80.0, "kd": 2.0, "action_scale": 0.5},  # cfg/task/Anymal.yaml env.control
        "added_mass_range": (-5.0, 5.0),  # cfg/task/Anymal.yaml task.randomization_params...mass.range
    },
    "Go1": {
        "urdf": "assets/urdf/go1/go1.urdf",
        "base": "trunk",  # cfg/task/Go1.yaml env.asset.baseBody
        "feet": ["FR_foot", "FL_foot", "RR_foot", "RL_foot"],  # cfg/task/Go1.yaml footBodies '.*_foot'
        "base_init_pos": (0.0, 0.0, 0.34),  # cfg/task/Go1.yaml baseInitState.pos
        # robots.md B6 / B2.2: MEN-G (mujoco_menagerie unitree_go1) total 12.743448 kg; the URDF's header says
        # it uses the MEN-G masses (the unitree_ros URDF would be 13.100528 kg).
        "total_mass_robots_md": 12.743448,
        # robots.md B1.2/B1.3, UR go1.urdf: hip -0.863..0.863, thigh -0.686..4.501, calf -2.818..-0.888;
        # effort 23.7 / 23.7 / 35.55 N m.
        "limits_robots_md": {
            **{f"{leg}_hip_joint": (-0.863, 0.863, 23.7) for leg in ("FR", "FL", "RR", "RL")},
            **{f"{leg}_thigh_joint": (-0.686, 4.501, 23.7) for leg in ("FR", "FL", "RR", "RL")},
            **{f"{leg}_calf_joint": (-2.818, -0.888, 35.55) for leg in ("FR", "FL", "RR", "RL")},
        },
        # cfg/task/Go1.yaml defaultJointAngles, written out per joint (L hips +0.1, R hips -0.1, front thighs 0.8,
        # rear thighs 1.0, calves -1.5; this is walk-these-ways' pose, robots.md B4 "WTW").
        "default_angles": {
            "FR_hip_joint": -0.1, "FL_hip_joint": 0.1, "RR_hip_joint": -0.1, "RL_hip_joint": 0.1,
            "FR_thigh_joint": 0.8, "FL_thigh_joint": 0.8, "RR_thigh_joint": 1.0, "RL_thigh_joint": 1.0,
            "FR_calf_joint": -1.5, "FL_calf_joint": -1.5, "RR_calf_joint": -1.5, "RL_calf_joint": -1.5,
        },
        # robots.md B4, row "WTW go1_config.py": DERIVED base z with the feet touching, front 0.32177 / rear
        # 0.31251, computed there with the UR foot radius 0.02.
        "contact_height_robots_md": {"FR_foot": 0.32177, "FL_foot": 0.32177, "RR_foot": 0.31251,
                                     "RL_foot": 0.31251},
        "foot_radius_robots_md": 0.02,
        "pd": {"kp": 20.0, "kd": 0.5, "action_scale": 0.25},  # cfg/task/Go1.yaml env.control
        "added_mass_range": (-1.0, 1.0),  # cfg/task/Go1.yaml task.randomization_params...mass.range
    },
}


# ------------------------------------------------------------------------------------------------ helpers
def make_legged(robot: str, overrides=()):
    return isaacgymenvs_mw.make(robot, num_envs=N, sim_device="cpu", rl_device="cpu", headless=True, seed=0,
                                overrides=list(overrides))


def parse_urdf(robot: str) -> dict:
    """Link masses, movable-joint limits and foot-sphere radii, read from the URDF file with xml.etree."""
    root = ET.parse(REPO_ROOT / FACTS[robot]["urdf"]).getroot()
    masses, radii = {}, {}
    for link in root.findall("link"):
        mass = link.find("inertial/mass")
        # A link without <inertial> would get a mass inferred from its geoms by MuJoCo; our URDFs give all.
        assert mass is not None, f"link {link.get('name')} has no inertial"
        masses[link.get("name")] = float(mass.get("value"))
        sphere = link.find("collision/geometry/sphere")
        if sphere is not None:
            radii[link.get("name")] = float(sphere.get("radius"))
    joints = {}
    for joint in root.findall("joint"):
        if joint.get("type") in ("revolute", "prismatic", "continuous"):
            lim = joint.find("limit")
            joints[joint.get("name")] = (float(lim.get("lower")), float(lim.get("upper")), float(lim.get("effort")))
    return {"masses": masses, "joints": joints, "radii": radii}


def yaml_cfg(robot: str, overrides=()):
    return compose_config([f"task={robot}", *overrides]).task


def all_envs() -> torch.Tensor:
    return torch.ones(N, dtype=torch.bool)


def reset_to_default_pose(task) -> None:
    """Reset every env to exactly the default joint pose at the init height, at rest."""
    task.reset_dof_pos_scale = (1.0, 1.0)
    task.reset_root_vel_range = 0.0
    task.reset_envs(all_envs())


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (w, x, y, z) quaternions, batched over rows."""
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.stack((aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw), axis=1)


def axis_quat(axis: int, angle: np.ndarray) -> np.ndarray:
    q = np.zeros((len(angle), 4))
    q[:, 0] = np.cos(angle / 2)
    q[:, 1 + axis] = np.sin(angle / 2)
    return q


def rot_matrices(yaw, pitch, roll) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), body -> world, written with matrices (independent of the quaternions)."""
    out = []
    for y, p, r in zip(yaw, pitch, roll):
        rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
        ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
        rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
        out.append(rz @ ry @ rx)
    return np.stack(out)


# A known root state per env: env 0 a pure yaw, the others yaw + pitch + roll.
YAW = np.array([0.7, -1.2, 2.5, -2.9])
PITCH = np.array([0.0, 0.2, -0.15, 0.1])
ROLL = np.array([0.0, -0.1, 0.25, 0.3])
V_WORLD = np.array([[0.8, -0.3, 0.05], [-0.5, 0.6, -0.1], [0.2, 0.9, 0.0], [-1.1, -0.4, 0.2]])
W_BODY = np.array([[0.1, -0.2, 0.9], [0.4, 0.0, -0.6], [-0.3, 0.5, 0.2], [0.0, 0.1, -1.0]])


def write_known_root_state(task, robot: str):
    """Write YAW/PITCH/ROLL, V_WORLD (world frame) and W_BODY (body frame, MuJoCo free-joint qvel[3:6]).

    Returns the rotation matrices (body -> world) computed independently of the quaternions written.
    """
    q = quat_mul(quat_mul(axis_quat(2, YAW), axis_quat(1, PITCH)), axis_quat(0, ROLL))
    root_pos = torch.tensor([FACTS[robot]["base_init_pos"]] * N, dtype=torch.float32)
    task.sim.write_state(all_envs(), root_pos=root_pos, root_quat=torch.tensor(q, dtype=torch.float32),
                         root_lin_vel=torch.tensor(V_WORLD, dtype=torch.float32),
                         root_ang_vel=torch.tensor(W_BODY, dtype=torch.float32))
    task.refresh_state()
    return rot_matrices(YAW, PITCH, ROLL)


# ------------------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module", params=ROBOTS)
def robot(request) -> str:
    return request.param


@pytest.fixture(scope="module")
def default_task(robot):
    """The task as its YAML defines it (randomisation, pushes and noise on)."""
    return make_legged(robot)


@pytest.fixture(scope="module")
def quiet_task(robot):
    return make_legged(robot, QUIET)


@pytest.fixture(scope="module")
def urdf(robot) -> dict:
    return parse_urdf(robot)


# ------------------------------------------------------------------------------------ 1. build and step
def test_builds_and_steps_with_contract_shapes(default_task, robot):
    task = default_task
    cfg = yaml_cfg(robot)
    assert "numObservations" not in cfg.env and "numStates" not in cfg.env  # derived from the terms
    assert task.num_obs == POLICY_OBS and task.num_states == NUM_STATES
    assert type(task) is get_task_class(robot)
    assert task.num_envs == N and task.num_actions == 12
    obs_dict = task.reset()
    assert obs_dict["obs"].shape == (N, POLICY_OBS) and obs_dict["states"].shape == (N, NUM_STATES)
    gen = torch.Generator().manual_seed(1)
    for _ in range(5):
        actions = 2.0 * torch.rand(N, 12, generator=gen) - 1.0
        obs_dict, rew, reset, extras = task.step(actions)
        assert obs_dict["obs"].shape == (N, POLICY_OBS) and obs_dict["obs"].dtype == torch.float32
        assert obs_dict["states"].shape == (N, NUM_STATES)
        assert rew.shape == (N,) and reset.shape == (N,) and extras["time_outs"].shape == (N,)
        assert torch.isfinite(obs_dict["obs"]).all() and torch.isfinite(obs_dict["states"]).all()
        assert torch.isfinite(rew).all()
        assert (rew >= 0).all()  # YAML rewards.onlyPositiveRewards: True
        # the actions reached the PD targets: target = default + actionScale * action (YAML env.control)
        default = torch.tensor([FACTS[robot]["default_angles"][j] for j in task.sim.dof_names])
        np.testing.assert_allclose(task.sim.ctrl.numpy(),
                                   (default + FACTS[robot]["pd"]["action_scale"] * actions).numpy(), atol=1e-6)


def test_without_privileged_states_the_obs_dict_has_no_states(robot):
    task = make_legged(robot, ["+task.env.numStates=0"])
    obs_dict, rew, _, _ = task.step(task.zero_actions())
    assert set(obs_dict) == {"obs"} and obs_dict["obs"].shape == (N, POLICY_OBS)
    assert torch.isfinite(rew).all()


# ---------------------------------------------------------------------------- 2. standing under PD
def test_stands_for_two_seconds_at_the_default_pose(quiet_task, robot, urdf):
    task, facts = quiet_task, FACTS[robot]
    reset_to_default_pose(task)
    names = task.sim.dof_names
    np.testing.assert_allclose(task.sim.dof_pos.numpy(), [[facts["default_angles"][j] for j in names]] * N,
                               atol=1e-7)
    np.testing.assert_allclose(task.sim.root_pos.numpy(), [facts["base_init_pos"]] * N, atol=1e-7)
    assert torch.count_nonzero(task.sim.qvel) == 0

    nominal = min(facts["contact_height_robots_md"].values())
    base_forces, heights = [], []
    steps = round(2.0 / CONTROL_DT)
    assert steps == 100
    for k in range(1, steps + 1):
        obs_dict, rew, reset, extras = task.step(task.zero_actions())
        assert not reset.any() and not extras["time_outs"].any(), f"an env was reset at step {k}"
        assert not task.terminated.any()
        assert torch.equal(task.progress_buf, torch.full((N,), k))
        heights.append(task.sim.root_pos[:, 2].clone())
        base_forces.append(torch.norm(task.sim.sensor(f"contact_{facts['base']}"), dim=-1).max())
    heights = torch.stack(heights)
    assert heights.min() > 0.6 * nominal, (heights.min(), nominal)
    assert heights.max() < facts["base_init_pos"][2] + 0.01  # dropped onto its feet, did not bounce up
    assert max(base_forces) < 1e-3  # the base never touched the ground
    assert (task.projected_gravity[:, 2] < -0.99).all()  # upright

    # Standing still, the feet carry the whole weight: sum of foot normal forces = (URDF mass + added mass) * g.
    urdf_total = sum(urdf["masses"].values())
    base_id = mujoco.mj_name2id(task.sim.mj_model, mujoco.mjtObj.mjOBJ_BODY, facts["base"])
    added = task.sim.model_field("body_mass")[:, base_id].numpy() - urdf["masses"][facts["base"]]
    foot_fz = torch.stack([task.sim.sensor(f"contact_{f}") for f in facts["feet"]], 1)[..., 2].sum(dim=1).abs().numpy()
    np.testing.assert_allclose(foot_fz, (urdf_total + added) * 9.81, rtol=0.02)

    # Privileged states: friction, added mass, base height, four foot contacts.
    states = obs_dict["states"].numpy()
    np.testing.assert_allclose(states[:, 48], 1.0)  # QUIET fixes the friction range at [1, 1]
    np.testing.assert_allclose(states[:, 49], added, atol=1e-5)
    np.testing.assert_allclose(states[:, 50], task.sim.root_pos[:, 2].numpy(), atol=1e-6)
    np.testing.assert_array_equal(states[:, 51:55], 1.0)


# ------------------------------------------------------------------ 3. mass and joint limits (URDF facts)
def test_total_and_link_masses_match_the_urdf_and_robots_md(default_task, robot, urdf):
    model = default_task.sim.mj_model
    facts = FACTS[robot]
    urdf_total = sum(urdf["masses"].values())
    base_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, facts["base"])
    assert base_id == 1 and model.body_parentid[base_id] == 0  # the root link hangs off the world
    assert model.body_subtreemass[base_id] == pytest.approx(urdf_total, rel=1e-9)
    for link, mass in urdf["masses"].items():
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, link)
        assert bid >= 0, link
        assert model.body_mass[bid] == pytest.approx(mass, rel=1e-9, abs=1e-12), link
    # robots.md states the totals the URDFs were written from (ANY-D for ANYmal, MEN-G for Go1).
    assert urdf_total == pytest.approx(facts["total_mass_robots_md"], abs=1e-5)
    assert model.body_subtreemass[base_id] == pytest.approx(facts["total_mass_robots_md"], abs=1e-5)


def test_joint_limits_and_effort_match_the_urdf_and_robots_md(default_task, robot, urdf):
    task, facts = default_task, FACTS[robot]
    model = task.sim.mj_model
    assert sorted(urdf["joints"]) == sorted(task.sim.dof_names) == sorted(facts["limits_robots_md"])
    for name, (lower, upper, effort) in urdf["joints"].items():
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        assert model.jnt_limited[jid] and model.jnt_actfrclimited[jid], name
        np.testing.assert_allclose(model.jnt_range[jid], (lower, upper), rtol=1e-12, err_msg=name)
        np.testing.assert_allclose(model.jnt_actfrcrange[jid], (-effort, effort), rtol=1e-12, err_msg=name)
        md_lower, md_upper, md_effort = facts["limits_robots_md"][name]
        np.testing.assert_allclose(model.jnt_range[jid], (md_lower, md_upper), atol=1e-9, err_msg=name)
        assert model.jnt_actfrcrange[jid][1] == pytest.approx(md_effort), name
    # The PD drives are YAML gains (kp, kd) on MuJoCo position actuators, one per joint.
    assert model.nu == 12
    np.testing.assert_allclose(model.actuator_gainprm[:, 0], facts["pd"]["kp"])
    np.testing.assert_allclose(model.actuator_biasprm[:, 1], -facts["pd"]["kp"])
    np.testing.assert_allclose(model.actuator_biasprm[:, 2], -facts["pd"]["kd"])


def test_effort_limit_clamps_the_pd_torque(quiet_task, robot, urdf):
    """A target far off the current angle asks for kp * 25+ rad: the joint torque is the URDF effort limit."""
    task = quiet_task
    reset_to_default_pose(task)
    task.step(torch.full((N, 12), task.clip_actions))
    effort = np.array([urdf["joints"][j][2] for j in task.sim.dof_names])
    np.testing.assert_allclose(task.sim.qfrc_actuator[:, 6:].numpy(), np.tile(effort, (N, 1)), rtol=1e-5)
    task.step(torch.full((N, 12), -task.clip_actions))
    np.testing.assert_allclose(task.sim.qfrc_actuator[:, 6:].numpy(), -np.tile(effort, (N, 1)), rtol=1e-5)


def test_random_resets_start_inside_the_joint_limits(quiet_task, robot, urdf):
    """Reset joint angles (default * U(resetDofPosScale)) must respect the URDF range of every joint.

    Package bug (Go1): the calf default -1.5 times a scale below 0.592 gives an angle above the calf's upper
    limit -0.888 (robots.md B1.2), so about 10% of calf draws start inside a joint-limit violation.
    """
    task = quiet_task
    task.reset_dof_pos_scale = tuple(yaml_cfg(robot).env.resetDofPosScale)
    assert task.reset_dof_pos_scale == (0.5, 1.5)  # cfg/legged/base.yaml
    lower = np.array([urdf["joints"][j][0] for j in task.sim.dof_names])
    upper = np.array([urdf["joints"][j][1] for j in task.sim.dof_names])
    outside = set()
    for _ in range(20):
        task.reset_envs(all_envs())
        q = task.sim.dof_pos.numpy()
        bad = (q < lower - 1e-6) | (q > upper + 1e-6)
        outside |= {task.sim.dof_names[j] for j in np.flatnonzero(bad.any(axis=0))}
    assert not outside, f"reset angles outside the joint range on {sorted(outside)}"


def test_default_pose_contact_height_matches_robots_md(default_task, robot, urdf):
    """MuJoCo C kinematics of the compiled model at the default pose against robots.md's derived heights."""
    model, facts = default_task.sim.mj_model, FACTS[robot]
    data = mujoco.MjData(model)
    data.qpos[:] = 0.0
    data.qpos[3] = 1.0  # base at the origin, level
    for joint, angle in facts["default_angles"].items():
        data.qpos[model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint)]] = angle
    mujoco.mj_kinematics(model, data)
    for foot, height_md in facts["contact_height_robots_md"].items():
        radius = urdf["radii"][foot]  # the foot link origin is the foot-sphere centre
        centre_z = data.xpos[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, foot)][2]
        # robots.md computed the height with its own foot radius; swap in the URDF's
        expected = height_md - facts["foot_radius_robots_md"] + radius
        assert -centre_z + radius == pytest.approx(expected, abs=2e-4), foot


# ---------------------------------------------------------------------------- 4. one training iteration
def test_one_training_iteration_writes_summary_and_checkpoint(robot, run_args, tmp_path):
    cfg = compose_config([f"task={robot}", f"num_envs={N}", "max_iterations=1", *run_args])
    steps_per_env = 24  # cfg/train/{Anymal,Go1}PPO.yaml runner.num_steps_per_env
    assert cfg.train.runner.num_steps_per_env == steps_per_env
    summary = run(cfg)
    dirs = [p for p in (tmp_path / "runs" / robot).iterdir() if p.is_dir()]
    assert len(dirs) == 1
    run_dir = dirs[0]
    on_disk = json.loads((run_dir / "summary.json").read_text())
    assert on_disk["task"] == robot and on_disk["num_envs"] == N and on_disk["iterations"] == 1
    assert on_disk["env_steps"] == steps_per_env * N
    assert on_disk["wall_time_s"] > 0 and on_disk["device"].startswith("cpu")
    assert Path(summary["run_dir"]) == run_dir and len(on_disk["history"]) == 1
    ckpt = run_dir / "model_1.pt"
    assert ckpt.is_file()
    state = torch.load(ckpt, map_location="cpu", weights_only=False)
    assert state["iter"] == 1
    actor_w = [v for k, v in state["actor_state_dict"].items() if k.startswith("mlp.") and k.endswith(".weight")]
    critic_w = [v for k, v in state["critic_state_dict"].items() if k.startswith("mlp.") and k.endswith(".weight")]
    assert actor_w[0].shape == (128, POLICY_OBS) and actor_w[-1].shape[0] == 12
    assert critic_w[0].shape == (128, NUM_STATES) and critic_w[-1].shape[0] == 1


# ----------------------------------------------------------------- 5. zero-scale terms are not computed
def test_zero_scale_term_is_not_computed_and_episode_sums_are_logged(robot, monkeypatch):
    cls = get_task_class(robot)
    scales = dict(yaml_cfg(robot).env.rewards.scales)
    assert scales["torques"] != 0.0  # the override below is what turns it off
    scales["torques"] = 0.0
    nonzero = [name for name, s in scales.items() if s != 0.0]
    calls: dict[str, list[torch.Tensor]] = defaultdict(list)

    def spy(name):
        original = getattr(cls, f"_reward_{name}")

        def wrapped(self):
            value = original(self)
            calls[name].append(value.clone())
            return value

        monkeypatch.setattr(cls, f"_reward_{name}", wrapped)

    for name in scales:
        spy(name)
    task = make_legged(robot, [*QUIET, "task.env.rewards.scales.torques=0.0"])
    reset_to_default_pose(task)
    steps = 3
    for _ in range(steps):
        _, _, reset, extras = task.step(task.zero_actions())
        assert not reset.any()
    assert "torques" not in calls
    assert {name for name in calls} == set(nonzero)  # every zero-scale term skipped, every other one computed
    assert all(len(calls[name]) == steps for name in nonzero)
    # Each term's episode sum is logged under its name: sum over steps of scale * dt * term, summed over envs.
    assert list(extras["episode_terms"]) == nonzero
    task.reset_envs(all_envs())
    logged = task.extras["episode_terms"]
    assert list(logged) == nonzero
    for name in nonzero:
        expected = sum(float(v.sum()) for v in calls[name]) * scales[name] * CONTROL_DT
        assert float(logged[name]) == pytest.approx(expected, rel=1e-5, abs=1e-9), name


def test_a_blown_up_world_earns_nothing_and_leaves_the_episode_sums_finite():
    """feet_slip reads the feet's velocities, which the physics derives from the state: in a world reset for NaN
    they stay NaN until the next physics step. One NaN in the episode sums used to stay there for the whole run
    (a G1 run on the GPU logged NaN for feet_slip from its first blow-up on)."""
    task = make_legged("Go1", [*QUIET, "+task.env.rewards.scales.feet_slip=-0.1"])
    reset_to_default_pose(task)
    for _ in range(3):
        task.step(task.zero_actions())
    bad = 1
    before = task.rewards.episode_sums.clone()
    task.sim.qvel[bad, 0] = float("nan")
    _, rew, reset, extras = task.step(task.zero_actions())
    assert bool(extras["nonfinite_resets"][bad]) and int(reset[bad]) == 1 and float(rew[bad]) == 0.0
    assert torch.isnan(task.sim.body_lin_vel(task._feet_body_ids)[bad]).any()  # what the term reads
    assert torch.isfinite(task.rewards.episode_sums).all()
    # The task reset the world in the same step: its episode's sums, without the blown-up step, are reported.
    assert not reset[torch.arange(task.num_envs) != bad].any()
    reported = torch.stack(list(extras["episode_terms"].values()))
    assert torch.equal(reported, before[bad]) and not task.rewards.episode_sums[bad].any()
    task.reset_envs(all_envs())
    assert all(torch.isfinite(v) for v in task.extras["episode_terms"].values())
    assert not task.rewards.episode_sums.any()


# --------------------------------------------------------------------------------- 6. randomisation
def test_friction_and_mass_are_randomised_per_env_within_yaml_ranges(default_task, robot, urdf):
    task, facts = default_task, FACTS[robot]
    rand = yaml_cfg(robot).task.randomization_params.actor_params
    model = task.sim.mj_model
    ground = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "ground")
    base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, facts["base"])

    geom_friction = task.sim.model_field("geom_friction").numpy()
    assert geom_friction.shape == (N, model.ngeom, 3)
    friction = geom_friction[:, ground, 0]
    lo, hi = rand.rigid_shape_properties.friction.range  # x the plane's friction, 1.0
    assert (lo, hi) == (0.5, 1.25)  # cfg/legged/base.yaml
    assert np.all((friction >= lo) & (friction <= hi)), friction
    assert len(np.unique(friction)) > 1, friction
    # only the ground's sliding friction is per env; everything else keeps the compiled value
    others = np.ones(model.ngeom, dtype=bool)
    others[ground] = False
    np.testing.assert_array_equal(geom_friction[:, others], np.broadcast_to(model.geom_friction[others],
                                                                             (N, others.sum(), 3)).astype(np.float32))
    np.testing.assert_allclose(geom_friction[:, ground, 1:], np.tile(model.geom_friction[ground, 1:], (N, 1)))

    body_mass = task.sim.model_field("body_mass").numpy()
    assert body_mass.shape == (N, model.nbody)
    added = body_mass[:, base] - urdf["masses"][facts["base"]]
    lo, hi = rand.rigid_body_properties.mass.range
    assert (lo, hi) == facts["added_mass_range"]
    assert np.all((added >= lo - 1e-5) & (added <= hi + 1e-5)), added
    assert len(np.unique(added)) > 1, added
    rest = np.arange(model.nbody) != base
    np.testing.assert_allclose(body_mass[:, rest], np.tile(model.body_mass[rest], (N, 1)), rtol=1e-6)

    # The privileged critic sees each env's own values.
    states = task.reset()["states"].numpy()
    np.testing.assert_allclose(states[:, 48], friction, rtol=1e-6)
    np.testing.assert_allclose(states[:, 49], added, atol=1e-5)


# ------------------------------------------------------------------------------------------ 7. bad input
def test_unknown_reward_scale_fails_with_the_list_of_terms(robot):
    terms = list(yaml_cfg(robot).env.rewards.scales)  # the YAML lists every term the task has
    with pytest.raises(ValueError) as err:
        make_legged(robot, ["+task.env.rewards.scales.no_such_term=1.0"])
    msg = str(err.value)
    assert "rewards.scales" in msg and "no_such_term" in msg
    for term in terms:
        assert f"'{term}'" in msg, (term, msg)


@pytest.mark.parametrize("override,key", [
    ("+task.env.defaultJointAngles.NOPE_joint=0.1", "env.defaultJointAngles"),
    ("+task.env.control.stiffness.NOPE=10", "env.control.stiffness"),
    ("+task.env.control.damping.NOPE=1", "env.control.damping"),
])
def test_unknown_joint_name_fails_with_the_list_of_joints(robot, urdf, override, key):
    with pytest.raises(ValueError) as err:
        make_legged(robot, [override])
    msg = str(err.value)
    assert key in msg and "NOPE" in msg
    for joint in urdf["joints"]:
        assert f"'{joint}'" in msg, (joint, msg)


# ----------------------------------------------------------------------------------- 8. reward formulas
def test_reward_terms_match_independent_formulas(quiet_task, robot):
    task = quiet_task
    sigma = 0.25  # cfg/legged/base.yaml rewards.trackingSigma
    rot = write_known_root_state(task, robot)
    v_body = np.einsum("nji,nj->ni", rot, V_WORLD)  # R^T v
    g_body = np.einsum("nji,j->ni", rot, np.array([0.0, 0.0, -1.0]))
    commands = np.array([[0.8, -0.3, 0.2], [0.0, 0.0, 0.0], [1.0, 0.5, -0.9], [-0.6, 0.7, 1.0]])
    task.commands[:] = torch.tensor(commands, dtype=torch.float32)

    lin = np.exp(-np.sum((commands[:, :2] - v_body[:, :2]) ** 2, axis=1) / sigma)
    np.testing.assert_allclose(task._reward_tracking_lin_vel().numpy(), lin, rtol=1e-5, atol=1e-6)
    ang = np.exp(-(commands[:, 2] - W_BODY[:, 2]) ** 2 / sigma)
    np.testing.assert_allclose(task._reward_tracking_ang_vel().numpy(), ang, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(task._reward_lin_vel_z().numpy(), v_body[:, 2] ** 2, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(task._reward_ang_vel_xy().numpy(), np.sum(W_BODY[:, :2] ** 2, axis=1), rtol=1e-5)
    np.testing.assert_allclose(task._reward_orientation().numpy(), np.sum(g_body[:, :2] ** 2, axis=1),
                               rtol=1e-5, atol=1e-7)
    assert task._reward_orientation()[0].item() == pytest.approx(0.0, abs=1e-7)  # a pure yaw is level

    gen = torch.Generator().manual_seed(3)
    actions, last = torch.randn(N, 12, generator=gen), torch.randn(N, 12, generator=gen)
    task.actions[:] = actions
    task.last_actions[:] = last
    np.testing.assert_allclose(task._reward_action_rate().numpy(),
                               np.sum((actions.numpy() - last.numpy()) ** 2, axis=1), rtol=1e-5)


def test_reward_is_dt_weighted_sum_clamped_at_zero(robot):
    keep = {"tracking_lin_vel": 1.5, "orientation": -5.0, "action_rate": -0.2}
    scales = yaml_cfg(robot).env.rewards.scales
    overrides = [f"task.env.rewards.scales.{k}={keep.get(k, 0.0)}" for k in scales]
    task = make_legged(robot, [*QUIET, *overrides])
    assert task.rewards.only_positive  # YAML rewards.onlyPositiveRewards: True
    rot = write_known_root_state(task, robot)
    v_body = np.einsum("nji,nj->ni", rot, V_WORLD)
    g_body = np.einsum("nji,j->ni", rot, np.array([0.0, 0.0, -1.0]))
    commands = np.array([[0.8, -0.3, 0.0], [-0.5, 0.6, 0.0], [3.0, -3.0, 0.0], [-1.1, -0.4, 0.0]])
    task.commands[:] = torch.tensor(commands, dtype=torch.float32)
    actions = torch.zeros(N, 12)
    actions[3] = 2.0  # env 3: a large action change drives the total below zero
    task.actions[:] = actions
    task.last_actions.zero_()
    task.compute_reward()
    terms = {
        "tracking_lin_vel": np.exp(-np.sum((commands[:, :2] - v_body[:, :2]) ** 2, axis=1) / 0.25),
        "orientation": np.sum(g_body[:, :2] ** 2, axis=1),
        "action_rate": np.sum(actions.numpy() ** 2, axis=1),
    }
    total = sum(keep[k] * CONTROL_DT * terms[k] for k in keep)
    assert total[3] < 0 < total[0]
    np.testing.assert_allclose(task.rew_buf.numpy(), np.maximum(total, 0.0), rtol=1e-5, atol=1e-7)


def test_termination_penalty_is_added_after_the_clamp_at_zero(robot):
    # legged_gym's order: clamp the other terms' sum at 0, then add the termination term, so a fall costs
    # something even on a step whose penalties already outweigh the tracking reward.
    keep = {"tracking_lin_vel": 1.5, "action_rate": -0.2, "termination": -50.0}
    scales = yaml_cfg(robot).env.rewards.scales
    overrides = [f"task.env.rewards.scales.{k}={keep.get(k, 0.0)}" for k in scales]
    task = make_legged(robot, [*QUIET, *overrides])
    rot = write_known_root_state(task, robot)
    v_body = np.einsum("nji,nj->ni", rot, V_WORLD)
    commands = np.array([[0.8, -0.3, 0.0], [-0.5, 0.6, 0.0], [3.0, -3.0, 0.0], [-1.1, -0.4, 0.0]])
    task.commands[:] = torch.tensor(commands, dtype=torch.float32)
    actions = torch.zeros(N, 12)
    actions[2:] = 2.0  # envs 2 and 3: the action change drives the clamped sum below zero
    task.actions[:] = actions
    task.last_actions.zero_()
    task.terminate_buf[:] = torch.tensor([True, False, True, False])
    task.timeout_buf.zero_()
    task.compute_reward()
    tracking = np.exp(-np.sum((commands[:, :2] - v_body[:, :2]) ** 2, axis=1) / 0.25)
    others = CONTROL_DT * (1.5 * tracking - 0.2 * np.sum(actions.numpy() ** 2, axis=1))
    assert others[2] < 0 and others[3] < 0 < others[0]
    fell = np.array([1.0, 0.0, 1.0, 0.0])
    np.testing.assert_allclose(task.rew_buf.numpy(), np.maximum(others, 0.0) - 50.0 * CONTROL_DT * fell,
                               rtol=1e-5, atol=1e-7)


def test_penalty_curriculum_scales_penalties_linearly_over_env_steps(robot):
    # env.rewards.penaltyCurriculum {start, steps}: negative-scale terms (termination aside) are multiplied by
    # start + (1 - start) * min(1, env steps / steps); positive terms and termination keep their scale.
    keep = {"tracking_lin_vel": 1.5, "action_rate": -0.2, "termination": -50.0}
    scales = yaml_cfg(robot).env.rewards.scales
    overrides = [f"task.env.rewards.scales.{k}={keep.get(k, 0.0)}" for k in scales]
    curriculum = ["task.env.rewards.penaltyCurriculum={start:0.25,steps:100}"]
    task = make_legged(robot, [*QUIET, *overrides, *curriculum, "task.env.rewards.onlyPositiveRewards=False"])
    rot = write_known_root_state(task, robot)
    v_body = np.einsum("nji,nj->ni", rot, V_WORLD)
    commands = np.array([[0.8, -0.3, 0.0], [-0.5, 0.6, 0.0], [3.0, -3.0, 0.0], [-1.1, -0.4, 0.0]])
    task.commands[:] = torch.tensor(commands, dtype=torch.float32)
    actions = torch.full((N, 12), 0.5)
    task.actions[:] = actions
    task.last_actions.zero_()
    task.terminate_buf[:] = torch.tensor([True, False, False, True])
    task.timeout_buf.zero_()
    tracking = np.exp(-np.sum((commands[:, :2] - v_body[:, :2]) ** 2, axis=1) / 0.25)
    action_rate = np.sum(actions.numpy() ** 2, axis=1)
    fell = np.array([1.0, 0.0, 0.0, 1.0])
    for steps_done, factor in ((0, 0.25), (40, 0.25 + 0.75 * 0.4), (100, 1.0), (1000, 1.0)):
        task.randomizer.step_count.fill_(steps_done)
        task.compute_reward()
        expected = CONTROL_DT * (1.5 * tracking - factor * 0.2 * action_rate - 50.0 * fell)
        np.testing.assert_allclose(task.rew_buf.numpy(), expected, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("value, complaint", [
    ({"start": 0.0, "steps": 10}, "start must be in (0, 1]"),
    ({"start": 0.5, "steps": 0}, "steps must be a whole number >= 1"),
    ({"start": 0.5}, "exactly the keys start and steps"),
])
def test_penalty_curriculum_bad_input_names_the_key(value, complaint):
    overrides = ["task.env.rewards.penaltyCurriculum={" + ",".join(f"{k}:{v}" for k, v in value.items()) + "}"]
    with pytest.raises(ValueError, match=re.escape(complaint)) as err:
        make_legged("Go1", [*QUIET, *overrides])
    assert "env.rewards.penaltyCurriculum" in str(err.value)


HEADING = ["+task.env.commands.heading.range=[-3.0,3.0]", "+task.env.commands.heading.stiffness=0.5"]


def test_heading_command_steers_the_yaw_rate_by_the_wrapped_heading_error():
    # env.commands.heading {range, stiffness}: yaw-rate command = clip(stiffness * wrap(heading - yaw), yawRate).
    task = make_legged("Go1", [*QUIET, *HEADING])
    task.reset()
    rot = write_known_root_state(task, "Go1")
    yaw = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])  # the body x axis in the world's ground plane
    targets = np.array([0.9, 2.9, -2.9, 2.9])  # the last two cross +-pi: the short way round is the other sign
    task.heading_targets[:] = torch.tensor(targets, dtype=torch.float32)
    task._resample_commands(torch.zeros(N, dtype=torch.bool))
    error = np.array([0.2, 4.1 - 2 * np.pi, -5.4 + 2 * np.pi, 5.8 - 2 * np.pi])  # worked by hand from the two rows
    np.testing.assert_allclose(yaw, YAW, atol=1e-6)
    np.testing.assert_allclose(task.commands[:, 2].numpy(), np.clip(0.5 * error, -1.0, 1.0), atol=1e-5)

    # Resampling draws new headings in range for the masked envs only.
    mask = torch.tensor([True, False, True, False])
    task._resample_commands(mask)
    new = task.heading_targets.numpy()
    np.testing.assert_allclose(new[~mask.numpy()], targets[~mask.numpy()], rtol=0, atol=1e-6)
    assert np.all(np.abs(new[mask.numpy()]) <= 3.0) and np.all(new[mask.numpy()] != targets[mask.numpy()])

    # After a real step the command follows the yaw MuJoCo C reads from the same quaternion.
    task.step(torch.zeros(N, 12))
    mat = np.zeros(9)
    for i, q in enumerate(task.sim.root_quat.numpy().astype(np.float64)):
        mujoco.mju_quat2Mat(mat, q)
        err = task.heading_targets[i].item() - math.atan2(mat[3], mat[0])
        err = (err + math.pi) % (2 * math.pi) - math.pi
        assert task.commands[i, 2].item() == pytest.approx(min(1.0, max(-1.0, 0.5 * err)), abs=1e-5)


@pytest.mark.parametrize("value, complaint", [
    ({"range": "[-4.0,1.0]", "stiffness": 0.5}, "range must be [low, high] in radians"),
    ({"range": "[-1.0,1.0]", "stiffness": 0}, "stiffness must be a number > 0"),
    ({"range": "[-1.0,1.0]"}, "exactly the keys range and stiffness"),
])
def test_heading_command_bad_input_names_the_key(value, complaint):
    overrides = [f"+task.env.commands.heading.{k}={v}" for k, v in value.items()]
    with pytest.raises(ValueError, match=re.escape(complaint)) as err:
        make_legged("Go1", [*QUIET, *overrides])
    assert "env.commands.heading" in str(err.value)


# -------------------------------------------------------------------------------- 9. observation layout
def test_observation_layout_matches_rotation_math_and_mujoco_c(quiet_task, robot):
    task = quiet_task
    scales = yaml_cfg(robot).env.obsScales
    assert dict(scales) == {"linVel": 2.0, "angVel": 0.25, "dofPos": 1.0, "dofVel": 0.05}  # task YAML
    gen = torch.Generator().manual_seed(5)
    default = torch.tensor([FACTS[robot]["default_angles"][j] for j in task.sim.dof_names])
    dof_pos = default + 0.1 * torch.randn(N, 12, generator=gen)
    dof_vel = torch.randn(N, 12, generator=gen)
    task.sim.write_state(all_envs(), dof_pos=dof_pos, dof_vel=dof_vel)
    rot = write_known_root_state(task, robot)
    commands = torch.tensor([[0.8, -0.3, 0.2], [0.0, 0.0, 0.0], [1.0, 0.5, -0.9], [-0.6, 0.7, 1.0]])
    task.commands[:] = commands
    actions = torch.randn(N, 12, generator=gen)
    task.actions[:] = actions
    task.compute_observations()
    obs = task.obs_buf.numpy()

    v_body = np.einsum("nji,nj->ni", rot, V_WORLD)
    g_body = np.einsum("nji,j->ni", rot, np.array([0.0, 0.0, -1.0]))
    np.testing.assert_allclose(obs[:, 0:3], 2.0 * v_body, atol=2e-6)
    np.testing.assert_allclose(obs[:, 3:6], 0.25 * W_BODY, atol=2e-6)
    np.testing.assert_allclose(obs[:, 6:9], g_body, atol=2e-6)
    np.testing.assert_allclose(obs[:, 9:12], commands.numpy() * [2.0, 2.0, 0.25], atol=1e-6)
    np.testing.assert_allclose(obs[:, 12:24], (dof_pos - default).numpy(), atol=1e-6)
    np.testing.assert_allclose(obs[:, 24:36], 0.05 * dof_vel.numpy(), atol=1e-6)
    np.testing.assert_allclose(obs[:, 36:48], actions.numpy(), atol=0)

    # MuJoCo C: the base body's 6D velocity [angular; linear] at its frame origin, in its frame (mjOBJ_XBODY is
    # the body frame; mjOBJ_BODY would be the principal-inertia frame), at the same state.
    model = task.sim.mj_model
    base = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, FACTS[robot]["base"])
    data = mujoco.MjData(model)
    res = np.zeros(6)
    for i in range(N):
        data.qpos[:] = task.sim.qpos[i].numpy()
        data.qvel[:] = task.sim.qvel[i].numpy()
        mujoco.mj_forward(model, data)
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_XBODY, base, res, 1)
        np.testing.assert_allclose(obs[i, 3:6], 0.25 * res[:3], atol=2e-6)
        np.testing.assert_allclose(obs[i, 0:3], 2.0 * res[3:], atol=2e-6)
        np.testing.assert_allclose(obs[i, 6:9], data.xmat[base].reshape(3, 3).T @ [0, 0, -1], atol=2e-6)


# -------------------------------------------------------------------------------------------- 10. time_outs
def test_episodes_end_by_time_out_at_the_step_limit(robot):
    task = make_legged(robot, [*QUIET, "task.env.episodeLength_s=0.2"])
    max_len = math.ceil(0.2 / CONTROL_DT)
    assert max_len == 10 and task.max_episode_length == max_len
    reset_to_default_pose(task)
    active = {n for n, s in yaml_cfg(robot).env.rewards.scales.items() if s != 0.0}
    progress, fired = 0, []
    for k in range(1, 2 * max_len + 3):
        _, _, reset, extras = task.step(task.zero_actions())
        progress += 1
        # The IsaacGymEnvs rule VecTask documents (and the Cartpole contract tests): an episode ends once
        # progress_buf reaches max_episode_length - 1.
        expect = progress >= max_len - 1
        assert torch.equal(reset, torch.full((N,), int(expect))), f"step {k}"
        assert torch.equal(extras["time_outs"], torch.full((N,), int(expect))), f"step {k}"
        assert not task.terminated.any(), f"step {k}: the standing robot fell"
        if expect:
            fired.append(k)
            progress = 0
            assert set(extras["episode_terms"]) == active
        assert torch.equal(task.progress_buf, torch.full((N,), progress)), f"step {k}"
    assert fired == [max_len - 1, 2 * (max_len - 1)]


# ------------------------------------------------------------------------------------------ tilt termination
def test_tilt_test_equals_the_angle_between_the_base_up_axis_and_the_world_up():
    from isaacgymenvs_mw.tasks.legged_task import base_tilted

    rng = np.random.default_rng(4)
    axes = rng.normal(size=(500, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(0.0, math.pi, 500)
    gravity = []
    for axis, angle in zip(axes, angles):  # world gravity (0, 0, -1) in a base rotated by `angle` about `axis`
        q, r = np.zeros(4), np.zeros(9)
        mujoco.mju_axisAngle2Quat(q, axis, angle)
        mujoco.mju_quat2Mat(r, q)
        gravity.append(r.reshape(3, 3).T @ np.array([0.0, 0.0, -1.0]))
    # the tilt is the angle between the base's z axis and world z: |angle| only for rotations about a horizontal axis
    tilt = np.array([np.arccos(np.clip(-g[2], -1.0, 1.0)) for g in gravity])
    got = base_tilted(torch.as_tensor(np.array(gravity), dtype=torch.float32), math.cos(1.2)).numpy()
    np.testing.assert_array_equal(got, tilt > 1.2)
    assert 0 < got.sum() < 500


def test_a_base_on_its_side_ends_the_episode_an_upright_one_does_not():
    task = make_legged("Anymal", overrides=["+task.env.terminationTilt=1.5708", "task.env.resetRootVelocityRange=0.0"])
    task.reset()
    n = task.num_envs
    # high above the ground (no contact can end it), turned about x by 100 deg in env 0 and 60 deg in the others
    angle = torch.full((n,), math.radians(60.0))
    angle[0] = math.radians(100.0)
    quat = torch.stack((torch.cos(angle / 2), torch.sin(angle / 2), torch.zeros(n), torch.zeros(n)), dim=1)
    pos = task.sim.root_pos.clone()
    pos[:, 2] = 3.0
    task.sim.write_state(all_envs(), root_pos=pos, root_quat=quat)
    _, _, done, extras = task.step(torch.zeros(n, task.num_actions))
    assert done.tolist() == [1] + [0] * (n - 1)
    assert extras["time_outs"].tolist() == [0] * n  # a failure, not a time-out


def test_a_tilt_limit_outside_its_range_is_refused():
    with pytest.raises(Exception, match=r"env\.terminationTilt=4\.0 is invalid: give an angle in \(0, pi\]"):
        make_legged("Anymal", overrides=["+task.env.terminationTilt=4.0"])
