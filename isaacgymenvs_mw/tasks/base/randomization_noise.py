"""Observation and action noise of the randomisation layer: per-term observation noise (``observations.terms``),
section-wide noise and IsaacGymEnvs' correlated offsets (``range_correlated``), all masked torch work on the device."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import torch

from isaacgymenvs_mw.tasks.base.observation_terms import ObsLayout
from isaacgymenvs_mw.tasks.base.randomization_config import ROOT, NoiseSpecs
from isaacgymenvs_mw.tasks.base.randomization_sampling import Sampler, combine
from isaacgymenvs_mw.utils.errors import ConfigError


class Noise:
    """The noise of the ``observations`` and ``actions`` sections; correlated offsets are drawn anew every
    ``frequency`` env steps of the sampler's clock."""

    def __init__(self, observations: NoiseSpecs, obs_terms: Any, actions: NoiseSpecs, frequency: int, num_envs: int,
                 sampler: Sampler) -> None:
        self.obs, self.obs_terms, self.act = observations, obs_terms, actions
        self.frequency, self.num_envs, self.sampler = frequency, num_envs, sampler
        self.correlated: dict[str, torch.Tensor] = {}
        self.term_noise: torch.Tensor | None = None

    def with_term_noise(self, layout: ObsLayout) -> ObsLayout:
        """The task's policy layout with ``observations.terms`` noise added to its terms' own (per-column noise)."""
        terms = dict(self.obs_terms or {})
        unknown = [n for n in terms if n not in layout.slices]
        if unknown:
            raise ConfigError(f"{ROOT}.observations.terms: unknown observation term(s) {unknown}; "
                              f"terms of this task: {layout.names}")
        bad = [n for n, v in terms.items() if not float(v) >= 0]
        if bad:
            raise ConfigError(f"{ROOT}.observations.terms: noise of {bad} must be >= 0")
        layout = ObsLayout([replace(t, noise=t.noise + float(terms.get(t.name, 0.0)) * abs(t.scale))
                            for t in layout.terms])
        if self.obs.correlated is not None:
            self.correlated["observations"] = self.sampler.sample(self.obs.correlated, (self.num_envs, layout.size))
        scale = layout.noise_scale(self.sampler.device)
        self.term_noise = scale if bool((scale != 0).any()) else None
        return layout

    def start_action_offsets(self, num_actions: int) -> None:
        """The first correlated action offsets, once the action size is known."""
        if self.act.correlated is not None:
            self.correlated["actions"] = self.sampler.sample(self.act.correlated, (self.num_envs, num_actions))

    def actions(self, actions: torch.Tensor) -> torch.Tensor:
        """The actions with this step's action noise."""
        if self.act.noise is None:
            return actions
        return combine(self.act.noise, actions, self._draw("actions", self.act, actions.shape))

    def observations(self, obs: torch.Tensor) -> None:
        """Add the per-term and the section-wide observation noise to the policy observation, in place."""
        if self.term_noise is not None:
            obs += (2.0 * torch.rand_like(obs) - 1.0) * self.term_noise
        if self.obs.noise is not None:
            obs.copy_(combine(self.obs.noise, obs, self._draw("observations", self.obs, obs.shape)))

    def _draw(self, name: str, specs: NoiseSpecs, shape: torch.Size) -> torch.Tensor:
        """This step's draws of the noise, plus the correlated offsets: drawn once, then anew every ``frequency``
        env steps (masked, no host sync)."""
        x = self.sampler.sample(specs.noise, shape)
        corr = specs.correlated
        if corr is None:
            return x
        if name not in self.correlated or self.correlated[name].shape != shape:  # else at the first (eager) step
            self.correlated[name] = self.sampler.sample(corr, shape)
        offsets = self.correlated[name]
        due = torch.remainder(self.sampler.clock, self.frequency) == 0
        offsets.copy_(torch.where(due, self.sampler.sample(corr, shape), offsets))
        return x + offsets
