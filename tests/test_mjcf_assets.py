"""MJCF robots as first-class assets (issues 12 and 17): the asset's own actuators, contact settings, free root
joint and start pose are kept; YAML drives only add to what the asset does not actuate; numActions, contact bodies,
required hooks and relative asset roots are checked or honoured by any VecTask, checked against MuJoCo C."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

from conftest import TESTS_DIR
from isaacgymenvs_mw.tasks.base.vec_task import VecTask

WALKER = TESTS_DIR / "assets" / "walker.xml"


class Walker(VecTask):
    """The smallest task over any asset: ctrl = action, observation = joint positions."""

    max_episode_length = 100

    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.sim.ctrl[:] = actions

    def post_physics_step(self) -> None:
        self.progress_buf += 1
        self.compute_observations()

    def compute_observations(self) -> None:
        self.obs_buf[:] = self.sim.dof_pos[:, : self.num_obs]


def walker_cfg(num_actions: int = 2, control: dict | None = None, asset: dict | None = None, **env) -> dict:
    return {
        "env": {
            "numEnvs": 2, "numObservations": 3, "numActions": num_actions,
            "asset": {"assetRoot": str(WALKER.parent), "assetFileName": WALKER.name, "fixBaseLink": False,
                      **(asset or {})},
            "control": control or {},
            "plane": {"enabled": True, "friction": 1.0},
            **env,
        },
        "sim": {"dt": 0.002, "nconmax": 16, "njmax": 64},
    }


def make_walker(cfg: dict, cls: type = Walker) -> VecTask:
    return cls(cfg, rl_device="cpu", sim_device="cpu", graphics_device_id=0, headless=True)


def file_model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_path(str(WALKER))


# ------------------------------------------------------------------------------------------------- actuators
def test_asset_actuators_are_kept_in_file_order():
    task = make_walker(walker_cfg())
    m, ref = task.sim.mj_model, file_model()
    assert m.nu == ref.nu == 2  # no framework motor appended next to the asset's own
    assert task.sim.actuator_names == ["right_hip_motor", "left_hip_motor"]
    assert task.sim.actuator_joints == ["right_hip", "left_hip"]
    np.testing.assert_array_equal(m.actuator_gear, ref.actuator_gear)
    np.testing.assert_array_equal(m.actuator_ctrlrange, ref.actuator_ctrlrange)
    np.testing.assert_array_equal(m.dof_armature[6:], ref.dof_armature[6:])
    np.testing.assert_array_equal(m.jnt_range, ref.jnt_range)


def test_ctrl_column_drives_the_named_actuator_with_its_gear():
    """ctrl[:, i] -> actuator i: the joint force is gear * clamp(ctrl, ctrlrange) on that actuator's joint only."""
    task = make_walker(walker_cfg())
    task.reset()
    ctrl = torch.tensor([[0.5, -0.25], [3.0, 0.0]])  # 3.0 is beyond ctrlrange [-1, 1]
    task.step(ctrl)
    names = task.sim.dof_names
    force = task.sim.qfrc_actuator[:, 6:]
    expected = np.zeros((2, len(names)))
    for i, (joint, gear) in enumerate(zip(task.sim.actuator_joints, (30.0, 20.0))):
        expected[:, names.index(joint)] = gear * np.clip(ctrl[:, i].numpy(), -1.0, 1.0)
    np.testing.assert_allclose(force.numpy(), expected, rtol=1e-5, atol=1e-5)


def test_default_drive_mode_covers_only_unactuated_joints():
    task = make_walker(walker_cfg(num_actions=3, control={"defaultDriveMode": "effort",
                                                          "effortLimit": {"left_ankle": 4.0}}))
    assert task.sim.actuator_names == ["right_hip_motor", "left_hip_motor", "left_ankle"]
    assert task.sim.actuator_joints == ["right_hip", "left_hip", "left_ankle"]
    task.reset()
    task.step(torch.tensor([[0.0, 0.0, 100.0], [0.0, 0.0, -2.0]]))
    ankle = task.sim.dof_names.index("left_ankle")
    # effortLimit caps the motor: 100 N m asked, 4 N m applied; -2 stays
    np.testing.assert_allclose(task.sim.qfrc_actuator[:, 6 + ankle].numpy(), [4.0, -2.0], rtol=1e-5)


def test_yaml_drive_on_an_actuated_joint_is_an_error_naming_it():
    with pytest.raises(ValueError, match=r"driveMode.*left_hip.*left_hip_motor"):
        make_walker(walker_cfg(control={"driveMode": {"left_hip": "position"}}))


def test_effort_drive_without_a_torque_cap_is_an_error():
    with pytest.raises(ValueError, match=r"left_ankle.*no torque cap.*env\.control\.effortLimit"):
        make_walker(walker_cfg(num_actions=3, control={"driveMode": {"left_ankle": "effort"}}))


def test_gear_and_ctrl_range_overrides():
    task = make_walker(walker_cfg(control={"gear": {"left_hip": 50.0}, "ctrlRange": {"right_hip_motor": [-2, 2]}}))
    m = task.sim.mj_model
    assert m.actuator_gear[:, 0].tolist() == [30.0, 50.0]  # by joint name; the other keeps the file's
    assert m.actuator_ctrlrange.tolist() == [[-2.0, 2.0], [-1.0, 1.0]]  # by actuator name


@pytest.mark.parametrize("key", ["gear", "ctrlRange"])
def test_override_on_a_missing_actuator_is_an_error_naming_the_key(key):
    value = 10.0 if key == "gear" else [-1, 1]
    with pytest.raises(ValueError, match=rf"env\.control\.{key}: 'knee' matches no actuator.*left_hip_motor"):
        make_walker(walker_cfg(control={key: {"knee": value}}))


def test_action_count_must_match_the_actuators():
    with pytest.raises(ValueError, match=r"numActions=5 but the model has 2 actuators.*right_hip_motor"):
        make_walker(walker_cfg(num_actions=5))


def test_an_asset_without_actuators_is_an_error(tmp_path):
    bare = tmp_path / "bare.xml"
    spec = mujoco.MjSpec.from_file(str(WALKER))
    for act in list(spec.actuators):
        spec.delete(act)
    bare.write_text(spec.to_xml())
    cfg = walker_cfg()
    cfg["env"]["asset"].update(assetRoot=str(tmp_path), assetFileName="bare.xml")
    with pytest.raises(ValueError, match=r"numActions=2 but the model has no actuators"):
        make_walker(cfg)
