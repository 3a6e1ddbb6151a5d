"""isaacgymenvs_mw: IsaacGymEnvs-style vectorised RL tasks on MuJoCo Warp."""

from __future__ import annotations

from typing import Sequence

__version__ = "0.1.0"


def make(
    task: str,
    num_envs: int | None = None,
    sim_device: str = "auto",
    rl_device: str = "auto",
    headless: bool = True,
    seed: int | None = None,
    overrides: Sequence[str] = (),
):
    """Build a task as train.py would, without training: ``env = isaacgymenvs_mw.make("Cartpole", num_envs=16)``.

    ``overrides`` are Hydra overrides, e.g. ``["task.env.maxEffort=200"]``.
    """
    from isaacgymenvs_mw.learning.launch import build_task
    from isaacgymenvs_mw.utils.config import compose_config
    from isaacgymenvs_mw.utils.seeding import set_seed

    args = [f"task={task}", f"sim_device={sim_device}", f"rl_device={rl_device}", f"headless={headless}"]
    if num_envs is not None:
        args.append(f"num_envs={num_envs}")
    cfg = compose_config([*args, *overrides])
    if seed is not None:
        set_seed(seed)
    return build_task(cfg)
