"""Draws of one distribution (``Spec``, randomization_spec.py) on the device, shrunk by its schedule, which reads
the run's env steps per env (the episode's clock, ``Episode.run_steps``). Shared by the randomisation layer's parts."""

from __future__ import annotations

import math

import torch

from isaacgymenvs_mw.tasks.base.randomization_spec import Spec


class Sampler:
    """Draws on ``device``; ``clock`` is a () float32 device tensor of env steps per env, read (never advanced) here."""

    def __init__(self, device: torch.device, clock: torch.Tensor | None = None) -> None:
        self.device = device
        # Until the task's episode hands its clock over (Randomizer.follow_clock), a clock of its own at 0, which
        # is what the episode's reads before its first step.
        self.clock = clock if clock is not None else torch.zeros((), device=device, dtype=torch.float32)

    def schedule(self, spec: Spec) -> torch.Tensor | float:
        if spec.schedule is None:
            return 1.0
        if spec.schedule == "linear":
            return torch.clamp(self.clock / spec.schedule_steps, max=1.0)
        return (self.clock >= spec.schedule_steps).float()

    def sample(self, spec: Spec, shape: tuple[int, ...]) -> torch.Tensor:
        """Draws of ``spec`` before combination with a nominal value; a schedule shrinks them towards identity."""
        if spec.distribution == "uniform":
            x = spec.lo + (spec.hi - spec.lo) * torch.rand(shape, device=self.device)
        elif spec.distribution == "gaussian":
            x = spec.lo + spec.hi * torch.randn(shape, device=self.device)
        else:
            log_lo, log_hi = math.log(spec.lo), math.log(spec.hi)
            x = torch.exp(log_lo + (log_hi - log_lo) * torch.rand(shape, device=self.device))
        if spec.schedule is not None:
            ident = spec.identity()
            x = ident + self.schedule(spec) * (x - ident)
        return x


def combine(spec: Spec, nominal: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """A draw applied to a nominal value by the spec's operation."""
    return nominal + x if spec.operation in ("additive", "set") else nominal * x
