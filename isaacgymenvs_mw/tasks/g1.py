"""Unitree G1 humanoid walking on flat ground or terrain; everything robot-specific is in cfg/task/G1.yaml."""

from isaacgymenvs_mw.tasks.legged_task import LeggedTask


class G1(LeggedTask):
    """Velocity tracking with Unitree's G1 (34.1 kg, 23 joints, PD position targets, two feet)."""
