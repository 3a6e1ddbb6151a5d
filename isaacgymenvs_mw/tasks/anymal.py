"""ANYmal C walking on flat ground; everything robot-specific is in cfg/task/Anymal.yaml."""

from isaacgymenvs_mw.tasks.legged_task import LeggedTask


class Anymal(LeggedTask):
    """Velocity tracking with ANYbotics' ANYmal C (52 kg, 12 joints, PD position targets)."""
