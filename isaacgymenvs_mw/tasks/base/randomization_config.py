"""``task.randomize`` + ``task.randomization_params`` parsed into what the randomisation layer's parts need
(tasks/base/randomization.py): noise, delay and push specs and the model quantities, each checked as the YAML says
it (one distribution's keys: randomization_spec.py). No model and no device here."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

from isaacgymenvs_mw.tasks.base.randomization_spec import (
    DRAW_KEYS,
    MAIN_ACTOR,
    NOISE_KEYS,
    QUANTITIES,
    REFUSED,
    SECTIONS,
    SELECTORS,
    SIM_QUANTITIES,
    Quantity,
    Spec,
    _interval_steps,
    _parse_spec,
)
from isaacgymenvs_mw.utils.config import whole_number
from isaacgymenvs_mw.utils.errors import ConfigError

ROOT = "task.randomization_params"


class Entry(NamedTuple):
    """One model quantity of the YAML, before it is bound to the model (randomization_model.py)."""

    spec: Spec
    quantity: Quantity
    patterns: list[str] | None  # the names / regular expressions of its selector, None: every element
    selector: str | None        # bodies, geoms, joints or actuators
    actor: str | None           # IsaacGymEnvs' per-actor level (actor_params.<actor>.<group>), None: the scene


@dataclass
class NoiseSpecs:
    """The ``observations`` or ``actions`` section: per-step noise and IsaacGymEnvs' correlated offsets."""

    noise: Spec | None = None
    correlated: Spec | None = None


@dataclass
class RandomizationConfig:
    """Everything ``task.randomization_params`` asks for (all empty when ``task.randomize`` is off)."""

    enabled: bool
    # IsaacGymEnvs' frequency: env steps an env's reset-time draws wait since its last draw, and between new
    # correlated noise offsets.
    frequency: int = 1
    observations: NoiseSpecs = field(default_factory=NoiseSpecs)
    obs_terms: Any = None  # observations.terms: {term: noise}, checked against the task's layout later
    actions: NoiseSpecs = field(default_factory=NoiseSpecs)
    delay: Spec | None = None
    push: Spec | None = None
    entries: list[Entry] = field(default_factory=list)


def parse_randomization(task_cfg: dict | None, control_dt: float) -> RandomizationConfig:
    """Check and parse the task YAML's randomisation keys; ``control_dt`` turns ``interval_s`` into env steps."""
    task_cfg = dict(task_cfg or {})
    enabled = bool(task_cfg.get("randomize", False))
    params = dict(task_cfg.get("randomization_params") or {}) if enabled else {}
    unknown = sorted(set(params) - set(SECTIONS))
    if unknown:
        raise ConfigError(f"{ROOT}.{unknown[0]}: unknown section (all unknown: {unknown}); valid sections: "
                          f"{list(SECTIONS)}")
    cfg = RandomizationConfig(enabled, frequency=whole_number(params.get("frequency", 1), f"{ROOT}.frequency", 1))
    cfg.observations, cfg.obs_terms = _parse_noise(params, "observations", extra=("terms",))
    cfg.actions, delay_raw = _parse_noise(params, "actions", extra=("delay",))
    if delay_raw is not None:
        cfg.delay = _parse_spec(delay_raw, f"{ROOT}.actions.delay", DRAW_KEYS, operations=("additive",))
        if cfg.delay.distribution != "uniform" or cfg.delay.lo < 0 \
                or cfg.delay.lo != int(cfg.delay.lo) or cfg.delay.hi != int(cfg.delay.hi):
            raise ConfigError(f"{ROOT}.actions.delay: give range: [low, high] of whole policy steps >= 0 with "
                              "distribution: uniform (every whole number in the range is equally likely)")
        _set_interval(cfg.delay, delay_raw, control_dt)
    if "push" in params:
        raw = params["push"]
        cfg.push = _parse_spec(raw, f"{ROOT}.push", NOISE_KEYS + ("interval_s", "interval_steps"),
                               operations=("set", "additive"), default_apply="interval")
        cfg.push.interval = _interval_steps(raw, f"{ROOT}.push", control_dt)
    for name, raw in dict(params.get("sim_params") or {}).items():
        key = f"{ROOT}.sim_params.{name}"
        if name not in SIM_QUANTITIES:
            raise ConfigError(f"{key}: unknown parameter; valid: {list(SIM_QUANTITIES)}")
        cfg.entries.append(_entry(raw, key, SIM_QUANTITIES[name], control_dt))
    for group, quantities, actor in _actor_groups(dict(params.get("actor_params") or {})):
        where = f"{ROOT}.actor_params.{actor + '.' if actor else ''}{group}"
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
                cfg.entries.append(_entry(item, key if not isinstance(raw, list) else f"{key}[{i}]",
                                          QUANTITIES[group][name], control_dt, actor))
    return cfg


def _actor_groups(params: dict) -> list[tuple[str, Any, str | None]]:
    """(group, its quantities, actor or None) of ``actor_params``: a group at the top applies to the whole scene;
    IsaacGymEnvs' per-actor level ``<actor>.<group>`` to one actor (an env.assets name, or MAIN_ACTOR)."""
    out = []
    for name, node in params.items():
        if name in QUANTITIES:
            out.append((name, node, None))
            continue
        key = f"{ROOT}.actor_params.{name}"
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


def _parse_noise(params: dict, section: str, extra: tuple[str, ...]) -> tuple[NoiseSpecs, Any]:
    """The noise and correlated specs of the observations or actions section, and its extra key's value."""
    raw = params.get(section)
    if raw is None:
        return NoiseSpecs(), None
    key = f"{ROOT}.{section}"
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
    return NoiseSpecs(spec, corr), (extras[0] if extras else None)


def _set_interval(spec: Spec, raw: dict, control_dt: float) -> None:
    if spec.apply == "interval":
        spec.interval = _interval_steps(raw, spec.key, control_dt)
    elif "interval_s" in raw or "interval_steps" in raw:
        raise ConfigError(f"{spec.key}: interval_s / interval_steps need apply: interval")


def _entry(raw: Any, key: str, quantity: Quantity, control_dt: float, actor: str | None = None) -> Entry:
    allowed = DRAW_KEYS + ((quantity.selects,) if quantity.selects else ())
    if quantity.selects == "geoms":
        allowed += ("bodies", "num_buckets")  # PhysX's material buckets: meaningful for surfaces only
    spec = _parse_spec(raw, key, allowed)
    if "num_buckets" in raw:
        spec.buckets = whole_number(raw["num_buckets"], f"{key}.num_buckets", 1)
        if spec.schedule is not None:  # the bucket values are drawn once, at startup, where a schedule is at 0
            raise ConfigError(f"{key}.num_buckets={raw['num_buckets']!r} and {key}.schedule={spec.schedule!r} "
                              "cannot go together: the buckets are drawn once, at startup; give one of them")
    _set_interval(spec, raw, control_dt)
    if quantity.minimum is not None:
        _check_positive(spec, quantity)
    selector = None
    patterns = None
    for name in SELECTORS:
        if name in raw and name in allowed:
            if selector is not None:
                raise ConfigError(f"{key}: give either {selector} or {name}, not both")
            selector, value = name, raw[name]
            patterns = [value] if isinstance(value, str) else [str(v) for v in value]
    return Entry(spec, quantity, patterns, selector, actor)


def _check_positive(spec: Spec, quantity: Quantity) -> None:
    """A quantity that must stay >= 0 (> 0) may not be given a range that takes it below."""
    what = "> 0" if quantity.minimum > 0 else ">= 0"
    if spec.operation == "scaling":
        low = spec.lo if spec.distribution != "gaussian" else spec.lo - 3.0 * spec.hi
        if low < 0 or (quantity.minimum > 0 and low <= 0):
            raise ConfigError(f"{spec.key}.range={[spec.lo, spec.hi]}: this quantity must stay {what}; a scaling "
                              "range must be > 0 (gaussian: mean - 3 std > 0)")
    # additive ranges are checked against the nominal values when the layer binds to the model
