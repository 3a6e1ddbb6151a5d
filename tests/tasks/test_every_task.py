"""A smoke test of every task the package registers, parametrised from the task map itself (issue 72, item 4).

The names are read from ``isaacgymenvs_mw.tasks.isaacgym_task_map`` when the file is collected, so a task
registered in the package is covered without editing a list here. Only the package's own classes are taken:
tasks that tests or examples/ register at import time (Pendulum, the tests' Cartpole variants) live elsewhere.

Each task, with 2 envs on the CPU: build; reset; the observation groups have the sizes the task declares; 3 steps
of zero actions and 3 of uniform random actions in [-1, 1] return finite observations and rewards of the contract's
shapes, without a blown-up world, without a NaN/inf the step had to replace by 0, and without Python state kept in
the step (PythonStateWarning); then a forced reset of one env through the public paths (``reset_buf`` +
``reset_done()``, and ``reset_envs(indices)``) restarts that env's clock and leaves the other env as it was.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

import isaacgymenvs_mw
from isaacgymenvs_mw.tasks import isaacgym_task_map
from isaacgymenvs_mw.tasks.base.python_state import PythonStateWarning
from isaacgymenvs_mw.utils.config import compose_config

REPO_ROOT = Path(__file__).resolve().parents[2]
NUM_ENVS = 2
STEPS = 3  # of zero actions, then as many of random actions
# A terrain task builds its whole map at construction: the smallest one that still has several levels and types
# (the keys of test_behaviour_recording.SMALL_MAP), applied to whichever of them the task's terrain section has.
SMALL_TERRAIN = {"numLevels": 3, "numTerrains": 2, "maxInitLevel": 2}
IMAGE_CHANNELS = {"rgb": 3, "depth": 1}  # per camera output (ImageTerm's docstring: rgb 3 channels, depth 1)


def _package_tasks() -> dict[str, type]:
    """The task map's entries whose class the package itself defines, read now (at collection)."""
    return {name: cls for name, cls in isaacgym_task_map.items()
            if cls.__module__.split(".")[0] == "isaacgymenvs_mw"}


PACKAGE_TASKS = _package_tasks()
TASK_NAMES = sorted(PACKAGE_TASKS)


# ------------------------------------------------------------------------------------------------ helpers
def _small_overrides(name: str) -> list[str]:
    """Overrides that keep a terrain task's map small; none for other tasks."""
    terrain = compose_config([f"task={name}"]).task.env.get("terrain")
    if not terrain:
        return []
    return [f"task.env.terrain.{key}={value}" for key, value in SMALL_TERRAIN.items() if key in terrain]


def _expected_image_shape(task) -> tuple[int, int, int] | None:
    """(C, H, W) of the "camera" group from what the task declares: its image terms, the YAML's cameras (their
    size) and env.history.camera (frames stacked along channels). None when the task observes no images."""
    terms = task.image_terms()
    if not terms:
        return None
    cameras = task.cfg["env"]["cameras"]
    sizes = {(int(cameras[t.camera]["height"]), int(cameras[t.camera]["width"])) for t in terms}
    assert len(sizes) == 1, f"image terms read cameras of different sizes: {sizes}"
    (height, width), = sizes
    length = int(((task.cfg["env"].get("history") or {}).get("camera") or {}).get("length", 1))
    return sum(IMAGE_CHANNELS[t.output] for t in terms) * length, height, width


def _check_obs_dict(task, obs_dict: dict, image_shape, where: str) -> None:
    n = task.num_envs
    expected_keys = {"obs"} | ({"states"} if task.num_states > 0 else set()) | ({"camera"} if image_shape else set())
    assert set(obs_dict) == expected_keys, f"{where}: observation groups {sorted(obs_dict)}"
    obs = obs_dict["obs"]
    assert obs.shape == (n, task.num_obs), f"{where}: obs {tuple(obs.shape)} != {(n, task.num_obs)}"
    assert obs.dtype == torch.float32, f"{where}: obs dtype {obs.dtype}"
    assert torch.isfinite(obs).all(), f"{where}: non-finite obs in columns {(~torch.isfinite(obs)).any(0).nonzero()}"
    if task.num_states > 0:
        states = obs_dict["states"]
        assert states.shape == (n, *task.state_space.shape), f"{where}: states {tuple(states.shape)}"
        assert states.dtype == torch.float32, f"{where}: states dtype {states.dtype}"
        assert torch.isfinite(states).all(), f"{where}: non-finite states"
    if image_shape:
        images = obs_dict["camera"]
        assert images.shape == (n, *image_shape), f"{where}: camera {tuple(images.shape)} != {(n, *image_shape)}"
        assert images.dtype == torch.uint8, f"{where}: camera dtype {images.dtype}"


def _check_step(task, out, image_shape, where: str) -> None:
    n = task.num_envs
    assert isinstance(out, tuple) and len(out) == 4, f"{where}: step returned {type(out)}"
    obs_dict, rew, reset, extras = out
    _check_obs_dict(task, obs_dict, image_shape, where)
    assert rew.shape == (n,), f"{where}: reward shape {tuple(rew.shape)}"
    assert rew.is_floating_point() and torch.isfinite(rew).all(), f"{where}: reward {rew}"
    assert reset.shape == (n,) and not reset.is_floating_point(), f"{where}: reset {reset}"
    assert set(reset.tolist()) <= {0, 1}, f"{where}: reset values {reset.tolist()}"
    assert task.reset_buf.shape == (n,) and task.progress_buf.shape == (n,), where
    assert extras["time_outs"].shape == (n,), f"{where}: time_outs {tuple(extras['time_outs'].shape)}"
    # The step hides two failures from the checks above: a world whose state went non-finite is put back to its
    # initial state (nonfinite_buf), and a NaN/inf reward or observation is replaced by 0 before it is returned
    # (nonfinite_inputs_buf, counted over the run in nonfinite_inputs_count). Either is a failure here.
    assert not task.nonfinite_buf.any(), f"{where}: worlds {task.nonfinite_buf.nonzero().flatten().tolist()} blew up"
    assert not task.nonfinite_inputs_buf.any() and float(task.nonfinite_inputs_count) == 0, (
        f"{where}: envs {task.nonfinite_inputs_buf.nonzero().flatten().tolist()} had a NaN/inf reward or observation "
        f"(replaced by 0; {float(task.nonfinite_inputs_count):g} so far)")


def _mid_episode(task, env: int, image_shape) -> None:
    """Step (zero actions) until ``env`` is past the first step of an episode, so that a reset is visible."""
    for _ in range(3):
        if int(task.progress_buf[env]) > 0:
            return
        _check_step(task, task.step(task.zero_actions()), image_shape, f"extra step to get env {env} mid-episode")
    assert int(task.progress_buf[env]) > 0, f"env {env} restarts at every step"


def _state(task, env: int) -> tuple[np.ndarray, np.ndarray]:
    return task.sim.qpos.numpy()[env].copy(), task.sim.qvel.numpy()[env].copy()


# -------------------------------------------------------------------------------------------------- tests
def test_the_parametrisation_is_the_task_map():
    assert TASK_NAMES, "the task map holds no package task"
    assert set(TASK_NAMES) == set(_package_tasks())  # nothing registered or dropped since collection


@pytest.mark.parametrize("name", TASK_NAMES)
def test_every_task_builds_resets_steps_and_resets_one_env(name):
    # A Python number the step's hooks change (frozen once a GPU step is captured) is named by a PythonStateWarning
    # after the first steps (tasks/base/python_state.py): an error here.
    with warnings.catch_warnings():
        warnings.simplefilter("error", PythonStateWarning)
        _smoke(name)


def _smoke(name: str) -> None:
    n = NUM_ENVS
    task = isaacgymenvs_mw.make(name, num_envs=n, sim_device="cpu", rl_device="cpu", headless=True,
                                overrides=_small_overrides(name))
    assert type(task) is PACKAGE_TASKS[name]
    assert task.num_envs == n
    assert task.execution.python_state is not None  # its first steps are watched for Python state
    assert task.action_space.shape == (task.num_actions,) and task.zero_actions().shape == (n, task.num_actions)

    # The sizes the YAML gives, where it gives them (most tasks derive them from their terms).
    env_cfg = task.cfg["env"]
    history = env_cfg.get("history") or {}
    if env_cfg.get("numObservations"):
        length = int((history.get("policy") or {}).get("length", 1))
        assert task.num_obs == int(env_cfg["numObservations"]) * length
    if env_cfg.get("numStates"):
        assert task.num_states == int(env_cfg["numStates"])
    assert task.observation_space.shape == (task.num_obs,)
    if task.num_states > 0:
        length = int((history.get("critic") or {}).get("length", 1))
        assert task.state_space.shape == (task.num_states * length,)
    image_shape = _expected_image_shape(task)

    _check_obs_dict(task, task.reset(), image_shape, "reset()")
    assert torch.equal(task.progress_buf, torch.zeros(n, dtype=task.progress_buf.dtype))

    gen = torch.Generator().manual_seed(0)
    actions = [task.zero_actions() for _ in range(STEPS)]
    actions += [torch.rand(n, task.num_actions, generator=gen) * 2 - 1 for _ in range(STEPS)]
    for k, a in enumerate(actions):
        kind = "zero" if k < STEPS else "random"
        _check_step(task, task.step(a), image_shape, f"step {k + 1} ({kind} actions)")

    # Reset env 0 through reset_buf + reset_done(): its clock restarts, env 1 is untouched.
    def reset_env_0() -> None:
        task.reset_buf.zero_()
        task.reset_buf[0] = 1
        obs_dict, ids = task.reset_done()
        assert ids.tolist() == [0]
        _check_obs_dict(task, obs_dict, image_shape, "reset_done()")

    _reset_one_env(task, 0, reset_env_0, image_shape, "reset_done() of env 0")
    # ...and env 1 through reset_envs with IsaacGymEnvs' index tensor, after one more step.
    _check_step(task, task.step(task.zero_actions()), image_shape, "step after reset_done()")
    _reset_one_env(task, 1, lambda: task.reset_envs(torch.tensor([1])), image_shape, "reset_envs([1])")
    _check_step(task, task.step(task.zero_actions()), image_shape, "step after reset_envs()")


def _reset_one_env(task, env: int, reset, image_shape, how: str) -> None:
    """Both envs mid-episode, then ``reset()`` of ``env``: its clock restarts, the other env's clock and state stay."""
    other = 1 - env
    _mid_episode(task, 0, image_shape)
    _mid_episode(task, 1, image_shape)
    progress = task.progress_buf.clone()
    q_before, v_before = _state(task, other)
    reset()
    assert int(task.progress_buf[env]) == 0
    assert int(task.progress_buf[other]) == int(progress[other])
    q, v = _state(task, other)
    np.testing.assert_array_equal(q, q_before, err_msg=f"{how} moved env {other}")
    np.testing.assert_array_equal(v, v_before, err_msg=f"{how} moved env {other}")


# Registered in a fresh interpreter: the package's task map as imported, then what each examples/ module that
# calls register_task adds (the example tasks, e.g. the README's Pendulum, are not the package's).
_REGISTRATIONS = """
import importlib, json, pathlib
from isaacgymenvs_mw.tasks import isaacgym_task_map as task_map
package = sorted(task_map)
examples = {}
for path in sorted(pathlib.Path("examples").glob("*.py")):
    if "register_task(" in path.read_text():
        module = importlib.import_module("examples." + path.stem)
        examples.update({k: module.__name__ for k, v in task_map.items() if v.__module__ == module.__name__})
print("REGISTRATIONS " + json.dumps({"package": package, "examples": examples}))
"""


def test_the_task_map_and_the_task_yamls_agree():
    out = subprocess.run([sys.executable, "-c", _REGISTRATIONS], cwd=REPO_ROOT, capture_output=True, text=True,
                         timeout=120, check=False)
    assert out.returncode == 0, out.stderr[-3000:]
    (line,) = [ln for ln in out.stdout.splitlines() if ln.startswith("REGISTRATIONS ")]
    registered = json.loads(line.split(" ", 1)[1])
    package, examples = set(registered["package"]), registered["examples"]
    # A fresh import registers exactly the package tasks this file is parametrised over.
    assert package == set(TASK_NAMES)

    yaml_names = {}
    for path in sorted((REPO_ROOT / "cfg" / "task").glob("*.yaml")):
        name = yaml.safe_load(path.read_text()).get("name")
        assert name == path.stem, f"{path.name} names its task {name!r}: task=<file name> would not find it"
        yaml_names[name] = path
    # Every registered task has its YAML; every YAML's task is registered by the package or by an example module.
    assert package <= set(yaml_names), f"registered without cfg/task/<name>.yaml: {sorted(package - set(yaml_names))}"
    assert set(yaml_names) == package | set(examples), (
        f"cfg/task YAMLs of no registered task: {sorted(set(yaml_names) - package - set(examples))}")
    assert not package & set(examples), f"example modules re-register package tasks: {sorted(package & set(examples))}"
