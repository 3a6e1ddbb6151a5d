"""cfg/legged/base.yaml: the legged robots' task YAMLs state only their differences from it (Hydra `defaults:`).

The reference is the raw YAML text of the files: every key a robot file leaves out must arrive with the base's
value, every key it sets must arrive with its own, nothing else may appear, and one extra override in a robot file
must change exactly that key of the composed config."""

from __future__ import annotations

import pytest
from omegaconf import DictConfig, OmegaConf

from conftest import REPO_ROOT
from isaacgymenvs_mw.utils.config import compose_config, to_dict

BASE = OmegaConf.load(REPO_ROOT / "cfg" / "legged" / "base.yaml")
ROBOTS = ["Anymal", "Go1"]

# What isaacgymenvs_mw/tasks/legged_task.py and VecTask read from a legged robot's composed task config.
LEGGED_KEYS = [
    "name", "env.numEnvs", "env.numActions", "env.controlFrequencyInv",
    "env.episodeLength_s", "env.asset.assetFileName", "env.asset.baseBody", "env.asset.footBodies",
    "env.asset.terminateContactBodies", "env.asset.penalizeContactBodies", "env.baseInitState.pos",
    "env.baseInitState.rot", "env.defaultJointAngles", "env.control.stiffness", "env.control.damping",
    "env.control.actionScale", "env.commands.resamplingTime_s", "env.commands.linVelX", "env.commands.linVelY",
    "env.commands.yawRate", "env.obsScales.linVel", "env.obsScales.angVel", "env.obsScales.dofPos",
    "env.obsScales.dofVel", "env.rewards.trackingSigma", "env.rewards.baseHeightTarget", "env.rewards.scales",
    "sim.dt", "sim.nconmax", "sim.njmax",
]


def leaves(node, prefix: tuple[str, ...] = ()) -> dict[tuple[str, ...], object]:
    """Every scalar or list in a raw (unresolved) config, by key path; mappings are walked into."""
    if isinstance(node, DictConfig):
        out = {}
        for key in node.keys():
            if prefix == () and key == "defaults":
                continue
            out.update(leaves(node._get_node(key), (*prefix, str(key))))
        return out
    return {prefix: OmegaConf.to_container(node) if OmegaConf.is_list(node) else node._value()}


def raw_task(robot: str) -> DictConfig:
    return OmegaConf.load(REPO_ROOT / "cfg" / "task" / f"{robot}.yaml")


@pytest.mark.parametrize("robot", ROBOTS)
def test_composed_robot_has_every_key_the_legged_task_reads(robot):
    cfg = compose_config([f"task={robot}", "num_envs=8"])
    assert cfg.task_name == robot and cfg.task.name == robot
    assert cfg.train.runner.experiment_name == robot  # train: ${task}PPO still follows the robot, not the base
    task = to_dict(cfg.task)  # fails naming the key if a ??? of the base was left unset
    for dotted in LEGGED_KEYS:
        node = task
        for part in dotted.split("."):
            assert part in node, f"{robot}: {dotted} missing from the composed task config"
            node = node[part]
        assert node != "???" and node is not None, f"{robot}: {dotted} = {node!r}"
    assert task["env"]["numEnvs"] == 8


@pytest.mark.parametrize("robot", ROBOTS)
def test_robot_file_changes_only_the_keys_it_sets(robot):
    composed = leaves(compose_config([f"task={robot}"]).task)
    composed.pop(("yaml_dir",))  # recorded by the framework, in no YAML file
    own, base = leaves(raw_task(robot)), leaves(BASE)
    for path, value in own.items():
        assert composed[path] == value, f"{robot}: {'.'.join(path)}"
    # A base key the robot file does not set (at it or below it) arrives unchanged, interpolations included.
    inherited = {p: v for p, v in base.items() if not any(q[:len(p)] == p for q in own)}
    for path, value in inherited.items():
        assert value != "???", f"{robot} leaves the base's mandatory {'.'.join(path)} unset"
        assert composed[path] == value, f"{robot}: {'.'.join(path)}"
    assert set(composed) == set(own) | set(inherited), "keys from neither the robot file nor the base"
    # Joint-keyed maps are the robot's alone: a base entry would merge into them and reach joints it never named.
    task = compose_config([f"task={robot}"]).task
    for dotted in ("env.defaultJointAngles", "env.control.stiffness", "env.control.damping", "env.asset.armature"):
        assert OmegaConf.select(task, dotted) == OmegaConf.select(raw_task(robot), dotted), f"{robot}: {dotted}"
    # The files really share: most of the robot's config is the base's.
    assert len(inherited) > 3 * len(own)


def test_keys_naming_the_base_body_follow_it():
    for robot, body in (("Anymal", "base"), ("Go1", "trunk")):
        task = to_dict(compose_config([f"task={robot}"]).task)
        assert task["env"]["asset"]["terminateContactBodies"] == [body]
        assert task["task"]["randomization_params"]["actor_params"]["rigid_body_properties"]["mass"]["bodies"] == body
    task = to_dict(compose_config(["task=Go1", "task.env.asset.baseBody=FL_hip"]).task)
    assert task["env"]["asset"]["terminateContactBodies"] == ["FL_hip"]
    assert task["task"]["randomization_params"]["actor_params"]["rigid_body_properties"]["mass"]["bodies"] == "FL_hip"


def write_robot(tmp_path, name: str, text: str):
    (tmp_path / "task").mkdir()
    (tmp_path / "train").mkdir()
    (tmp_path / "task" / f"{name}.yaml").write_text(text)
    (tmp_path / "train" / f"{name}PPO.yaml").write_text((REPO_ROOT / "cfg" / "train" / "Go1PPO.yaml").read_text())
    return tmp_path


def test_one_more_key_in_a_robot_file_changes_only_that_key(tmp_path):
    text = (REPO_ROOT / "cfg" / "task" / "Go1.yaml").read_text()
    assert "resetRootVelocityRange" not in text and text.count("\nenv:\n") == 1  # a key Go1 inherits
    folder = write_robot(tmp_path, "MyGo1", text.replace("\nenv:\n", "\nenv:\n  resetRootVelocityRange: 0.25\n"))
    stock = leaves(compose_config(["task=Go1"]).task)
    mine = leaves(compose_config(["task=MyGo1"], config_dir=folder).task)
    changed = {p for p in stock.keys() | mine.keys() if stock.get(p) != mine.get(p)}
    assert changed == {("env", "resetRootVelocityRange"), ("yaml_dir",)}
    assert mine[("env", "resetRootVelocityRange")] == 0.25 and stock[("env", "resetRootVelocityRange")] == 0.5


def test_robot_missing_a_mandatory_key_fails_naming_it(tmp_path):
    text = (REPO_ROOT / "cfg" / "task" / "Go1.yaml").read_text()
    lines = [line for line in text.splitlines() if "assetFileName" not in line]
    folder = write_robot(tmp_path, "NoAsset", "\n".join(lines))
    cfg = compose_config(["task=NoAsset"], config_dir=folder)
    with pytest.raises(ValueError, match=r"task\.env\.asset\.assetFileName has no value"):
        to_dict(cfg.task)


def test_the_base_is_not_a_task():
    with pytest.raises(Exception) as info:
        compose_config(["task=base"])
    msg = str(info.value)
    assert "task/base" in msg and "Anymal" in msg and "Go1" in msg


TERRAIN = OmegaConf.load(REPO_ROOT / "cfg" / "legged" / "terrain.yaml")


@pytest.mark.parametrize("task_name, robot", [("AnymalTerrain", "Anymal"), ("Go1Terrain", "Go1"),
                                              ("G1Terrain", "G1")])
def test_terrain_task_is_its_robot_then_the_shared_terrain_then_its_own_keys(task_name, robot):
    composed = leaves(compose_config([f"task={task_name}"]).task)
    flat = leaves(compose_config([f"task={robot}"]).task)
    terrain, own = leaves(TERRAIN), leaves(raw_task(task_name))
    for path, value in own.items():
        assert composed[path] == value, f"{task_name}: {'.'.join(path)}"
    for path, value in terrain.items():
        if path not in own:
            assert composed[path] == value, f"{task_name}: {'.'.join(path)} is not the shared terrain's"
    later = set(terrain) | set(own)
    # A robot's null (a feature off, e.g. penaltyCurriculum) that the terrain setup replaces with a mapping
    replaced = {path for path in flat if any(p[:len(path)] == path and p != path for p in later)}
    assert all(flat[path] is None for path in replaced), f"{task_name}: a robot's value became a mapping"
    for path, value in flat.items():
        if path not in later and path not in replaced and path != ("name",):
            assert composed[path] == value, f"{task_name}: {'.'.join(path)} is not {robot}'s"
    assert set(composed) == (set(flat) - replaced) | later
    assert composed[("env", "terrain", "type")] == "heightfield"


def test_the_terrain_setup_is_not_a_task():
    with pytest.raises(Exception) as info:
        compose_config(["task=terrain"])
    assert "task/terrain" in str(info.value) and "AnymalTerrain" in str(info.value)
