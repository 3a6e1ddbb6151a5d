"""Misspelt keys inside a task YAML are one line naming the file, the key as typed and the key meant
(utils/task_keys.py): an error for a task of this project, a warning for a user's own task, whose code may read it."""

from __future__ import annotations

import warnings

import pytest
import yaml

import isaacgymenvs_mw
from conftest import REPO_ROOT
from isaacgymenvs_mw.utils.config import CFG_DIR, compose_config
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.task_keys import misspelt_keys

CARTPOLE = (REPO_ROOT / "cfg" / "task" / "Cartpole.yaml").read_text()


@pytest.mark.parametrize("task", sorted(p.stem for p in (REPO_ROOT / "cfg" / "task").glob("*.yaml")))
def test_no_shipped_task_yaml_has_a_key_taken_for_a_typo(task):
    from omegaconf import OmegaConf

    cfg = compose_config([f"task={task}"])
    assert misspelt_keys(OmegaConf.to_container(cfg.task, resolve=False), CFG_DIR) == []


@pytest.mark.parametrize("typed, meant, spot", [
    ("resetDst", "resetDist", "  resetDist:"),            # a task key: the task would raise a KeyError
    ("maxEfort", "maxEffort", "  maxEffort:"),
    ("clipAction", "clipActions", "  clipActions:"),      # a framework key: silently left at its default
])
def test_a_misspelt_key_in_a_copy_of_a_shipped_task_yaml_is_one_line(tmp_path, typed, meant, spot):
    assert spot in CARTPOLE, spot
    (tmp_path / "task").mkdir()
    (tmp_path / "task" / "Cartpole.yaml").write_text(CARTPOLE.replace(spot, f"  {typed}:"))
    with pytest.raises(ConfigError) as err:
        compose_config(["task=Cartpole"], config_dir=tmp_path)
    assert str(err.value) == (f"{tmp_path / 'task' / 'Cartpole.yaml'}: task.env.{typed} (did you mean "
                              f"task.env.{meant}?): no such key is read by task Cartpole (docs/config.md lists its keys)")


def test_a_framework_key_misspelt_in_a_users_own_task_yaml_is_a_warning(tmp_path):
    data = yaml.safe_load(CARTPOLE)
    data["name"] = "MyCartpole"
    data["env"]["defaultDriveMod"] = "effort"
    data["env"]["myOwnGain"] = 3.0  # the user's own key, spelt like nothing known: no word
    (tmp_path / "task").mkdir()
    (tmp_path / "task" / "MyCartpole.yaml").write_text(yaml.safe_dump(data))
    (tmp_path / "train").mkdir()
    (tmp_path / "train" / "MyCartpolePPO.yaml").write_text((REPO_ROOT / "cfg/train/CartpolePPO.yaml").read_text())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        compose_config(["task=MyCartpole"], config_dir=tmp_path)
    lines = [str(w.message) for w in caught if "did you mean" in str(w.message)]
    assert lines == [f"{tmp_path / 'task' / 'MyCartpole.yaml'}: task.env.defaultDriveMod (did you mean "
                     "task.env.defaultDriveMode?): not a key of the framework's; if your task reads it, ignore this"]


def test_make_refuses_the_typo_too(tmp_path):
    (tmp_path / "task").mkdir()
    (tmp_path / "task" / "Cartpole.yaml").write_text(CARTPOLE.replace("  resetDist:", "  resetDst:"))
    with pytest.raises(ConfigError, match=r"task\.env\.resetDst \(did you mean task\.env\.resetDist\?\)"):
        isaacgymenvs_mw.make("Cartpole", num_envs=2, sim_device="cpu", rl_device="cpu", config_dir=tmp_path)
