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


def test_yaml_drive_on_an_actuated_joint_rewrites_its_actuator_in_place():
    task = make_walker(walker_cfg(control={"driveMode": {"left_hip": "position"}, "stiffness": {"left_hip": 40.0},
                                           "damping": {"left_hip": 2.0}}))
    m = task.sim.mj_model
    assert task.sim.actuator_names == ["right_hip_motor", "left_hip_motor"]  # one per joint, names and order kept
    a = m.actuator("left_hip_motor").id
    assert m.actuator_gainprm[a, 0] == 40.0 and m.actuator_biasprm[a, :3].tolist() == [0.0, -40.0, -2.0]


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


# ----------------------------------------------------------------------------------- floating base and start pose
def test_free_root_joint_is_the_floating_base_at_the_bodys_own_pose():
    task = make_walker(walker_cfg())
    m, ref = task.sim.mj_model, file_model()
    assert task.sim.floating_base and m.njnt == ref.njnt  # the file's free joint, no second one added
    np.testing.assert_allclose(m.qpos0[:7], ref.qpos0[:7])
    np.testing.assert_allclose(m.qpos0[:3], [0.0, 0.0, 0.6])
    np.testing.assert_allclose(m.qpos0[3:7], [math.cos(math.pi / 8), 0, 0, math.sin(math.pi / 8)], atol=1e-6)


def test_base_init_state_wins_over_the_bodys_pose():
    task = make_walker(walker_cfg(baseInitState={"pos": [1.0, 2.0, 0.8], "rot": [0.0, 0.0, 0.0, 1.0]}))
    np.testing.assert_allclose(task.sim.mj_model.qpos0[:7], [1.0, 2.0, 0.8, 0.0, 0.0, 0.0, 1.0])
    task.reset()
    task.sim.reset_worlds(torch.ones(2, dtype=torch.bool))  # a reset goes back to that pose
    np.testing.assert_allclose(task.sim.root_pos.numpy(), [[1.0, 2.0, 0.8]] * 2)


def test_plain_vec_task_puts_a_urdf_floating_base_at_base_init_state():
    cfg = walker_cfg(num_actions=1, control={"driveMode": {"hinge": "effort"}}, baseInitState={"pos": [0, 0, 2.0]})
    cfg["env"]["asset"] = {"assetRoot": "", "assetFileName": "urdf/pendulum.urdf", "fixBaseLink": False}
    cfg["env"]["numObservations"] = 1
    task = make_walker(cfg)
    assert task.sim.floating_base
    np.testing.assert_allclose(task.sim.mj_model.qpos0[:7], [0, 0, 2.0, 1, 0, 0, 0])


def test_free_root_joint_with_fix_base_link_is_an_error():
    with pytest.raises(ValueError, match=r"root body 'torso' has a free joint.*fixBaseLink is True"):
        make_walker(walker_cfg(asset={"fixBaseLink": True}))


@pytest.mark.parametrize("rot", [[1.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0]])
def test_bad_base_init_rot_is_an_error(rot):
    with pytest.raises(ValueError, match=r"env\.baseInitState\.rot"):
        make_walker(walker_cfg(baseInitState={"pos": [0, 0, 1], "rot": rot}))


# -------------------------------------------------------------------------------------------------- contacts
BOX_XML = """<mujoco model="box">
  <worldbody>
    <body name="box" pos="0 0 0.1">
      <freejoint/>
      <geom name="box_geom" type="box" size="0.1 0.1 0.1" mass="2" contype="4" conaffinity="4" condim="{condim}"/>
      {ghost}
    </body>
  </worldbody>
  <actuator><motor name="unused" joint="lid"/></actuator>
</mujoco>"""


def box_task(tmp_path, condim: int = 3, ghost: bool = False, **asset) -> VecTask:
    """A 2 kg box on the ground, sensed by env.asset.contactBodies. MuJoCo needs an actuated joint for numActions
    >= 1, so the box carries a tiny lid on a hinge with a motor."""
    ghost_geom = ('<geom name="ghost" type="sphere" size="0.05" pos="0 0 -0.12" mass="0" contype="0" '
                  'conaffinity="0"/>') if ghost else ""
    xml = BOX_XML.format(condim=condim, ghost=ghost_geom).replace(
        "{ghost}", "").replace("</body>\n  </worldbody>",
                               '<body name="lid" pos="0 0 0.1"><joint name="lid" type="hinge" axis="0 1 0"/>'
                               '<geom type="sphere" size="0.01" mass="0.001" contype="0" conaffinity="0"/></body>'
                               "</body>\n  </worldbody>")
    (tmp_path / "box.xml").write_text(xml)
    cfg = walker_cfg(num_actions=1, asset={"assetRoot": str(tmp_path), "assetFileName": "box.xml",
                                           "contactBodies": ["box"], **asset})
    cfg["env"]["numObservations"] = 1
    return make_walker(cfg)


def settle(task: VecTask, steps: int, push_x: float = 0.0) -> None:
    task.reset()
    task.sim.xfrc_applied[:, task.sim.body_id("box"), 0] = push_x
    for _ in range(steps):
        task.step(torch.zeros(task.num_envs, 1))


def test_contact_force_sign_and_frame(tmp_path):
    """The net contact force sensor reads the force the body exerts on what it touches, in the world frame: a
    resting body shows -m g in z, the opposite sign to IsaacGym's net_contact_force (the force on the body)."""
    task = box_task(tmp_path, keepAssetContacts=False)
    adr = int(task.sim.mj_model.sensor("contact_box").adr[0])
    assert list(task.sim.sensors.get("contact_forces").bodies) == ["box"]
    settle(task, 300, push_x=5.0)  # 5 N pushes the box along +x; static friction (mu 1 * 19.6 N) holds it
    weight = 2.001 * 9.81
    force = task.sim.sensordata[:, adr:adr + 3]
    np.testing.assert_allclose(force.numpy(), [[5.0, 0.0, -weight]] * 2, atol=2e-2)
    np.testing.assert_allclose(task.sim.sensor("contact_forces")[:, 0].numpy(), force.numpy())
    assert abs(float(task.sim.qvel[0, 0])) < 1e-2  # it did not slide: friction balanced the push


def test_mjcf_contact_settings_are_kept(tmp_path):
    """The file's bits and condim count: the non-colliding ghost sinks into the ground, and a frictionless
    (condim 1) box slides under a push, a = F / m."""
    task = box_task(tmp_path, condim=1, ghost=True)
    m = task.sim.mj_model
    box, ghost = task.sim.geom_id("box_geom"), task.sim.geom_id("ghost")
    assert (m.geom_contype[box], m.geom_conaffinity[box], m.geom_condim[box]) == (4, 4, 1)
    assert (m.geom_contype[ghost], m.geom_conaffinity[ghost]) == (0, 0)
    settle(task, 100, push_x=5.0)
    assert float(task.sim.root_pos[0, 2]) == pytest.approx(0.1, abs=5e-3)  # on its box, not on the ghost
    elapsed = 100 * task.control_dt
    assert float(task.sim.qvel[0, 0]) == pytest.approx(5.0 / 2.001 * elapsed, rel=2e-2)


def test_framework_filter_when_asked(tmp_path):
    """keepAssetContacts: False gives the URDF behaviour: every robot geom touches the ground (the ghost too)."""
    task = box_task(tmp_path, condim=1, ghost=True, keepAssetContacts=False)
    m = task.sim.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)  # MuJoCo C: which geoms touch the ground at the start pose
    ground = task.sim.geom_id("ground")
    touching = {int(g) for c in d.contact[: d.ncon] for g in (c.geom1, c.geom2) if ground in (c.geom1, c.geom2)}
    assert touching == {ground, task.sim.geom_id("box_geom"), task.sim.geom_id("ghost")}
    assert m.geom_condim[ground] == 3 and m.geom_priority[ground] == 1  # the ground's friction decides
    settle(task, 100)
    assert float(task.sim.root_pos[0, 2]) > 0.13  # held up by the ghost


def test_self_collisions_with_kept_mjcf_contacts_is_an_error():
    with pytest.raises(ValueError, match=r"env\.asset\.selfCollisions.*keepAssetContacts"):
        make_walker(walker_cfg(asset={"selfCollisions": True}))


def test_unknown_contact_body_is_an_error():
    with pytest.raises(ValueError, match=r"env\.asset\.contactBodies: 'hand' matches no body"):
        make_walker(walker_cfg(asset={"contactBodies": ["hand"]}))


# ------------------------------------------------------------------------------------------------------ hooks
def test_a_missing_hook_fails_at_construction_naming_it():
    class NoObservations(VecTask):
        def pre_physics_step(self, actions):
            pass

        def post_physics_step(self):
            pass

    with pytest.raises(NotImplementedError, match=r"NoObservations must implement compute_observations\(\).*obs_buf"):
        make_walker(walker_cfg(), NoObservations)
