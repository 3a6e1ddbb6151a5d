"""isaacgymenvs_mw: IsaacGymEnvs-style vectorised RL tasks on MuJoCo Warp."""

from __future__ import annotations

import os
from typing import Sequence

from isaacgymenvs_mw._version import __version__

__all__ = ["__version__", "make"]


def make(
    task: str,
    num_envs: int | None = None,
    sim_device: str = "auto",
    rl_device: str = "auto",
    headless: bool = True,
    seed: int | None = None,
    overrides: Sequence[str] = (),
    config_dir: str | os.PathLike | None = None,
):
    """Build a task as train.py would, without training: ``env = isaacgymenvs_mw.make("Cartpole", num_envs=16)``.

    ``overrides`` are Hydra overrides, e.g. ``["task.env.maxEffort=200"]``. ``config_dir`` is a folder of your own
    holding ``task/<Name>.yaml`` and ``train/<Name>PPO.yaml`` (train.py's ``--config-dir``); a task class outside
    the package is imported with ``overrides=["task_module=my_tasks"]`` (the module must be importable).
    """
    from isaacgymenvs_mw.tasks.build import build_task
    from isaacgymenvs_mw.utils.compile_cache import use_cache_folder
    from isaacgymenvs_mw.utils.config import compose_config
    from isaacgymenvs_mw.utils.seeding import set_seed

    args = [f"task={task}", f"sim_device={sim_device}", f"rl_device={rl_device}", f"headless={headless}"]
    if num_envs is not None:
        args.append(f"num_envs={num_envs}")
    use_cache_folder()  # ISAACGYMENVS_MW_CACHE, as train.py reads it
    cfg = compose_config([*args, *overrides], config_dir=config_dir)
    if seed is not None:
        set_seed(seed)
    return build_task(cfg)
