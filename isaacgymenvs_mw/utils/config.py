"""Hydra/OmegaConf helpers: IsaacGymEnvs' resolvers, composing the config outside train.py, run-key checks."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from omegaconf import DictConfig, OmegaConf

CFG_DIR = Path(__file__).resolve().parents[2] / "cfg"


def _resolve_default(default, arg):
    return default if arg == "" or arg is None else arg


def register_resolvers() -> None:
    """Resolvers used by the YAML files (same names and meaning as IsaacGymEnvs)."""
    resolvers = {
        "eq": lambda a, b: str(a).lower() == str(b).lower(),
        "contains": lambda a, b: str(a).lower() in str(b).lower(),
        "if": lambda pred, a, b: a if pred else b,
        "resolve_default": _resolve_default,
    }
    for name, fn in resolvers.items():
        if not OmegaConf.has_resolver(name):
            OmegaConf.register_new_resolver(name, fn)


register_resolvers()


def compose_config(overrides: Sequence[str] = ()) -> DictConfig:
    """The same config train.py would see for these command-line overrides (e.g. ['task=Cartpole', 'num_envs=8'])."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CFG_DIR), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def whole_number(value, key: str, minimum: int) -> int:
    """``value`` as an int >= minimum; booleans, fractions and text fail with a message naming ``key``."""
    ok = not isinstance(value, bool)
    if ok and isinstance(value, float):
        ok = value.is_integer()
    if ok:
        try:
            number = int(value)
        except (TypeError, ValueError):
            ok = False
    if not ok or number < minimum:
        raise ValueError(f"{key}={value!r} is invalid: give a whole number >= {minimum}")
    return number


def check_run_config(cfg: DictConfig) -> None:
    """Fail on run-level keys that are out of range, before anything is allocated."""
    for key, minimum in (("num_envs", 1), ("max_iterations", 0)):
        value = cfg.get(key, "")
        if value not in ("", None):
            whole_number(value, key, minimum)


def to_dict(cfg: DictConfig) -> dict:
    return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
