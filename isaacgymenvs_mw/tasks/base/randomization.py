"""Domain randomisation for every VecTask, driven by the task YAML (``task.randomize``, ``task.randomization_params``).

The vocabulary is IsaacGymEnvs' where it maps: ``observations`` and ``actions`` noise, ``sim_params`` (gravity),
``actor_params`` grouped as ``rigid_body_properties`` / ``rigid_shape_properties`` / ``dof_properties`` (plus our
``actuator_properties``), each quantity with ``range``, ``distribution`` (uniform | gaussian | loguniform),
``operation`` (additive | scaling) and an optional ``schedule`` (linear | constant) over ``schedule_steps`` env
steps; also IsaacGymEnvs' per-actor level (``actor_params.<actor>.<group>``), ``frequency``, ``range_correlated``,
``setup_only`` and ``num_buckets``, and a one-line refusal of its keys with no MuJoCo counterpart (``REFUSED``). Ours on
top: what a quantity applies to (``bodies`` / ``geoms`` / ``joints`` / ``actuators``: names or regular
expressions), when it is drawn (``apply``: startup | reset | interval), per-term observation noise, an action delay
and pushes. docs/config.md lists every key.

Each draw is relative to the compiled model's (nominal) value, so scaling never compounds; only the worlds that
reset (or whose interval is due) draw; the values live in per-world Model fields on the device, and every draw is
masked torch work (no host sync), so the step stays capturable as a CUDA graph and compilable by torch.compile.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import torch

from isaacgymenvs_mw.sim import InertiaConstants, Simulator, ground_geoms
from isaacgymenvs_mw.sim.randomization import (
    actor_elements,
    element_ids,
    per_world_fields,
    write_view,
)
from isaacgymenvs_mw.tasks.base.observation_terms import ObsLayout
from isaacgymenvs_mw.tasks.base.randomization_spec import (
    QUANTITIES,
    SECTIONS,
    NOISE_KEYS,
    DRAW_KEYS,
    MAIN_ACTOR,
    REFUSED,
    SIM_QUANTITIES,
    SELECTORS,
    Quantity,
    Spec,
    Param,
    _parse_spec,
    _interval_steps,
)
from isaacgymenvs_mw.utils.config import whole_number
from isaacgymenvs_mw.utils.errors import ConfigError

class Randomizer:
    """The randomisation layer of one VecTask: parses the YAML, binds to the model, draws on the device.

    ``VecTask`` calls, in this order each step: ``before_physics`` (interval draws, pushes), ``actions`` (delay,
    noise), the physics, the task's post-physics step (whose resets call ``on_reset`` before the task's ``reset_idx``),
    ``observations`` (noise). All of it is masked torch work on the sim device.
    """

    def __init__(self, task_cfg: dict | None, control_dt: float, num_envs: int, device: torch.device,
                 step_count: torch.Tensor | None = None) -> None:
        task_cfg = dict(task_cfg or {})
        self.enabled = bool(task_cfg.get("randomize", False))
        params = dict(task_cfg.get("randomization_params") or {}) if self.enabled else {}
        root = "task.randomization_params"
        unknown = sorted(set(params) - set(SECTIONS))
        if unknown:
            raise ConfigError(f"{root}.{unknown[0]}: unknown section (all unknown: {unknown}); valid sections: "
                              f"{list(SECTIONS)}")
        self.root, self.control_dt, self.num_envs, self.device = root, control_dt, num_envs, device
        self.raw = params
        # IsaacGymEnvs' frequency: env steps an env's reset-time draws wait since its last draw, and between new
        # correlated noise offsets.
        self.frequency = whole_number(params.get("frequency", 1), f"{root}.frequency", 1)
        self.since_draw = torch.zeros(num_envs, dtype=torch.long, device=device)
        self.correlated: dict[str, torch.Tensor] = {}
        (self.obs_noise, self.obs_corr), self.obs_terms = self._parse_noise("observations", extra=("terms",))
        (self.action_noise, self.action_corr), delay_raw = self._parse_noise("actions", extra=("delay",))
        self.delay_spec = None
        if delay_raw is not None:
            self.delay_spec = _parse_spec(delay_raw, f"{root}.actions.delay", DRAW_KEYS, operations=("additive",))
            if self.delay_spec.distribution != "uniform" or self.delay_spec.lo < 0 \
                    or self.delay_spec.lo != int(self.delay_spec.lo) or self.delay_spec.hi != int(self.delay_spec.hi):
                raise ConfigError(f"{root}.actions.delay: give range: [low, high] of whole policy steps >= 0 with "
                                 "distribution: uniform (every whole number in the range is equally likely)")
            self._set_interval(self.delay_spec, delay_raw)
        self.push_spec = None
        if "push" in params:
            raw = params["push"]
            self.push_spec = _parse_spec(raw, f"{root}.push", NOISE_KEYS + ("interval_s", "interval_steps"),
                                         operations=("set", "additive"), default_apply="interval")
            self.push_spec.interval = _interval_steps(raw, f"{root}.push", control_dt)
        # Model quantities: (spec, quantity, selector patterns, selector, actor), bound to the model in bind().
        self.entries: list[tuple[Spec, Quantity, list[str] | None, str | None, str | None]] = []
        for name, raw in dict(params.get("sim_params") or {}).items():
            key = f"{root}.sim_params.{name}"
            if name not in SIM_QUANTITIES:
                raise ConfigError(f"{key}: unknown parameter; valid: {list(SIM_QUANTITIES)}")
            self._add_entry(raw, key, SIM_QUANTITIES[name])
        for group, quantities, actor in self._actor_groups(dict(params.get("actor_params") or {})):
            where = f"{root}.actor_params.{actor + '.' if actor else ''}{group}"
            for name, raw in dict(quantities or {}).items():
                key = f"{where}.{name}"
                if name in REFUSED:
                    raise ConfigError(f"{key}={raw!r} has no counterpart here: {REFUSED[name]}")
                if name not in QUANTITIES[group]:
                    hint = (" (a position drive's gains are actuator_properties.stiffness / damping)"
                            if group == "dof_properties" and name == "stiffness" else "")
                    raise ConfigError(f"{key}: unknown parameter; valid in {group}: "
                                     f"{list(QUANTITIES[group])}{hint}")
                for i, item in enumerate(raw if isinstance(raw, list) else [raw]):
                    self._add_entry(item, key if not isinstance(raw, list) else f"{key}[{i}]",
                                    QUANTITIES[group][name], actor)
        self.params: list[Param] = []
        self.sim: Simulator | None = None
        # The run's env steps per env, which the schedules read: the episode's clock (tasks/base/episode.py), which
        # counts it; a Randomizer made on its own (tests) keeps a clock of its own.
        self.step_count = step_count if step_count is not None else torch.zeros((), device=device, dtype=torch.float32)
        self.term_noise: torch.Tensor | None = None
        self.max_delay = 0

    # ------------------------------------------------------------------ parsing
    def _actor_groups(self, params: dict) -> list[tuple[str, Any, str | None]]:
        """(group, its quantities, actor or None) of ``actor_params``: a group at the top applies to the whole scene;
        IsaacGymEnvs' per-actor level ``<actor>.<group>`` to one actor (an env.assets name, or MAIN_ACTOR)."""
        out = []
        for name, node in params.items():
            if name in QUANTITIES:
                out.append((name, node, None))
                continue
            key = f"{self.root}.actor_params.{name}"
            if not isinstance(node, dict):
                raise ConfigError(f"{key}={node!r} is invalid: give a group of {list(QUANTITIES)}, or an actor "
                                  f"('{MAIN_ACTOR}' or an env.assets name) holding such groups")
            for group, quantities in node.items():
                if group in REFUSED:
                    raise ConfigError(f"{key}.{group}={quantities!r} has no counterpart here: {REFUSED[group]}")
                if group not in QUANTITIES:
                    raise ConfigError(f"{key}.{group}: unknown group; valid: {list(QUANTITIES)}")
                out.append((group, quantities, str(name)))
        return out

    def _parse_noise(self, section: str, extra: tuple[str, ...]) -> tuple[tuple[Spec | None, Spec | None], Any]:
        """(noise spec, correlated spec) of the observations or actions section, and its extra key's value."""
        raw = self.raw.get(section)
        if raw is None:
            return (None, None), None
        key = f"{self.root}.{section}"
        if not isinstance(raw, dict):
            raise ConfigError(f"{key}: expected a mapping, got {raw!r}")
        noise = {k: v for k, v in raw.items() if k not in extra and k != "range_correlated"}
        spec = _parse_spec(noise, key, NOISE_KEYS) if noise else None
        corr = None
        if "range_correlated" in raw:
            if spec is None:
                raise ConfigError(f"{key}.range_correlated={raw['range_correlated']!r} needs {key}.range (the "
                                  "noise it is added to)")
            # IsaacGymEnvs' correlated noise: an offset per env and column, kept for `frequency` steps, added to the
            # per-step draw; its schedule shrinks it towards no offset.
            corr = _parse_spec({**noise, "range": raw["range_correlated"], "operation": "additive"},
                               f"{key}.range_correlated", NOISE_KEYS)
        extras = [raw.get(k) for k in extra]
        return (spec, corr), (extras[0] if extras else None)

    def _set_interval(self, spec: Spec, raw: dict) -> None:
        if spec.apply == "interval":
            spec.interval = _interval_steps(raw, spec.key, self.control_dt)
        elif "interval_s" in raw or "interval_steps" in raw:
            raise ConfigError(f"{spec.key}: interval_s / interval_steps need apply: interval")

    def _add_entry(self, raw: Any, key: str, quantity: Quantity, actor: str | None = None) -> None:
        allowed = DRAW_KEYS + ((quantity.selects,) if quantity.selects else ())
        if quantity.selects == "geoms":
            allowed += ("bodies", "num_buckets")  # PhysX's material buckets: meaningful for surfaces only
        spec = _parse_spec(raw, key, allowed)
        if "num_buckets" in raw:
            spec.buckets = whole_number(raw["num_buckets"], f"{key}.num_buckets", 1)
            if spec.schedule is not None:  # the bucket values are drawn once, at startup, where a schedule is at 0
                raise ConfigError(f"{key}.num_buckets={raw['num_buckets']!r} and {key}.schedule={spec.schedule!r} "
                                  "cannot go together: the buckets are drawn once, at startup; give one of them")
        self._set_interval(spec, raw)
        if quantity.minimum is not None:
            self._check_positive(spec, quantity)
        selector = None
        patterns = None
        for name in SELECTORS:
            if name in raw and name in allowed:
                if selector is not None:
                    raise ConfigError(f"{key}: give either {selector} or {name}, not both")
                selector, value = name, raw[name]
                patterns = [value] if isinstance(value, str) else [str(v) for v in value]
        self.entries.append((spec, quantity, patterns, selector, actor))

    @staticmethod
    def _check_positive(spec: Spec, quantity: Quantity) -> None:
        """A quantity that must stay >= 0 (> 0) may not be given a range that takes it below."""
        what = "> 0" if quantity.minimum > 0 else ">= 0"
        if spec.operation == "scaling":
            low = spec.lo if spec.distribution != "gaussian" else spec.lo - 3.0 * spec.hi
            if low < 0 or (quantity.minimum > 0 and low <= 0):
                raise ConfigError(f"{spec.key}.range={[spec.lo, spec.hi]}: this quantity must stay {what}; a scaling "
                                 "range must be > 0 (gaussian: mean - 3 std > 0)")
        # additive ranges are checked against the nominal values in bind()

    # ------------------------------------------------------------------ binding
    def per_world_fields(self) -> tuple[str, ...]:
        """Model fields the simulator must batch per world for the configured quantities."""
        return per_world_fields([entry[1].prop for entry in self.entries])

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
                param.bucket_values = self.sample(spec, (spec.buckets,))
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
        """The ground of a terrain is many geoms (sim/builder.py) but one surface: its parts take one draw."""
        ground = set(ground_geoms(m))
        ids = index.tolist()
        if quantity.selects != "geoms" or sum(g in ground for g in ids) < 2:
            return None
        columns: dict[object, int] = {}
        draw_of = [columns.setdefault("ground" if g in ground else g, len(columns)) for g in ids]
        return torch.tensor(draw_of, dtype=torch.long, device=self.device)

    # -------------------------------------------------------------- drawing
    def _schedule(self, spec: Spec) -> torch.Tensor | float:
        if spec.schedule is None:
            return 1.0
        if spec.schedule == "linear":
            return torch.clamp(self.step_count / spec.schedule_steps, max=1.0)
        return (self.step_count >= spec.schedule_steps).float()

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
            x = ident + self._schedule(spec) * (x - ident)
        return x

    @staticmethod
    def combine(spec: Spec, nominal: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return nominal + x if spec.operation in ("additive", "set") else nominal * x

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
            draws = self.sample(p.spec, shape)
        value = self.combine(p.spec, p.nominal, draws if p.draw_of is None else draws[:, p.draw_of])
        if q.minimum is not None:
            value = torch.clamp(value, min=q.minimum)
        rows = mask.view((-1,) + (1,) * (value.dim() - 1))
        for view, sign in p.views:
            current = view[:, p.index]
            view[:, p.index] = torch.where(rows, (value * sign).expand_as(current), current)

    def _update_inertia_constants(self, mask: torch.Tensor) -> None:
        if self.inertia is not None:
            self.inertia.update(self.sim, mask)

    # ------------------------------------------------------------- per step
    def with_term_noise(self, layout: ObsLayout) -> ObsLayout:
        """The task's policy layout with ``observations.terms`` noise added to its terms' own (per-column noise)."""
        terms = dict(self.obs_terms or {})
        unknown = [n for n in terms if n not in layout.slices]
        if unknown:
            raise ConfigError(f"{self.root}.observations.terms: unknown observation term(s) {unknown}; "
                             f"terms of this task: {layout.names}")
        bad = [n for n, v in terms.items() if not float(v) >= 0]
        if bad:
            raise ConfigError(f"{self.root}.observations.terms: noise of {bad} must be >= 0")
        layout = ObsLayout([replace(t, noise=t.noise + float(terms.get(t.name, 0.0)) * abs(t.scale))
                            for t in layout.terms])
        if self.obs_corr is not None:
            self.correlated["observations"] = self.sample(self.obs_corr, (self.num_envs, layout.size))
        scale = layout.noise_scale(self.device)
        self.term_noise = scale if bool((scale != 0).any()) else None
        return layout

    def on_reset(self, mask: torch.Tensor) -> None:
        """Draw the reset-time quantities of the resetting worlds (those whose last draw is ``frequency`` env steps
        old) and clear their action history."""
        due = mask & (self.since_draw >= self.frequency) if self.frequency > 1 else mask
        self.since_draw.masked_fill_(due, 0)  # IsaacGymEnvs' randomize_buf: zeroed where the draw happens
        self._draw_params(due, "reset")
        if self.max_delay:
            self.action_history.masked_fill_(mask.view(1, -1, 1), 0.0)
            if self.delay_spec is not None and self.delay_spec.apply == "reset":
                self._draw_delay(mask)

    def before_physics(self, progress: torch.Tensor) -> None:
        """Interval draws and pushes for the worlds whose interval is due (by their episode's step count)."""
        for p in self.params:
            if p.spec.apply == "interval":
                due = (progress % p.spec.interval == 0) & (progress > 0)
                self._draw_param(p, due)
                if p.quantity.prop.changes_inertia:
                    self._update_inertia_constants(due)
        if self.delay_spec is not None and self.delay_spec.apply == "interval":
            self._draw_delay((progress % self.delay_spec.interval == 0) & (progress > 0))
        if self.push_spec is not None:
            due = ((progress % self.push_spec.interval == 0) & (progress > 0)).unsqueeze(1)
            vel = self.sim.root_lin_vel[:, :2]
            kick = self.sample(self.push_spec, (self.num_envs, 2))
            new = kick if self.push_spec.operation == "set" else vel + kick
            vel.copy_(torch.where(due, new, vel))

    def actions(self, actions: torch.Tensor) -> torch.Tensor:
        """The actions that reach the task this step: delayed by each env's delay, then noised."""
        if self.max_delay:
            self.history_head.add_(1).remainder_(self.max_delay + 1)
            self.action_history.index_copy_(0, self.history_head.view(1), actions.unsqueeze(0))
            slot = (self.history_head - self.delay).remainder(self.max_delay + 1)
            actions = self.action_history.gather(0, slot.view(1, -1, 1).expand(1, *actions.shape)).squeeze(0)
        if self.action_noise is not None:
            actions = self.combine(self.action_noise, actions, self._noise("actions", self.action_noise,
                                                                           self.action_corr, actions.shape))
        return actions

    def observations(self, obs: torch.Tensor) -> None:
        """Add the per-term and the section-wide observation noise to the policy observation, in place."""
        if self.term_noise is not None:
            obs += (2.0 * torch.rand_like(obs) - 1.0) * self.term_noise
        if self.obs_noise is not None:
            obs.copy_(self.combine(self.obs_noise, obs, self._noise("observations", self.obs_noise, self.obs_corr,
                                                                    obs.shape)))

    def _noise(self, name: str, spec: Spec, corr: Spec | None, shape: torch.Size) -> torch.Tensor:
        """This step's draws of ``spec``, plus the correlated offsets of ``corr``: drawn once, then anew every
        ``frequency`` env steps (masked, no host sync)."""
        x = self.sample(spec, shape)
        if corr is None:
            return x
        if name not in self.correlated or self.correlated[name].shape != shape:  # else at the first (eager) step
            self.correlated[name] = self.sample(corr, shape)
        offsets = self.correlated[name]
        due = torch.remainder(self.step_count, self.frequency) == 0
        offsets.copy_(torch.where(due, self.sample(corr, shape), offsets))
        return x + offsets

    def count_step(self) -> None:
        self.since_draw.add_(1)

    # ---------------------------------------------------------------- delay
    def setup_delay(self, nominal: int, num_actions: int) -> None:
        """Allocate the action ring buffer: ``nominal`` (env.control.actionDelay) plus the randomised range."""
        if nominal < 0:
            raise ConfigError(f"env.control.actionDelay={nominal} is invalid: give a whole number of policy steps >= 0")
        self.nominal_delay = int(nominal)
        if self.action_corr is not None:
            self.correlated["actions"] = self.sample(self.action_corr, (self.num_envs, num_actions))
        self.max_delay = self.nominal_delay + (int(self.delay_spec.hi) if self.delay_spec is not None else 0)
        self.delay = torch.full((self.num_envs,), self.nominal_delay, dtype=torch.long, device=self.device)
        if self.max_delay:
            self.action_history = torch.zeros((self.max_delay + 1, self.num_envs, num_actions), device=self.device)
            self.history_head = torch.zeros((), dtype=torch.long, device=self.device)
            if self.delay_spec is not None:
                self._draw_delay(torch.ones(self.num_envs, dtype=torch.bool, device=self.device))

    def _draw_delay(self, mask: torch.Tensor) -> None:
        lo, hi = int(self.delay_spec.lo), int(self.delay_spec.hi)
        new = self.nominal_delay + torch.randint(lo, hi + 1, (self.num_envs,), device=self.device)
        self.delay.copy_(torch.where(mask, new, self.delay))
