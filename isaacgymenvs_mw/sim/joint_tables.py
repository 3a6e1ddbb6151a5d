"""Per-joint and per-body YAML values (``{joint name or regex: value}``) resolved against a model's names, with
one-line errors naming the key as the user typed it (sim/request.py and the tasks read them)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from isaacgymenvs_mw.sim.names import name_matches
from isaacgymenvs_mw.utils.config import real_number
from isaacgymenvs_mw.utils.errors import ConfigError


def match_body_names(patterns: Sequence[str] | str | None, body_names: Sequence[str], key: str) -> list[str]:
    """Bodies that any of the patterns selects (``name_matches``: a full match), in model order; a pattern that
    selects no body is an error naming ``key``."""
    if isinstance(patterns, str):
        patterns = [patterns]
    out: list[str] = []
    for pattern in patterns or []:
        out += [body_names[i] for i in name_matches(pattern, body_names, key, "bodies") if body_names[i] not in out]
    return out


def match_joint_values(
    patterns: Mapping[str, object] | None, joint_names: Sequence[str], key: str, default: object | None = None
) -> dict[str, object]:
    """Resolve a {pattern: value} YAML mapping to {joint: value}.

    A pattern selects every joint whose whole name it matches (``name_matches``: ``".*_HAA"`` -> all *_HAA joints).
    A key that is a joint's own name wins over the other patterns; among patterns the first in YAML order wins. A
    pattern that selects no joint is an error naming the key, and so is a value that is not a mapping.
    """
    patterns = joint_table(patterns, key)
    selected = {pattern: set(name_matches(pattern, joint_names, key, "joints")) for pattern in patterns}
    resolved: dict[str, object] = {}
    for i, name in enumerate(joint_names):
        if name in patterns:
            resolved[name] = patterns[name]
            continue
        for pattern, value in patterns.items():
            if i in selected[pattern]:
                resolved[name] = value
                break
        else:
            if default is not None:
                resolved[name] = default
    return resolved


def joint_table(patterns: object, key: str, one_for_all: bool = False) -> dict[str, object]:
    """A per-joint YAML value as a {pattern: value} dict: a mapping as given, nothing as {}, and with
    ``one_for_all`` a plain number as every joint's value; anything else (text, a list) is an error naming ``key``."""
    if patterns is None:
        return {}
    if hasattr(patterns, "items"):
        return dict(patterns)
    number = isinstance(patterns, (int, float)) and not isinstance(patterns, bool)
    if one_for_all and number:
        return {".*": patterns}
    also = ", e.g. {'.*': 20.0}, or one number for every joint" if one_for_all else ""
    raise ConfigError(f"{key}={patterns!r} is invalid: give a mapping {{joint or regex: value}}{also}")


def match_joint_numbers(patterns: Mapping[str, object] | float | None, joint_names: Sequence[str], key: str,
                        default: float | None = None, low: float | None = None) -> dict[str, float]:
    """``match_joint_values`` for a per-joint number (gains, armature, limits, angles): each value must be a
    number (>= ``low`` when given); a bad one is an error naming ``key``, the pattern and the value. A plain number
    stands for every joint (``stiffness: 20`` is ``{'.*': 20}``): the command line's
    ``task.env.control.stiffness=20`` replaces the YAML's mapping, and means that."""
    table = joint_table(patterns, key, one_for_all=True)
    single = not hasattr(patterns, "items")  # a plain number: its key is the whole key, as the user typed it
    for pattern, value in table.items():
        real_number(value, key if single else f"{key}[{pattern!r}]", low=low)
    return {name: float(value) for name, value in match_joint_values(table, joint_names, key, default).items()}
