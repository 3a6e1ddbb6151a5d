"""Unitree Go1 walking on flat ground; everything robot-specific is in cfg/task/Go1.yaml."""

from isaacgymenvs_mw.tasks.legged_task import LeggedTask


class Go1(LeggedTask):
    """Velocity tracking with Unitree's Go1 (12.7 kg, 12 joints, PD position targets)."""
