"""Hydra/OmegaConf helpers: IsaacGymEnvs' resolvers, composing the config outside train.py, run-key checks."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from omegaconf import DictConfig, OmegaConf, open_dict

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


def compose_config(overrides: Sequence[str] = (), config_dir: str | Path | None = None) -> DictConfig:
    """The same config train.py would see for these command-line overrides (e.g. ['task=Cartpole', 'num_envs=8']).

    ``config_dir``: a folder of your own with ``task/<Name>.yaml`` and ``train/<Name>PPO.yaml``, searched after the
    repository's ``cfg/`` (as ``python train.py --config-dir <dir>`` or ``hydra.searchpath=[file://<dir>]`` does).
    """
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    overrides = list(overrides)
    if config_dir is not None:
        folder = Path(config_dir).expanduser().resolve()
        if not folder.is_dir():
            raise FileNotFoundError(f"config_dir '{config_dir}' is not a folder (it should hold task/ and train/)")
        overrides.append(f"hydra.searchpath=[file://{folder}]")
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CFG_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides, return_hydra_config=True)
    record_task_dir(cfg, cfg.hydra)
    with open_dict(cfg):
        del cfg["hydra"]  # train.py's config has no hydra node either
    return cfg


def record_task_dir(cfg: DictConfig, hydra_cfg: DictConfig) -> None:
    """Store the folder of the task YAML Hydra loaded as ``task.yaml_dir`` (relative ``assetRoot`` resolves there).

    Hydra does not record which file a config group option came from, so this repeats its lookup: the first
    folder of the config search path (``hydra.runtime.config_sources``, in order) holding ``task/<choice>.yaml``.
    """
    choice = hydra_cfg.runtime.choices.get("task")
    if not choice or "task" not in cfg:
        return
    for source in hydra_cfg.runtime.config_sources:
        if source.get("schema") != "file":
            continue
        candidate = Path(source.path) / "task" / f"{choice}.yaml"
        if candidate.is_file():
            with open_dict(cfg):
                cfg.task.yaml_dir = str(candidate.parent.resolve())
            return


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
