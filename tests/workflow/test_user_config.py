"""A user's --config-dir folder (utils/user_config.py): IsaacGymEnvs' whole cfg folder works as it is (its config.yaml
and its PhysX task YAMLs of tasks this project has cannot replace the project's; one line says so), and a user's own
task and train YAMLs are searched before cfg/."""

from __future__ import annotations

import os
import subprocess
import sys

from conftest import CPU_ARGS, REPO_ROOT, TESTS_DIR
from isaacgymenvs_mw.utils.user_config import is_isaacgym_task_yaml

IGE_CFG = TESTS_DIR / "data" / "isaacgymenvs_cfg"  # IsaacGymEnvs' config.yaml, task/Ant.yaml and train YAMLs


def test_isaacgym_task_yamls_are_told_from_this_projects():
    assert is_isaacgym_task_yaml(IGE_CFG / "task" / "Ant.yaml")
    assert not is_isaacgym_task_yaml(REPO_ROOT / "cfg" / "task" / "Ant.yaml")
    assert not is_isaacgym_task_yaml(IGE_CFG / "train" / "AntPPO.yaml")


def test_the_readme_isaacgymenvs_command_trains_with_isaacgymenvs_cfg_folder(tmp_path):
    """``python train.py --config-dir <IsaacGymEnvs>/cfg task=Ant train=AntPPO`` (the README's line), on the CPU with
    few envs: IsaacGymEnvs' AntPPO.yaml trains this project's Ant; its config.yaml and task/Ant.yaml are not read."""
    runs = tmp_path / "runs"
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "--config-dir", str(IGE_CFG), "task=Ant", "train=AntPPO",
           "num_envs=16", "max_iterations=1", f"runs_dir={runs}", *CPU_ARGS]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert "not read: config.yaml (the run keys are cfg/config.yaml's); the IsaacGymEnvs (PhysX) task YAMLs of Ant" \
        in out
    (run_dir,) = (runs / "Ant").iterdir()
    config = (run_dir / "config.yaml").read_text()
    assert f"yaml_dir: {REPO_ROOT / 'cfg' / 'task'}" in config  # this project's MuJoCo Ant
    assert "reward_shaper:\n        scale_value: 0.01" in config  # IsaacGymEnvs' train YAML
    assert (run_dir / "model_1.pt").is_file()
