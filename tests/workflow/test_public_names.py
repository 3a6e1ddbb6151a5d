"""VecTask's public names never break a task that assigns the same name (tasks/base/public_names.py, issue 74).

A task's own attribute wins over a read-only fact of VecTask, with one warning line; buffers take an assignment into
the framework's tensor; replacing an object the step runs on stops construction with one line. And a task written
against the older public API (tests/data/outside_task) trains and evaluates through the outside-task path."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings

import pytest
import torch

import isaacgymenvs_mw
from conftest import CPU_ARGS, REPO_ROOT, TESTS_DIR
from isaacgymenvs_mw.tasks import isaacgym_task_map
from isaacgymenvs_mw.tasks.base.public_names import FRAMEWORK_OBJECTS, overridable_names
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.tasks.cartpole import Cartpole
from isaacgymenvs_mw.utils.errors import ConfigError

# Names a port plausibly keeps of its own that are not VecTask's (yet): they must stay plain attributes.
PORT_NAMES = ["step_count", "num_steps", "env_steps_count", "frame_count", "episode_count", "successes",
              "consecutive_successes"]


def _sentinel(name: str) -> object:
    return ("own", name)


class EveryNameCartpole(Cartpole):
    """Cartpole that, after VecTask's constructor, assigns every overridable public name and the port-style names,
    and counts its own env steps under ``env_steps`` in its step."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        for name in overridable_names(VecTask):
            setattr(self, name, _sentinel(name))
        for name in PORT_NAMES:
            setattr(self, name, _sentinel(name))
        self.extras = {"own": 1}  # IsaacGymEnvs' VecTask made it a fresh dict too: the step's entries join it
        self.env_steps = torch.zeros((), dtype=torch.float64, device=self.device)

    def compute_reward(self):
        super().compute_reward()
        self.env_steps += 1.0  # its own counter: one per step, not num_envs per step


def _make(cls, num_envs=3):
    """Build ``cls`` with Cartpole's YAML, as make() builds a registered task."""
    saved = isaacgym_task_map.get("Cartpole")
    isaacgym_task_map["Cartpole"] = cls
    try:
        return isaacgymenvs_mw.make("Cartpole", num_envs=num_envs, sim_device="cpu", rl_device="cpu")
    finally:
        isaacgym_task_map["Cartpole"] = saved


def test_the_overridable_names_are_vec_tasks_read_only_facts():
    names = set(overridable_names(VecTask))
    # the IsaacGymEnvs surface's read-only facts and VecTask's own counter, checked by name: a new public fact
    # added as a plain property would be missing here and break a task that assigns it
    assert {"env_steps", "num_obs", "num_observations", "num_states", "num_acts", "num_environments", "obs_space",
            "state_space", "act_space", "observation_space", "action_space", "control_steps",
            "total_train_env_frames", "device_type", "device_id", "sim_initialized", "step_execution"} <= names
    plain_properties = [name for klass in VecTask.__mro__ for name, v in vars(klass).items()
                        if isinstance(v, property) and v.fset is None]
    assert plain_properties == [], f"read-only properties a task cannot assign: {plain_properties}"


def test_a_task_that_assigns_every_public_name_builds_steps_and_resets():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        task = _make(EveryNameCartpole)
    warned = "\n".join(str(w.message) for w in caught)
    for name in overridable_names(VecTask):
        assert f"sets its own `{name}`" in warned, name
    for name in PORT_NAMES:
        assert f"`{name}`" not in warned, name
    assert "env_steps` (The run's env steps so far over this process's envs" in warned

    obs = task.reset()["obs"]
    assert obs.shape == (3, 4)
    for _ in range(5):
        obs_dict, rew, reset, extras = task.step(torch.full((3, 1), 0.3))
    obs = obs_dict["obs"]
    assert obs.shape == (3, 4) and torch.isfinite(obs).all() and rew.shape == (3,)
    # the task reads its own values; the framework's counter goes on (5 steps x 3 envs)
    assert float(task.env_steps) == 5.0
    assert int(VecTask.env_steps.framework_value(task)) == 15
    assert VecTask.total_train_env_frames.framework_value(task) == 15
    assert task.num_obs == _sentinel("num_obs") and task.step_count == _sentinel("step_count")
    assert task.execution.steps == 5 and extras["own"] == 1 and "time_outs" in extras
    # a reset of some envs still runs through the framework's episode
    task.reset_buf[:] = torch.tensor([1, 0, 1])
    task.reset_done()
    assert task.progress_buf.tolist() == [0, 5, 0]


def test_an_assigned_observation_buffer_is_copied_into_the_framework_buffer():
    task = _make(Cartpole)
    task.reset()
    buffer = task.observations.obs_buf
    task.obs_buf = torch.arange(12.0).reshape(3, 4)
    assert task.obs_buf is buffer and buffer[2, 3] == 11.0
    with pytest.raises(ConfigError, match=r"^Cartpole: self.obs_buf = a \(3, 5\) value, but the buffer is \(3, 4\)"):
        task.obs_buf = torch.zeros(3, 5)


@pytest.mark.parametrize("name", sorted(FRAMEWORK_OBJECTS))
def test_replacing_an_object_the_step_runs_on_is_one_line(name):
    class Replacing(Cartpole):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            setattr(self, name, 0)

    with pytest.raises(ConfigError) as err:
        _make(Replacing)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"Replacing sets self.{name} = int, but VecTask uses self.{name}")
    assert "rename the task's attribute" in message


def test_a_subclass_of_a_subclass_is_checked_once_after_the_outermost_constructor():
    class Outer(EveryNameCartpole):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.metrics = "mine"  # after the inner constructor's check: only the outermost one can see it

    with pytest.raises(ConfigError, match="Outer sets self.metrics = str"):
        _make(Outer)


FIXTURE = TESTS_DIR / "data" / "outside_task"


def test_a_task_written_against_the_older_api_trains_and_evaluates(tmp_path):
    """The compatibility fixture, only through the documented outside-task path: its own module on PYTHONPATH,
    ``task_module=``, its YAMLs through ``--config-dir``; 3 iterations, then test mode on the kept checkpoint."""
    runs = tmp_path / "runs"
    env = {**os.environ, "PYTHONPATH": str(FIXTURE), "OMP_NUM_THREADS": "1"}
    common = [sys.executable, str(REPO_ROOT / "train.py"), "--config-dir", str(FIXTURE / "cfg"), "task=LegacyWalker",
              "task_module=legacy_walker_task", "num_envs=4", f"runs_dir={runs}", *CPU_ARGS]
    proc = subprocess.run([*common, "max_iterations=3"], cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "LegacyWalker sets its own `env_steps`" in proc.stderr
    (run_dir,) = (runs / "LegacyWalker").iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["iterations"] == 3 and summary["env_steps"] == 3 * 4 * 4

    proc = subprocess.run([*common, "test=True", f"checkpoint={run_dir / 'model_3.pt'}"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    evaluation = json.loads((run_dir / "eval.json").read_text())
    assert evaluation["episodes"] == 4
    # the task's own counter ran (its fade-in paid a share of the torso height, which starts at 0.6 m): a positive
    # episode reward below 19 steps of a torso that never rose above 0.7 m
    assert 0.0 < evaluation["mean_episode_reward"] < 19 * 0.7
