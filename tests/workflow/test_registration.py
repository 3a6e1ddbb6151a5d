"""Registering a user's VecTask subclass by name and building it through the task map and the run config."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch

from conftest import CPU_ARGS
from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.tasks import VecTask, get_task_class, isaacgym_task_map, register_task
from isaacgymenvs_mw.tasks.cartpole import Cartpole
from isaacgymenvs_mw.utils.config import compose_config, to_dict


class MirroredCartpole(Cartpole):
    """A tiny user task: Cartpole observed with the sign flipped."""

    def compute_observations(self) -> None:
        q, qd = self.sim.dof_pos, self.sim.dof_vel
        self.obs_buf[:] = -torch.stack((q[:, 0], qd[:, 0], q[:, 1], qd[:, 1]), dim=-1)


@pytest.fixture
def clean_task_map():
    saved = dict(isaacgym_task_map)
    yield isaacgym_task_map
    isaacgym_task_map.clear()
    isaacgym_task_map.update(saved)


def test_register_and_build_a_user_task(clean_task_map):
    assert "MirroredCartpole" not in clean_task_map
    returned = register_task("MirroredCartpole", MirroredCartpole)
    assert returned is MirroredCartpole
    cls = get_task_class("MirroredCartpole")
    assert cls is MirroredCartpole and get_task_class("Cartpole") is Cartpole

    cfg = compose_config(["task=Cartpole", "num_envs=4"])
    task = cls(to_dict(cfg.task), rl_device="cpu", sim_device="cpu", graphics_device_id=0, headless=True)
    assert isinstance(task, VecTask) and task.num_envs == 4
    obs = task.reset()["obs"]
    q, v = task.sim.dof_pos, task.sim.dof_vel
    np.testing.assert_array_equal(obs.numpy(), -np.stack([q[:, 0], v[:, 0], q[:, 1], v[:, 1]], axis=1))
    obs_dict, rew, reset, extras = task.step(task.zero_actions())
    q, v = task.sim.dof_pos, task.sim.dof_vel
    np.testing.assert_array_equal(obs_dict["obs"].numpy(), -np.stack([q[:, 0], v[:, 0], q[:, 1], v[:, 1]], axis=1))


def test_register_task_as_decorator(clean_task_map):
    @register_task("DecoratedCartpole")
    class DecoratedCartpole(Cartpole):
        pass

    assert DecoratedCartpole is not None and issubclass(DecoratedCartpole, Cartpole)
    assert get_task_class("DecoratedCartpole") is DecoratedCartpole
    cfg = compose_config(["task=Cartpole", "task.name=DecoratedCartpole", "num_envs=3", *CPU_ARGS])
    task = build_task(cfg)
    assert type(task) is DecoratedCartpole and task.num_envs == 3


def test_register_task_rejects_non_vectask(clean_task_map):
    with pytest.raises(TypeError, match="NotATask"):
        register_task("NotATask", dict)
    assert "NotATask" not in clean_task_map


def test_task_module_key_imports_the_users_module(clean_task_map):
    sys.modules.pop("_user_task_module", None)
    assert "ModuleCartpoleForTests" not in clean_task_map
    cfg = compose_config(["task=Cartpole", "task.name=ModuleCartpoleForTests", "task_module=_user_task_module",
                          "num_envs=3", *CPU_ARGS])
    task = build_task(cfg)
    assert type(task).__name__ == "ModuleCartpole" and task.num_envs == 3
    obs = task.reset()["obs"]
    q, v = task.sim.dof_pos, task.sim.dof_vel
    np.testing.assert_array_equal(obs.numpy(), 2.0 * np.stack([q[:, 0], v[:, 0], q[:, 1], v[:, 1]], axis=1))
