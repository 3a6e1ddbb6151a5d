"""The action delay: ``env.control.actionDelay`` policy steps, plus a per-env whole number drawn from
``task.randomization_params.actions.delay``, served from a ring buffer of past actions on the device."""

from __future__ import annotations

import torch

from isaacgymenvs_mw.tasks.base.randomization_spec import Spec
from isaacgymenvs_mw.utils.errors import ConfigError


class ActionDelay:
    """Delays each env's actions by its own number of policy steps; ``setup`` allocates the buffer."""

    def __init__(self, spec: Spec | None, num_envs: int, device: torch.device) -> None:
        self.spec, self.num_envs, self.device = spec, num_envs, device
        self.nominal = 0
        self.max_delay = 0

    def setup(self, nominal: int, num_actions: int) -> None:
        """Allocate the action ring buffer: ``nominal`` (env.control.actionDelay) plus the randomised range."""
        self.nominal = int(nominal)
        self.max_delay = self.nominal + (int(self.spec.hi) if self.spec is not None else 0)
        self.delay = torch.full((self.num_envs,), self.nominal, dtype=torch.long, device=self.device)
        if self.max_delay:
            self.history = torch.zeros((self.max_delay + 1, self.num_envs, num_actions), device=self.device)
            self.head = torch.zeros((), dtype=torch.long, device=self.device)
            if self.spec is not None:
                self._draw(torch.ones(self.num_envs, dtype=torch.bool, device=self.device))

    @staticmethod
    def check_nominal(nominal: int) -> None:
        if nominal < 0:
            raise ConfigError(f"env.control.actionDelay={nominal} is invalid: give a whole number of policy steps >= 0")

    def on_reset(self, mask: torch.Tensor) -> None:
        """Clear the resetting envs' past actions (their first steps act on zeros); redraw a reset-time delay."""
        if self.max_delay:
            self.history.masked_fill_(mask.view(1, -1, 1), 0.0)
            if self.spec is not None and self.spec.apply == "reset":
                self._draw(mask)

    def before_physics(self, progress: torch.Tensor) -> None:
        """Redraw an interval delay for the envs whose interval is due."""
        if self.spec is not None and self.spec.apply == "interval":
            self._draw((progress % self.spec.interval == 0) & (progress > 0))

    def apply(self, actions: torch.Tensor) -> torch.Tensor:
        """Store this step's actions; return each env's actions of ``delay`` steps ago."""
        if not self.max_delay:
            return actions
        self.head.add_(1).remainder_(self.max_delay + 1)
        self.history.index_copy_(0, self.head.view(1), actions.unsqueeze(0))
        slot = (self.head - self.delay).remainder(self.max_delay + 1)
        return self.history.gather(0, slot.view(1, -1, 1).expand(1, *actions.shape)).squeeze(0)

    def _draw(self, mask: torch.Tensor) -> None:
        lo, hi = int(self.spec.lo), int(self.spec.hi)
        new = self.nominal + torch.randint(lo, hi + 1, (self.num_envs,), device=self.device)
        self.delay.copy_(torch.where(mask, new, self.delay))
