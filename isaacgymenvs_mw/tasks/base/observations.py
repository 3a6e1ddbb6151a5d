"""Observations as lists of named terms: size, scale and noise side by side, the total size derived.

A task declares what its policy (and critic) observe as a list of ``ObsTerm``; ``ObsLayout`` turns the list into
the things that used to be hand-kept in step with it: the total size (checked against ``env.numObservations`` /
``env.numStates`` with an error naming the key), each term's columns, the per-column noise amplitude, and the
description an exported policy carries.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Callable, Sequence

import torch

from isaacgymenvs_mw.utils.errors import ConfigError


@dataclass(frozen=True)
class ObsTerm:
    """One named piece of an observation vector.

    Args:
        name: unique within its layout ("base_lin_vel", "dof_pos", ...).
        size: number of columns.
        scale: factor VecTask multiplies ``compute()``'s value by (also documentation and export).
        noise: half-width of the uniform noise added to the observed (scaled) value; 0 = none.
        compute: what computes the raw (num_envs, size) value: a function or bound method without arguments.
            None only for a task that fills its observation itself (the layout then documents it).
    """

    name: str
    size: int
    scale: float = 1.0
    noise: float = 0.0
    compute: Callable[[], torch.Tensor] | None = field(default=None, compare=False, repr=False)


class ObsLayout:
    """Column layout of an observation vector made of ``terms``, in order."""

    def __init__(self, terms: Sequence[ObsTerm]) -> None:
        names = [t.name for t in terms]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ConfigError(f"observation terms {duplicates} appear more than once; term names must be unique")
        bad = [t.name for t in terms if int(t.size) < 1]
        if bad:
            raise ConfigError(f"observation terms {bad} have size < 1")
        self.terms = tuple(terms)
        self.slices: dict[str, slice] = {}
        start = 0
        for t in self.terms:
            self.slices[t.name] = slice(start, start + int(t.size))
            start += int(t.size)
        self.size = start

    @property
    def names(self) -> list[str]:
        return [t.name for t in self.terms]

    def check(self, declared: int, key: str) -> None:
        """Fail, naming ``key``, when a size given in the YAML is not the sum of the terms."""
        if declared != self.size:
            parts = " + ".join(f"{t.name} {t.size}" for t in self.terms)
            raise ConfigError(f"{key}={declared}, but the task observes {self.size} values ({parts}); "
                             f"remove {key} (the size is derived from the terms) or set {key}: {self.size}")

    def noise_scale(self, device: torch.device | str) -> torch.Tensor:
        """(size,) uniform-noise half-widths, one per column."""
        return torch.cat([torch.full((int(t.size),), float(t.noise)) for t in self.terms]).to(device)

    def columns(self, names: Sequence[str], key: str) -> torch.Tensor:
        """Column indices of the named terms, in the order given; an unknown name fails naming ``key``."""
        unknown = [n for n in names if n not in self.slices]
        if unknown:
            raise ConfigError(f"{key}: unknown observation term(s) {unknown}; terms: {self.names}")
        return torch.cat([torch.arange(self.slices[n].start, self.slices[n].stop) for n in names])

    def describe(self) -> list[dict]:
        """The layout as plain data (name, size, scale, noise, first column), for logs and exported policies."""
        described = [f.name for f in fields(ObsTerm) if f.name != "compute"]
        return [{**{k: getattr(t, k) for k in described}, "start": self.slices[t.name].start} for t in self.terms]
