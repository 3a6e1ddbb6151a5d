"""The one rule by which task YAML keys select names of the model (joints, bodies, geoms, actuators): a regular
expression that must match the whole name (docs/config.md, "Selecting names"). The model builder, the randomiser
and the cameras (a camera's ``body``) select with it."""

from __future__ import annotations

import re
from typing import Sequence

import mujoco

from isaacgymenvs_mw.utils.errors import ConfigError


def compile_pattern(pattern: object, key: str) -> re.Pattern:
    """``pattern`` as a regular expression; an invalid one is an error naming ``key``."""
    try:
        return re.compile(str(pattern))
    except re.error as err:
        raise ConfigError(f"{key}: '{pattern}' is not a valid regular expression ({err})") from None


def no_match_error(key: str, pattern: object, kind: str, names: Sequence[str], how: str = "") -> ConfigError:
    """The one error of a pattern that selects nothing: the key, the pattern and the names it could have selected."""
    singular = {"bodies": "body"}.get(kind, kind[:-1])
    return ConfigError(f"{key}: '{pattern}' matches no {singular}{how} (a pattern must match the whole name); "
                       f"{kind}: {list(names)}")


def name_matches(pattern: str, names: Sequence[str], key: str, kind: str) -> list[int]:  # kind: "joints", ...
    """Indices of the names that ``pattern``, a regular expression, matches as a whole (``re.fullmatch``).

    The one rule of every YAML key that selects names (joints, bodies, geoms, actuators; docs/config.md, "Selecting
    names"): ``"HAA"`` selects only a name ``HAA``, ``".*_HAA"`` every name ending in ``_HAA``. Selecting nothing is
    an error naming ``key``, the pattern and the names.
    """
    regex = compile_pattern(pattern, key)
    hits = [i for i, name in enumerate(names) if regex.fullmatch(name)]
    if not hits:
        raise no_match_error(key, pattern, kind, names)
    return hits


def one_body(spec: mujoco.MjSpec, pattern: str, key: str) -> str:
    """The one body of the composed scene whose whole name ``pattern`` matches (``name_matches``' rule)."""
    names = [b.name for b in spec.bodies if b.name != spec.worldbody.name]
    hits = name_matches(pattern, names, key, "bodies")
    if len(hits) != 1:
        raise ConfigError(f"{key}: '{pattern}' matches {len(hits)} bodies {[names[i] for i in hits]}; give a pattern "
                          "that selects one")
    return names[hits[0]]
