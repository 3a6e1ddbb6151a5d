"""Building a task from a composed config: what ``train.py`` and ``isaacgymenvs_mw.make()`` share.

It lives beside the task map, below ``learning/``: building a task needs no trainer, and ``make()`` users get
tasks without importing rsl_rl.
"""

from __future__ import annotations

import importlib
import inspect
import os
import sys
import traceback

import torch
from omegaconf import DictConfig

from isaacgymenvs_mw.sim import set_verbose
from isaacgymenvs_mw.tasks import get_task_class
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.utils.config import check_run_config, cpu_threads, to_dict
from isaacgymenvs_mw.utils.device import check_device_pair, check_multi_gpu, resolve_device
from isaacgymenvs_mw.utils.errors import ConfigError, under_task


def import_task_module(name: str) -> None:
    """``task_module=``: import the module that registers the user's tasks, or say in one line why it cannot be.

    Python looks in the running script's folder (train.py's, or the user's script calling make()) and PYTHONPATH;
    the current folder is looked in too, last, as a user running from their project's folder expects."""
    try:
        _import_with_cwd_last(name)
    except ModuleNotFoundError as err:
        missing = err.name or name
        if missing == name or name.startswith(f"{missing}."):  # the module itself (or its package) is not found
            script = os.path.dirname(os.path.abspath(sys.argv[0])) if sys.argv and sys.argv[0] else None
            where = f"the script's folder ({script}), " if script else ""
            raise ConfigError(f"task_module={name!r}: no module {missing!r} in {where}the current folder "
                              f"({os.getcwd()}) or PYTHONPATH: run from the folder that holds it, or add that "
                              "folder to PYTHONPATH") from err
        raise ConfigError(f"task_module={name!r} imports {missing!r}, which is not installed: pip install it (or "
                          "fix the import)") from err


def _import_with_cwd_last(name: str) -> None:
    try:
        importlib.import_module(name)
        return
    except ModuleNotFoundError as err:
        top = name.split(".")[0]
        if (err.name or name) not in (name, top) and not name.startswith(f"{err.name}."):
            raise  # the module was found and imports something missing
        cwd = os.getcwd()
        if cwd in sys.path or "" in sys.path:
            raise
    sys.path.append(cwd)
    importlib.import_module(name)


def build_task(cfg: DictConfig) -> VecTask:
    """Construct the task named by ``cfg.task_name`` on the configured devices."""
    check_run_config(cfg)
    set_verbose(cfg.get("verbose", False))
    torch.set_num_threads(cpu_threads(cfg.get("cpu_threads", 1)))
    if cfg.get("task_module"):
        import_task_module(str(cfg.task_module))
    task_class = get_task_class(cfg.task_name)
    rank = int(os.getenv("LOCAL_RANK", "0"))
    check_multi_gpu(bool(cfg.get("multi_gpu", False)), int(os.getenv("WORLD_SIZE", "1")), rank)
    if cfg.get("multi_gpu", False):
        sim_device = rl_device = f"cuda:{rank}"
    else:
        sim_device = resolve_device(cfg.sim_device, "sim_device")
        rl_device = resolve_device(cfg.rl_device, "rl_device")
    check_device_pair(sim_device, rl_device)
    if sim_device.startswith("cuda"):
        torch.cuda.set_device(torch.device(sim_device))
    task_cfg = to_dict(cfg.task)
    # The run-level `deterministic` reaches the sim layer through the task's sim section (MuJoCo Warp's option).
    task_cfg.setdefault("sim", {})["deterministic"] = bool(cfg.get("deterministic", False))
    try:
        return task_class(
            task_cfg, rl_device=rl_device, sim_device=sim_device, graphics_device_id=cfg.graphics_device_id,
            headless=cfg.headless, virtual_screen_capture=False, force_render=False,
        )
    except ConfigError as err:  # the task names its keys from its own section; the command line says task.<key>
        raise under_task(err) from err
    except ValueError as err:
        where = raised_by_task_code(err, task_class)
        if where is None:  # raised by a library or the framework: a bug, which keeps its traceback
            raise
        raise under_task(ConfigError(f"{err} ({where})")) from err


def raised_by_task_code(err: BaseException, task_class: type) -> str | None:
    """Where ``err`` was raised when that is the task's own code ("raised at my_task.py:42"), else None.

    A ValueError raised while a task is built is the task's bad-value check (``raise ValueError("env.x ...")``, or
    ``float(env["x"])`` of a word) when its innermost Python frame lies in the file of one of the task's classes
    outside the framework (``tasks/base``); a ValueError raised in torch, numpy or the framework is a bug there."""
    files = {os.path.realpath(inspect.getfile(cls)) for cls in task_class.__mro__
             if issubclass(cls, VecTask) and cls.__module__.split(".")[:3] != ["isaacgymenvs_mw", "tasks", "base"]}
    frames = traceback.extract_tb(err.__traceback__)
    if not frames or os.path.realpath(frames[-1].filename) not in files:
        return None
    return f"raised at {os.path.basename(frames[-1].filename)}:{frames[-1].lineno}"
