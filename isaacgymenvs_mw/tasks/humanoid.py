"""Humanoid: IsaacGymEnvs' 21-joint runner (assets/mjcf/humanoid.xml, its own motors); settings in
cfg/task/Humanoid.yaml."""

from __future__ import annotations

import torch

from isaacgymenvs_mw.tasks.locomotion_task import LocomotionTask


class Humanoid(LocomotionTask):
    """Run along +x: 108 observations (the Ant's plus each joint's actuator torque), 21 motor commands in [-1, 1]."""

    observe_dof_forces = True

    def _reward_joints_at_limit(self) -> torch.Tensor:
        # penalises joints pressed to their limits, growing linearly from the threshold and weighted by motor strength
        thr = self.env_numbers["jointsAtLimitThreshold"]
        excess = (torch.abs(self.dof_pos_scaled()) - thr).clamp(min=0.0) / (1.0 - thr)
        return -self.env_numbers["jointsAtLimitCost"] * torch.sum(excess * self.dof_effort_ratio, dim=-1)
