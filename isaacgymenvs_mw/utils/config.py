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


def check_run_config(cfg: DictConfig) -> None:
    """Fail on run-level keys that are out of range, before anything is allocated."""
    num_envs = cfg.get("num_envs", "")
    if num_envs not in ("", None):
        try:
            ok = int(num_envs) >= 1
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ValueError(f"num_envs={num_envs!r} is invalid: give a whole number >= 1 (or leave it empty)")
    max_it = cfg.get("max_iterations", "")
    if max_it not in ("", None):
        try:
            ok = int(max_it) >= 0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ValueError(f"max_iterations={max_it!r} is invalid: give a whole number >= 0")


def to_dict(cfg: DictConfig) -> dict:
    return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
