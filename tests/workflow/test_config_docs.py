"""docs/config.md documents every key of cfg/config.yaml, cfg/task/*.yaml and cfg/train/*.yaml (DESIGN: every key
has a default in YAML, documented in docs/config.md). A key added to a YAML file without a line in the docs fails."""

from __future__ import annotations

import re

import pytest
from omegaconf import DictConfig, OmegaConf

from conftest import REPO_ROOT

DOCS = REPO_ROOT / "docs" / "config.md"
YAML_FILES = sorted((REPO_ROOT / "cfg").rglob("*.yaml"))
# Mappings whose keys are the user's choice (joint names or patterns), not configuration keys.
USER_KEYED = {"defaultJointAngles", "driveMode", "stiffness", "damping", "armature", "jointDamping", "effortLimit",
              "gear", "ctrlRange", "velocityClamp"}


def key_paths(node: DictConfig, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    paths = []
    for key in node.keys():
        if prefix == () and key == "defaults":
            continue  # Hydra's defaults list: documented as `defaults: task` / `defaults: train`
        path = (*prefix, str(key))
        child = node._get_node(key)
        if isinstance(child, DictConfig) and str(key) not in USER_KEYED:
            paths += key_paths(child, path)
        else:
            paths.append(path)
    return paths


def documented_names(text: str) -> set[str]:
    """Every backticked name in the docs, and each dotted suffix of it (`env.rewards.upright` -> `upright`, ...)."""
    names = set()
    for token in re.findall(r"`([A-Za-z_][\w.]*)", text):
        parts = token.split(".")
        names.update(".".join(parts[i:]) for i in range(len(parts)))
    return names


@pytest.mark.parametrize("yaml_file", YAML_FILES, ids=lambda p: str(p.relative_to(REPO_ROOT / "cfg")))
def test_every_yaml_key_is_in_the_config_reference(yaml_file):
    names = documented_names(DOCS.read_text())
    cfg = OmegaConf.load(yaml_file)
    missing = []
    for path in key_paths(cfg):
        # the key is documented by its own name or by a dotted path ending in it (`observationNoise.enabled`)
        suffixes = {".".join(path[i:]) for i in range(len(path))}
        if not suffixes & names:
            missing.append(".".join(path))
    assert not missing, f"{yaml_file.name}: keys missing from docs/config.md: {missing}"


def test_the_check_sees_nested_keys():
    cfg = OmegaConf.create({"env": {"rewards": {"scales": {"no_such_term_anywhere": 1.0}},
                                    "defaultJointAngles": {"HAA": 0.0}}})
    paths = key_paths(cfg)
    assert ("env", "rewards", "scales", "no_such_term_anywhere") in paths
    assert ("env", "defaultJointAngles") in paths
    assert "no_such_term_anywhere" not in documented_names(DOCS.read_text())


# ---------------------------------------------------------------- regex keys with brackets on the command line
PORTING = REPO_ROOT / "docs" / "porting.md"
BRACKETS = "### Regex keys with brackets on the command line"


def documented_override_lines() -> list[list[str]]:
    """The command lines of porting.md's section on bracketed keys, split as a POSIX shell hands them to train.py."""
    import shlex

    section = PORTING.read_text().split(BRACKETS, 1)[1].split("\n### ", 1)[0]
    block = re.search(r"```\n(.*?)```", section, re.S).group(1)
    return [shlex.split(line.strip()) for line in block.strip().splitlines()]


def test_documented_bracket_override_parses_where_the_quoted_key_does_not():
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    parser = OverridesParser.create()
    (first, _) = documented_override_lines()
    assert first[:3] == ["python", "train.py", "task=MyTask"]
    override = parser.parse_override(first[3])
    assert override.key_or_group == "task.env.control.damping" and override.is_add()
    assert override.value() == {"lower_leg_joint[0-2]": 2.0}
    # The form the docs warn about: Hydra's grammar takes no quoted mapping key.
    with pytest.raises(HydraException, match="no viable alternative"):
        parser.parse_override("""task.env.control.damping={"lower_leg_joint[0-2]":2.0}""")
    assert "'task.env.control.damping={\"lower_leg_joint[0-2]\":2.0}'" in PORTING.read_text()


def test_documented_override_reaches_the_joint_table():
    """The Anymal line of the docs, composed as train.py composes it, gives 60 to every HFE and KFE joint's drive and
    leaves the HAA joints at 80; the bracketed key also selects joints by the project's one name rule."""
    from isaacgymenvs_mw.sim import request_from_config
    from isaacgymenvs_mw.sim.joint_tables import match_joint_numbers
    from isaacgymenvs_mw.tasks.base.sim_factory import ASSETS_DIR
    from isaacgymenvs_mw.utils.config import compose_config, to_dict

    (_, second) = documented_override_lines()
    assert second[:3] == ["python", "train.py", "task=Anymal"]
    task = to_dict(compose_config(second[2:]).task)
    assert list(task["env"]["control"]["stiffness"].items()) == [(".*_(HFE|KFE)", 60.0), (".*", 80.0)]
    request = request_from_config(task["env"], task.get("sim", {}), task.get("yaml_dir"), ASSETS_DIR)
    kp = {joint: drive.stiffness for joint, drive in request.drives.items()}
    assert len(kp) == 12
    assert all(v == (60.0 if joint.endswith(("_HFE", "_KFE")) else 80.0) for joint, v in kp.items()), kp
    # Added with "+" alone, the pattern comes after the YAML's '.*', which selects every joint first: no effect.
    added = to_dict(compose_config(["task=Anymal", second[-1].replace(",.*:80.0", "")]).task)
    request = request_from_config(added["env"], added.get("sim", {}), added.get("yaml_dir"), ASSETS_DIR)
    assert {drive.stiffness for drive in request.drives.values()} == {80.0}

    joints = ["lower_leg_joint0", "lower_leg_joint1", "lower_leg_joint2", "upper_leg_joint0"]
    table = match_joint_numbers({"lower_leg_joint[0-2]": 2.0}, joints, "env.control.damping", default=0.0)
    assert table == {"lower_leg_joint0": 2.0, "lower_leg_joint1": 2.0, "lower_leg_joint2": 2.0,
                     "upper_leg_joint0": 0.0}
