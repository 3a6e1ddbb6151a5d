"""Deployable export (Go1, CPU, tiny): the metadata in policy.onnx / policy.pt / policy.json equals the task's values,
and examples/deploy_mujoco.py, fed the task's own states in plain MuJoCo, rebuilds the task's observation (history
included) so that its onnxruntime actions equal the torch policy's.

Expected values come from outside the code under test: the task YAML (read with OmegaConf, joint patterns written
out here by hand), MuJoCo compiling the URDF on its own (joint order), importlib.metadata (versions).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import sys
from importlib import metadata

import mujoco
import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

import isaacgymenvs_mw
from conftest import CPU_ARGS, REPO_ROOT
from isaacgymenvs_mw.learning.export import export_policy, read_metadata
from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.utils import files
from isaacgymenvs_mw.utils.config import compose_config, to_dict
from isaacgymenvs_mw.utils.files import DiskWriteError

sys.path.insert(0, str(REPO_ROOT / "examples"))
import deploy_mujoco  # noqa: E402

HISTORY = ["dof_vel", "actions"]
OVERRIDES = [
    "task.task.randomize=False",  # the deployed observation is noiseless (and the model nominal)
    f"+task.env.history={{policy:{{length:3,terms:[{','.join(HISTORY)}]}}}}",
]
# cfg/task/Go1.yaml over the legged base its defaults list names, merged here by OmegaConf rather than Hydra.
GO1_YAML = OmegaConf.merge(OmegaConf.load(REPO_ROOT / "cfg" / "legged" / "base.yaml"),
                           OmegaConf.load(REPO_ROOT / "cfg" / "task" / "Go1.yaml"))


def default_angle(joint: str) -> float:
    """cfg/task/Go1.yaml defaultJointAngles, read by hand."""
    if joint.endswith("hip_joint"):
        return 0.1 if joint[1] == "L" else -0.1
    if joint.endswith("thigh_joint"):
        return 0.8 if joint[0] == "F" else 1.0
    assert joint.endswith("calf_joint"), joint
    return -1.5


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("export") / "exported"
    torch.manual_seed(0)
    task = isaacgymenvs_mw.make("Go1", num_envs=2, sim_device="cpu", rl_device="cpu", overrides=OVERRIDES)
    env = RslRlVecEnv(task)
    train_cfg = rsl_rl_config(to_dict(compose_config(["task=Go1", *CPU_ARGS]).train))
    train_cfg.pop("max_iterations"), train_cfg.pop("experiment_name", None)
    runner = Runner(env, train_cfg, log_dir=None, device="cpu")
    # An untrained policy with a non-trivial normaliser, so that leaving it out of the export would show.
    actor = runner.alg.get_policy()
    with torch.no_grad():
        actor.obs_normalizer._mean.normal_(0.0, 0.3)
        actor.obs_normalizer._std.uniform_(0.5, 2.0)
    export_policy(runner, out, task=task)
    return task, env, runner, out


def test_exported_metadata_equals_the_task(exported):
    task, _, _, out = exported
    on_disk = json.loads((out / "policy.json").read_text())
    assert read_metadata(out / "policy.onnx") == on_disk
    assert read_metadata(out / "policy.pt") == on_disk
    meta = on_disk
    env, sim = GO1_YAML.env, GO1_YAML.sim

    urdf_model = mujoco.MjModel.from_xml_path(str(REPO_ROOT / "assets" / env.asset.assetFileName))
    joints = [urdf_model.joint(j).name for j in range(urdf_model.njnt)]
    assert meta["joint_names"] == joints and len(joints) == env.numActions == 12
    # Action i commands actuator i; the framework's drives are named after their joints, so both lists agree.
    assert meta["actuator_names"] == joints and meta["actuator_joints"] == meta["joint_names"]
    assert meta["default_joint_pos"] == pytest.approx([default_angle(j) for j in joints])
    assert meta["action_scale"] == env.control.actionScale
    assert meta["stiffness"] == pytest.approx([20.0] * 12) and meta["damping"] == pytest.approx([0.5] * 12)
    assert meta["control_dt"] == pytest.approx(sim.dt * env.controlFrequencyInv)
    assert meta["physics_dt"] == pytest.approx(sim.dt) and meta["decimation"] == env.controlFrequencyInv
    assert meta["clip_actions"] == env.clipActions and meta["clip_observations"] == env.clipObservations

    obs = meta["observation"]
    scales = env.obsScales
    assert [(t["name"], t["size"], t["scale"]) for t in obs["terms"]] == [
        ("base_lin_vel", 3, scales.linVel), ("base_ang_vel", 3, scales.angVel), ("projected_gravity", 3, 1.0),
        ("commands", 3, 1.0), ("dof_pos", 12, scales.dofPos), ("dof_vel", 12, scales.dofVel), ("actions", 12, 1.0)]
    assert meta["commands_scale"] == pytest.approx([scales.linVel, scales.linVel, scales.angVel])
    assert obs["frame_size"] == task.num_obs == 48  # derived from the terms
    assert obs["history"]["length"] == 3 and obs["history"]["terms"] == HISTORY
    assert obs["size"] == 48 + 2 * 24 == task.observation_space.shape[0]
    assert meta["state"]["size"] == task.num_states == 55 and meta["state"]["history"] == {"length": 1}

    versions = meta["versions"]
    for dist in ("torch", "warp-lang", "mujoco", "mujoco-warp", "rsl-rl-lib"):
        assert versions[dist] == metadata.version(dist)
    assert versions["isaacgymenvs_mw"] == isaacgymenvs_mw.__version__

    # the exported MuJoCo model is the task's: same joints, PD gains and timestep
    model = mujoco.MjModel.from_binary_path(str(out / meta["files"]["mujoco_model"]))
    assert model.opt.timestep == pytest.approx(sim.dt) and model.nu == 12
    assert np.allclose(model.actuator_gainprm[:, 0], 20.0) and np.allclose(model.actuator_biasprm[:, 2], -0.5)


def test_deploy_example_observation_and_onnx_actions_match_the_task(exported):
    task, env, runner, out = exported
    robot = deploy_mujoco.Deployment(out)
    session = deploy_mujoco.load_session(out)
    policy = runner.get_inference_policy(device="cpu")
    torch.manual_seed(1)
    obs_td = env.get_observations()  # the task's observation after its reset (history filled)

    def sync_robot() -> None:
        """Put env 0's state and command into the MuJoCo C data, as a robot's state estimator would."""
        robot.data.qpos[:] = task.sim.qpos[0].double().numpy()
        robot.data.qvel[:] = task.sim.qvel[0].double().numpy()
        robot.command[:] = task.commands[0].double().numpy()
        mujoco.mj_forward(robot.model, robot.data)

    sync_robot()
    robot_obs = robot.observe(new_episode=True)
    for step in range(8):
        task_obs = obs_td["policy"][0].numpy()
        assert robot_obs.shape == task_obs.shape == (96,)
        np.testing.assert_allclose(robot_obs, task_obs, rtol=1e-5, atol=1e-5, err_msg=f"step {step}")
        with torch.inference_mode():
            torch_actions = policy(obs_td).numpy()
        onnx_action = session.run(["actions"], {"obs": robot_obs[None].astype(np.float32)})[0][0]
        np.testing.assert_allclose(onnx_action, torch_actions[0], rtol=1e-4, atol=1e-5, err_msg=f"step {step}")
        assert np.ptp(torch_actions[0]) > 1e-3  # a real action, not a constant
        robot.last_action[:] = np.clip(onnx_action, -robot.clip_actions, robot.clip_actions)
        obs_td, _, dones, _ = env.step(torch.as_tensor(np.stack([onnx_action, torch_actions[1]])))
        assert not bool(dones[0])  # eight steps from a reset: no episode ends (the history would restart)
        sync_robot()
        robot_obs = robot.observe()


def test_deploy_example_physics_matches_the_task(exported):
    """One control period of the deploy script's MuJoCo C (``apply``), started from the task's state with the same
    action, ends where the task's MuJoCo Warp step does: the sim-to-sim check compares policies, not solvers.

    MuJoCo C run with the task's own solver limits (4 Newton iterations) fails this: from these states it measured
    0.6-1.2 rad/s mean and 7-12 rad/s worst joint-speed error per step (five seeds), against 0.03-0.06 and
    0.35-1.0 rad/s solved to convergence; an Anymal policy then tracked 0.43 m/s instead of Warp's 0.23 m/s.
    """
    task, env, _, out = exported
    robot = deploy_mujoco.Deployment(out)
    torch.manual_seed(2)
    task.reset()
    errors = []
    for _ in range(40):
        actions = 0.5 * torch.randn(2, task.num_actions)  # leg motion with feet landing and lifting
        robot.data.qpos[:] = task.sim.qpos[0].double().numpy()
        robot.data.qvel[:] = task.sim.qvel[0].double().numpy()
        mujoco.mj_forward(robot.model, robot.data)
        robot.apply(actions[0].numpy())
        _, _, dones, _ = env.step(actions)
        if not bool(dones[0]):  # a reset replaced the state MuJoCo C stepped from
            errors.append(np.abs(robot.data.qvel - task.sim.qvel[0].double().numpy()).max())
    errors = np.array(errors)
    assert len(errors) >= 30 and np.abs(robot.data.qvel).max() > 1.0  # moving, mostly in contact, few resets
    assert errors.mean() < 0.2 and errors.max() < 3.0, (errors.mean(), errors.max())


def test_deploy_example_runs_and_reports_tracking_error(exported):
    *_, out = exported
    result = deploy_mujoco.run(out, (0.5, 0.0, 0.0), seconds=0.4, settle=0.1)
    assert result["task"] == "Go1"
    assert np.isfinite(result["lin_vel_tracking_error"]) and np.isfinite(result["yaw_rate_tracking_error"])
    assert result["min_base_height"] > 0.1  # started standing on the floor


def test_an_export_on_a_disk_that_fills_midway_is_one_line_and_leaves_the_previous_one_whole(exported, tmp_path,
                                                                                             monkeypatch):
    task, _, runner, out = exported
    target = tmp_path / "exported"
    shutil.copytree(out, target)
    before = {p.name: p.read_bytes() for p in target.iterdir()}
    real_write, calls = files._write_bytes, []

    def fills_on_the_second_file(path, data):
        calls.append(path.name)
        if len(calls) == 2:  # half of it reaches the disk, then the disk is full
            path.write_bytes(data[: len(data) // 2])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_write(path, data)

    monkeypatch.setattr(files, "_write_bytes", fills_on_the_second_file)
    with pytest.raises(DiskWriteError) as err:
        export_policy(runner, target, task=task)
    assert "\n" not in str(err.value)
    assert str(err.value).startswith(f"cannot write policy.pt in {target} ({os.strerror(errno.ENOSPC)}; "), err.value
    assert {p.name: p.read_bytes() for p in target.iterdir()} == before  # no new file in, no hidden file left
    assert [p.name for p in tmp_path.iterdir()] == ["exported"]  # and no private folder beside it


def test_exported_model_mjb_is_the_model_mujoco_saves(exported, tmp_path):
    task, *_, out = exported
    task.sim.save_model(str(tmp_path / "by_mujoco.mjb"))  # MuJoCo's own file writer
    assert (out / "model.mjb").read_bytes() == (tmp_path / "by_mujoco.mjb").read_bytes()


def test_plain_task_policy_json_names_the_actuators_in_action_order(tmp_path):
    """Cartpole (a plain VecTask, no joint metadata of its own): policy.json says which actuator each action drives.

    Expected: cfg/task/Cartpole.yaml's driven joints (driveMode, not none), in the order MuJoCo compiles the URDF."""
    cfg = OmegaConf.load(REPO_ROOT / "cfg" / "task" / "Cartpole.yaml").env
    urdf_model = mujoco.MjModel.from_xml_path(str(REPO_ROOT / "assets" / cfg.asset.assetFileName))
    joints = [urdf_model.joint(j).name for j in range(urdf_model.njnt)]
    driven = [j for j in joints if cfg.control.driveMode.get(j, cfg.control.defaultDriveMode) != "none"]
    assert driven == ["slider_to_cart"] and cfg.numActions == len(driven)

    task = isaacgymenvs_mw.make("Cartpole", num_envs=2, sim_device="cpu", rl_device="cpu")
    env = RslRlVecEnv(task)
    train_cfg = rsl_rl_config(to_dict(compose_config(["task=Cartpole", *CPU_ARGS]).train))
    train_cfg.pop("max_iterations"), train_cfg.pop("experiment_name", None)
    export_policy(Runner(env, train_cfg, log_dir=None, device="cpu"), tmp_path, task=task)
    meta = json.loads((tmp_path / "policy.json").read_text())
    assert meta["actuator_names"] == driven and meta["actuator_joints"] == driven
    assert meta["num_actions"] == len(meta["actuator_names"])
    assert "joint_names" not in meta
    assert read_metadata(tmp_path / "policy.onnx")["actuator_names"] == driven


def test_rsl_rl_recurrent_policy_runs_test_mode_and_exports_its_state(tmp_path):
    """rsl-rl-lib's RNNModel actor (an LSTM on the observation): its checkpoint passes the size check in test mode
    (the observation count is the LSTM's input, not the MLP's), and policy.onnx takes and returns the LSTM's state,
    giving the actions of rsl-rl-lib's own ONNX module over 3 steps with the state carried."""
    import onnxruntime

    from isaacgymenvs_mw.learning.launch import run

    args = ["task=Cartpole", "num_envs=8", *CPU_ARGS, f"runs_dir={tmp_path}", "train.actor.class_name=RNNModel",
            "++train.actor.rnn_type=lstm", "++train.actor.rnn_hidden_dim=8", "++train.actor.rnn_num_layers=1"]
    run(compose_config([*args, "max_iterations=2"]))
    (run_dir,) = (tmp_path / "Cartpole").iterdir()
    result = run(compose_config([*args, "test=True", f"checkpoint={run_dir / 'model_2.pt'}"]))
    assert result["episodes"] == 8
    onnx_path = run_dir / "exported" / "policy.onnx"
    assert read_metadata(onnx_path)["recurrent"]["state_inputs"] == ["h_in", "c_in"]

    cfg = compose_config([*args, "test=True"])
    task = isaacgymenvs_mw.make("Cartpole", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True)
    runner = Runner(RslRlVecEnv(task), rsl_rl_config(to_dict(cfg.train)), log_dir=None, device="cpu")
    runner.load(str(run_dir / "model_2.pt"), map_location="cpu")
    reference, _ = runner.export_modules()  # rsl-rl-lib's _OnnxRNNModel, eager
    session = onnxruntime.InferenceSession(str(onnx_path))
    h = c = np.zeros((1, 3, 8), dtype=np.float32)
    h_ref = c_ref = torch.zeros(1, 3, 8)
    obs = np.random.default_rng(2).normal(size=(3, 3, 4)).astype(np.float32)
    for t in range(3):
        actions, h, c = session.run(["actions", "h_out", "c_out"], {"obs": obs[t], "h_in": h, "c_in": c})
        with torch.no_grad():
            expected, h_ref, c_ref = reference(torch.from_numpy(obs[t]), h_ref, c_ref)
        np.testing.assert_allclose(actions, expected.numpy(), rtol=1e-4, atol=1e-5)
    task.close()
