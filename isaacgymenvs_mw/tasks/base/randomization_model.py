"""The model quantities of the randomisation layer (``sim_params``, ``actor_params``): bound to the compiled model's
per-world fields, drawn at startup, at resets (gated by ``frequency``) and at intervals, as masked torch work."""

from __future__ import annotations

import torch

from isaacgymenvs_mw.sim import InertiaConstants, Simulator, ground_geoms
from isaacgymenvs_mw.sim.randomization import (
    actor_elements,
    element_ids,
    per_world_fields,
    write_view,
)
from isaacgymenvs_mw.tasks.base.randomization_config import Entry
from isaacgymenvs_mw.tasks.base.randomization_sampling import Sampler, combine
from isaacgymenvs_mw.tasks.base.randomization_spec import MAIN_ACTOR, Param, Quantity
from isaacgymenvs_mw.utils.errors import ConfigError


class ModelRandomizer:
    """The parsed model quantities (``entries``); ``bind`` resolves them against the model and draws startup."""

    def __init__(self, entries: list[Entry], frequency: int, num_envs: int, sampler: Sampler) -> None:
        self.entries, self.frequency, self.num_envs, self.sampler = entries, frequency, num_envs, sampler
        self.device = sampler.device
        # IsaacGymEnvs' randomize_buf: env steps since each env's reset-time draws last drew.
        self.since_draw = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self.params: list[Param] = []
        self.sim: Simulator | None = None
        self.inertia: InertiaConstants | None = None

    def per_world_fields(self) -> tuple[str, ...]:
        """Model fields the simulator must batch per world for the configured quantities."""
        return per_world_fields([entry.quantity.prop for entry in self.entries])

    # ------------------------------------------------------------------ binding
    def bind(self, sim: Simulator) -> None:
        """Resolve names against the compiled model, check the ranges against the nominal values, draw startup."""
        self.sim = sim
        m = sim.mj_model
        written: dict[tuple[str, int | None, int], str] = {}
        for spec, quantity, patterns, selector, actor in self.entries:
            index = element_ids(m, quantity.prop, selector, patterns, spec.key, self.device)
            if actor is not None:
                index = self._actor_index(m, quantity, index, actor, spec.key)
            param = Param(spec, quantity, index, nominal=torch.empty(0),
                          draw_of=self._shared_draws(m, quantity, index))
            if spec.buckets:
                param.bucket_values = self.sampler.sample(spec, (spec.buckets,))
            for write in quantity.prop.writes:
                view = write_view(sim, write, quantity.prop.torque_speed, spec.key)
                for i in index.tolist():
                    clash = written.get((write.field, write.column, i))
                    if clash is not None:
                        raise ConfigError(f"{spec.key} and {clash} both randomise {write} of the same element; "
                                          "select disjoint elements")
                    written[(write.field, write.column, i)] = spec.key
                param.views.append((view, write.sign))
                if param.nominal.numel() == 0:
                    param.nominal = (view[:1, index] * write.sign).clone()
            if quantity.minimum is not None and spec.operation == "additive" and spec.distribution != "gaussian":
                low = float((param.nominal + spec.lo).min())
                if low < quantity.minimum or (quantity.minimum > 0 and low <= 0):
                    raise ConfigError(f"{spec.key}.range={[spec.lo, spec.hi]}: this quantity must stay "
                                      f"{'> 0' if quantity.minimum > 0 else '>= 0'}, but nominal + low = {low:.4g}")
            self.params.append(param)
        self.inertia = (InertiaConstants(m, sim.device)
                        if any(p.quantity.prop.changes_inertia for p in self.params) else None)
        everyone = torch.ones(self.num_envs, dtype=torch.bool, device=self.device)
        self._draw_params(everyone, "startup")

    def _actor_index(self, m, quantity: Quantity, index: torch.Tensor, actor: str, key: str) -> torch.Tensor:
        """The part of ``index`` that belongs to ``actor``: an env.assets name, or MAIN_ACTOR for env.asset."""
        prefixes = {name: view.prefix for name, view in self.sim.assets.items()}
        if actor not in prefixes and actor != MAIN_ACTOR:
            raise ConfigError(f"{key}: '{actor}' is no actor of this scene; actors: "
                              f"{[MAIN_ACTOR + ' (env.asset)', *prefixes]}")
        owned = actor_elements(m, quantity.prop, index, prefixes.get(actor), list(prefixes.values()))
        if owned.numel() == 0:
            raise ConfigError(f"{key}: actor '{actor}' has no {quantity.selects} among those selected")
        return owned

    def _shared_draws(self, m, quantity: Quantity, index: torch.Tensor) -> torch.Tensor | None:
        """The ground of a terrain is many geoms (sim/ground.py) but one surface: its parts take one draw."""
        ground = set(ground_geoms(m))
        ids = index.tolist()
        if quantity.selects != "geoms" or sum(g in ground for g in ids) < 2:
            return None
        columns: dict[object, int] = {}
        draw_of = [columns.setdefault("ground" if g in ground else g, len(columns)) for g in ids]
        return torch.tensor(draw_of, dtype=torch.long, device=self.device)

    # -------------------------------------------------------------- drawing
    def on_reset(self, mask: torch.Tensor) -> None:
        """Draw the reset-time quantities of the resetting worlds whose last draw is ``frequency`` env steps old."""
        due = mask & (self.since_draw >= self.frequency) if self.frequency > 1 else mask
        self.since_draw.masked_fill_(due, 0)  # IsaacGymEnvs' randomize_buf: zeroed where the draw happens
        self._draw_params(due, "reset")

    def before_physics(self, progress: torch.Tensor) -> None:
        """Interval draws for the worlds whose interval is due (by their episode's step count)."""
        for p in self.params:
            if p.spec.apply == "interval":
                due = (progress % p.spec.interval == 0) & (progress > 0)
                self._draw_param(p, due)
                if p.quantity.prop.changes_inertia:
                    self._update_inertia_constants(due)

    def count_step(self) -> None:
        self.since_draw.add_(1)

    def _draw_params(self, mask: torch.Tensor, when: str) -> None:
        touched_mass = False
        for p in self.params:
            if p.spec.apply != when and not (when == "startup" and p.spec.apply == "reset"):
                continue
            self._draw_param(p, mask)
            touched_mass |= p.quantity.prop.changes_inertia
        if touched_mass:
            self._update_inertia_constants(mask)

    def _draw_param(self, p: Param, mask: torch.Tensor) -> None:
        q = p.quantity
        k = p.index.numel() if p.draw_of is None else int(p.draw_of.max()) + 1
        shape = (self.num_envs, k, q.axes) if q.axes else (self.num_envs, k, 1) if q.broadcast else \
            (self.num_envs, k)
        if p.bucket_values is not None:
            draws = p.bucket_values[torch.randint(0, p.spec.buckets, shape, device=self.device)]
        else:
            draws = self.sampler.sample(p.spec, shape)
        value = combine(p.spec, p.nominal, draws if p.draw_of is None else draws[:, p.draw_of])
        if q.minimum is not None:
            value = torch.clamp(value, min=q.minimum)
        rows = mask.view((-1,) + (1,) * (value.dim() - 1))
        for view, sign in p.views:
            current = view[:, p.index]
            view[:, p.index] = torch.where(rows, (value * sign).expand_as(current), current)

    def _update_inertia_constants(self, mask: torch.Tensor) -> None:
        if self.inertia is not None:
            self.inertia.update(self.sim, mask)
