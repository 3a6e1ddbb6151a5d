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
              "gear", "ctrlRange"}


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
