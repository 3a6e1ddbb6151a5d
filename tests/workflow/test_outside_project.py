"""A project outside the repository: its task module, MJCF asset and YAML files all live in a temporary folder.
train.py trains it through --config-dir (from yet another working directory), test mode evaluates the checkpoint,
and isaacgymenvs_mw.make(config_dir=...) builds it; its relative assetRoot resolves against its task YAML's folder."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap

import pytest
import torch

import isaacgymenvs_mw
from conftest import CPU_ARGS, REPO_ROOT, TESTS_DIR
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.tasks import isaacgym_task_map
from isaacgymenvs_mw.utils.config import compose_config

MODULE = "outside_walker_tasks"

TASK_MODULE = '''
import torch

from isaacgymenvs_mw.tasks import register_task
from isaacgymenvs_mw.tasks.base.vec_task import VecTask


class OutsideWalker(VecTask):
    """Keep the torso up with the walker's own hip motors; observation = torso height and the joint state."""

    def pre_physics_step(self, actions):
        self.sim.ctrl[:] = actions

    def post_physics_step(self):
        self.progress_buf += 1
        self.rew_buf[:] = self.sim.root_pos[:, 2]
        self.reset_buf[:] = (self.progress_buf >= self.max_episode_length - 1).long()
        self.reset_idx(self.reset_buf != 0)
        self.compute_observations()

    def reset_idx(self, env_ids):
        mask = self.env_mask(env_ids)
        self.sim.reset_worlds(mask)
        self.sim.refresh_kinematics()
        self.progress_buf.masked_fill_(mask, 0)

    def compute_observations(self):
        self.obs_buf[:] = torch.cat((self.sim.root_pos[:, 2:3], self.sim.dof_pos, self.sim.dof_vel), dim=-1)


register_task("OutsideWalker", OutsideWalker)
'''

TASK_YAML = '''
name: OutsideWalker
physics_engine: mujoco_warp
env:
  numEnvs: ${resolve_default:4,${...num_envs}}
  numObservations: 7
  numActions: 2
  controlFrequencyInv: 2
  episodeLength_s: 0.2          # 20 policy steps of 2 x 0.005 s
  asset:
    assetRoot: ../../assets      # relative to this file's folder (cfg/task/)
    assetFileName: walker.xml
    fixBaseLink: False
    contactBodies: [left_foot, right_foot]
  plane:
    enabled: True
sim:
  dt: 0.005
  nconmax: 16
  njmax: 64
'''


@pytest.fixture
def project(tmp_path):
    root = tmp_path / "project"
    (root / "cfg" / "task").mkdir(parents=True)
    (root / "cfg" / "train").mkdir(parents=True)
    (root / "assets").mkdir()
    shutil.copy(TESTS_DIR / "assets" / "walker.xml", root / "assets" / "walker.xml")
    (root / f"{MODULE}.py").write_text(textwrap.dedent(TASK_MODULE))
    (root / "cfg" / "task" / "OutsideWalker.yaml").write_text(TASK_YAML)
    train = (REPO_ROOT / "cfg" / "train" / "PendulumPPO.yaml").read_text()
    train = train.replace("num_steps_per_env: 16", "num_steps_per_env: 4").replace("Pendulum", "OutsideWalker")
    (root / "cfg" / "train" / "OutsideWalkerPPO.yaml").write_text(train)
    sys.path.insert(0, str(root))
    saved = dict(isaacgym_task_map)
    yield root
    sys.path.remove(str(root))
    sys.modules.pop(MODULE, None)
    isaacgym_task_map.clear()
    isaacgym_task_map.update(saved)


def test_train_test_and_make_a_project_outside_the_repository(project, tmp_path, monkeypatch):
    workdir = tmp_path / "elsewhere"  # neither the repository nor the project: nothing resolves against it
    workdir.mkdir()
    runs = tmp_path / "runs"
    args = ["task=OutsideWalker", f"task_module={MODULE}", "num_envs=4", f"runs_dir={runs}", *CPU_ARGS]
    env = {**os.environ, "PYTHONPATH": str(project), "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "--config-dir", str(project / "cfg"), *args,
           "max_iterations=1"]
    proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    (run_dir,) = (runs / "OutsideWalker").iterdir()
    assert json.loads((run_dir / "summary.json").read_text())["iterations"] == 1
    saved_cfg = (run_dir / "config.yaml").read_text()
    assert f"yaml_dir: {project / 'cfg' / 'task'}" in saved_cfg  # where the relative assetRoot was resolved

    # test mode, composed the way make() composes (config_dir instead of --config-dir)
    monkeypatch.chdir(workdir)
    cfg = compose_config([*args, "test=True", f"checkpoint={run_dir / 'model_1.pt'}"], config_dir=project / "cfg")
    result = run(cfg)
    assert result["episodes"] == 4 and (run_dir / "eval.json").is_file()

    task = isaacgymenvs_mw.make("OutsideWalker", num_envs=3, sim_device="cpu", rl_device="cpu",
                                overrides=[f"task_module={MODULE}"], config_dir=project / "cfg")
    assert type(task).__module__ == MODULE and task.num_envs == 3
    assert task.sim.actuator_names == ["right_hip_motor", "left_hip_motor"]
    assert list(task.sim.sensors.get("contact_forces").bodies) == ["left_foot", "right_foot"]
    obs = task.reset()["obs"]
    torch.testing.assert_close(obs[:, 0], torch.full((3,), 0.6))  # the MJCF torso's own start height


def test_a_missing_relative_asset_names_how_it_was_resolved(project):
    yaml = project / "cfg" / "task" / "OutsideWalker.yaml"
    yaml.write_text(TASK_YAML.replace("../../assets", "../assets"))
    with pytest.raises(FileNotFoundError, match=r"resolved against the task YAML's folder .*cfg/task"):
        isaacgymenvs_mw.make("OutsideWalker", num_envs=2, sim_device="cpu", rl_device="cpu",
                             overrides=[f"task_module={MODULE}"], config_dir=project / "cfg")


def test_config_dir_that_does_not_exist_is_an_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="config_dir"):
        compose_config(["task=Cartpole"], config_dir=tmp_path / "nope")


def test_pendulum_with_a_wrong_num_actions_fails_at_construction():
    """The README's claim: a size mismatch fails. numActions=3 against the Pendulum's one hinge motor."""
    if str(REPO_ROOT) not in sys.path:
        sys.path.insert(0, str(REPO_ROOT))
    with pytest.raises(ValueError, match=r"env\.numActions=3 but the model has 1 actuators.*hinge"):
        isaacgymenvs_mw.make("Pendulum", num_envs=2, sim_device="cpu", rl_device="cpu",
                             overrides=["task_module=examples.pendulum_task", "task.env.numActions=3"])


def test_task_module_from_a_users_script_is_found_in_the_current_folder(tmp_path):
    """A script elsewhere calling make(overrides=["task_module=examples.pendulum_task"]) from the repository's folder:
    Python puts the script's folder on the path, not the current one, which task_module= looks in too (last); from
    a folder without it, one line names where it looked."""
    script = tmp_path / "my_script.py"
    script.write_text("import isaacgymenvs_mw\n"
                      "from isaacgymenvs_mw.utils.errors import ConfigError\n"
                      "try:\n"
                      "    t = isaacgymenvs_mw.make('Pendulum', num_envs=2, sim_device='cpu', rl_device='cpu',\n"
                      "                             overrides=['task_module=examples.pendulum_task'])\n"
                      "    print('built', type(t).__module__)\n"
                      "except ConfigError as err:\n"
                      "    print('error', err)\n")
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    found = subprocess.run([sys.executable, str(script)], cwd=REPO_ROOT, capture_output=True, text=True, timeout=300,
                           env=env)
    assert "built examples.pendulum_task" in found.stdout, found.stdout + found.stderr[-2000:]
    missing = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                             timeout=300, env=env)
    assert (f"error task_module='examples.pendulum_task': no module 'examples' in the script's folder ({tmp_path}), "
            f"the current folder ({tmp_path}) or PYTHONPATH") in missing.stdout, missing.stdout + missing.stderr[-2000:]
