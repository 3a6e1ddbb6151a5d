"""Pushes (``task.randomization_params.push``): every ``interval`` policy steps of an env's episode its root's
horizontal velocity is set to, or kicked by, a draw."""

from __future__ import annotations

import torch

from isaacgymenvs_mw.sim import Simulator
from isaacgymenvs_mw.tasks.base.randomization_sampling import Sampler
from isaacgymenvs_mw.tasks.base.randomization_spec import Spec


class Pushes:
    """Masked velocity kicks of the envs whose push is due (no host sync)."""

    def __init__(self, spec: Spec, num_envs: int, sampler: Sampler) -> None:
        self.spec, self.num_envs, self.sampler = spec, num_envs, sampler

    def before_physics(self, progress: torch.Tensor, sim: Simulator) -> None:
        due = ((progress % self.spec.interval == 0) & (progress > 0)).unsqueeze(1)
        vel = sim.root_lin_vel[:, :2]
        kick = self.sampler.sample(self.spec, (self.num_envs, 2))
        new = kick if self.spec.operation == "set" else vel + kick
        vel.copy_(torch.where(due, new, vel))
