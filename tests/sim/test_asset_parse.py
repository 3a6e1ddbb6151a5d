"""Parsing asset files (sim/asset_parse.py): a URDF joint with lower == upper is locked, as IsaacGym treats it (MuJoCo's
URDF importer alone leaves it free), and a file MuJoCo's parser refuses is one line naming the file."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from isaacgymenvs_mw.sim.asset_loading import load_spec
from isaacgymenvs_mw.utils.errors import ConfigError

INERTIAL = ('<inertial><origin xyz="0.2 0 0"/><mass value="1"/>'
            '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>')


def _urdf(lower: float, upper: float) -> str:
    """A base on a hinge about z and an arm on a hinge about y with the given limits: gravity swings the arm unless
    its joint is locked."""
    return f'''<robot name="lock">
  <link name="world"/>
  <link name="base">{INERTIAL}</link>
  <link name="arm">{INERTIAL}</link>
  <joint name="to_base" type="fixed"><parent link="world"/><child link="base"/></joint>
  <joint name="elbow" type="revolute"><parent link="base"/><child link="arm"/><origin xyz="0.1 0 1"/>
    <axis xyz="0 1 0"/><limit lower="{lower}" upper="{upper}" effort="1" velocity="1"/></joint>
</robot>'''


def _arm_drop(tmp_path, lower, upper) -> tuple[list[str], float]:
    path = tmp_path / "lock.urdf"
    path.write_text(_urdf(lower, upper))
    spec = load_spec(path, collapse_fixed_joints=False)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    start = data.xipos[model.body("arm").id].copy()
    for _ in range(200):
        mujoco.mj_step(model, data)
    return [j.name for j in spec.joints], float(np.linalg.norm(data.xipos[model.body("arm").id] - start))


def test_a_urdf_joint_with_equal_limits_is_locked(tmp_path):
    joints, moved = _arm_drop(tmp_path, 0.0, 0.0)
    assert joints == [] and moved < 1e-9  # welded: gravity does not swing the arm


def test_a_urdf_joint_with_a_range_stays_a_joint(tmp_path):
    joints, moved = _arm_drop(tmp_path, -1.5, 1.5)
    assert joints == ["elbow"] and moved > 0.01  # the same arm swings under gravity


def test_a_file_mujoco_cannot_parse_is_one_line(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><bodyy/></worldbody></mujoco>")
    with pytest.raises(ConfigError) as err:
        load_spec(bad)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"env.asset: MuJoCo cannot load '{bad}': ")
    assert message.endswith("(fix the file, or give another with env.asset.assetFileName)")


@pytest.mark.parametrize("xml, phrase, hint", [
    ('<mujoco><worldbody><body><joint name="a"/><joint name="a"/><geom size=".1"/></body></worldbody></mujoco>',
     "repeated name 'a' in joint", "give each element its own name in the asset"),
])
def test_a_repeated_name_is_one_line_with_what_to_do(tmp_path, xml, phrase, hint):
    path = tmp_path / "dup.xml"
    path.write_text(xml)
    with pytest.raises(ConfigError) as err:
        load_spec(path)
    message = str(err.value)
    assert "\n" not in message and phrase in message and message.endswith(f"({hint})")


@pytest.mark.parametrize("xml, phrase, hint", [
    # a root body with its own joints beside a free joint (what a floating base adds to such an asset)
    ('<mujoco><worldbody><body><freejoint/><joint type="hinge"/><geom size=".1"/></body></worldbody></mujoco>',
     "more than 6 dofs in body", "set env.asset.fixBaseLink: True or remove them"),
    ('<mujoco><asset><mesh name="m" file="{tmp}/nope.stl"/></asset><worldbody><body><geom type="mesh" mesh="m"/>'
     '</body></worldbody></mujoco>', "nope.stl", "a path in the asset is relative to the asset's folder"),
])
def test_mujoco_compile_errors_are_one_line_naming_the_asset(tmp_path, xml, phrase, hint):
    from isaacgymenvs_mw.sim.asset_parse import compile_error

    spec = mujoco.MjSpec.from_string(xml.replace("{tmp}", str(tmp_path)))
    with pytest.raises(ValueError) as raised:
        spec.compile()
    message = str(compile_error(raised.value, tmp_path / "robot.xml"))
    assert "\n" not in message and message.startswith(f"MuJoCo cannot compile the model of '{tmp_path / 'robot.xml'}'")
    assert phrase in message and hint in message


def _cartpole_with_tip(tmp_path, collapse: bool):
    """The repository's cart-pole URDF plus a link on a fixed joint at the pole's top, as a port's marker body."""
    import isaacgymenvs_mw
    from conftest import REPO_ROOT

    text = (REPO_ROOT / "assets" / "urdf" / "cartpole.urdf").read_text()
    tip = ('<link name="pole_tip"><inertial><mass value="0.01"/><inertia ixx="1e-5" iyy="1e-5" izz="1e-5" ixy="0" '
           'ixz="0" iyz="0"/></inertial></link><joint name="pole_to_tip" type="fixed"><parent link="pole"/>'
           '<child link="pole_tip"/><origin xyz="0 0 1"/></joint></robot>')
    (tmp_path / "tip.urdf").write_text(text.replace("</robot>", tip))
    overrides = [f"task.env.asset.assetRoot={tmp_path}", "task.env.asset.assetFileName=tip.urdf",
                 f"task.env.asset.collapseFixedJoints={collapse}"]
    return isaacgymenvs_mw.make("Cartpole", num_envs=2, sim_device="cpu", rl_device="cpu", overrides=overrides)


def test_a_body_that_collapse_fixed_joints_merged_is_named_with_the_setting(tmp_path):
    import torch

    task = _cartpole_with_tip(tmp_path, collapse=True)
    with pytest.raises(ValueError) as err:
        task.apply_body_forces(torch.zeros(2, 1, 3), bodies=["pole_tip"])
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith("bodies: body 'pole_tip' was merged into 'pole' by "
                              "task.env.asset.collapseFixedJoints=True"), message
    with pytest.raises(ValueError, match=r"^bodies: no body named 'pole_top'; valid: "):  # a plain typo stays plain
        task.apply_body_forces(torch.zeros(2, 1, 3), bodies=["pole_top"])
    # with the setting off the body is there, and a force on it is taken
    kept = _cartpole_with_tip(tmp_path, collapse=False)
    assert "pole_tip" in kept.sim.body_names and not kept.sim.fused_bodies
    kept.apply_body_forces(torch.zeros(2, 1, 3), bodies=["pole_tip"])
