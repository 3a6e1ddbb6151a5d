"""Ant: IsaacGymEnvs' four-legged runner (assets/mjcf/ant.xml, its own gear-15 motors); settings in
cfg/task/Ant.yaml."""

from isaacgymenvs_mw.tasks.locomotion_task import LocomotionTask


class Ant(LocomotionTask):
    """Run along +x: 60 observations (IsaacGymEnvs' layout), 8 motor commands in [-1, 1]."""
