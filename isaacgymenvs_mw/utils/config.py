"""Hydra/OmegaConf helpers: IsaacGymEnvs' resolvers, composing the config outside train.py, run-key checks."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Sequence

from omegaconf import DictConfig, OmegaConf, open_dict
from omegaconf.errors import MissingMandatoryValue

from isaacgymenvs_mw.utils.errors import ConfigError, MissingFileError
from isaacgymenvs_mw.utils.task_keys import check_task_keys
from isaacgymenvs_mw.utils.user_config import user_config_view

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

# Folders given to compose_config(config_dir=...), searched before cfg/ as --config-dir is (see _UserConfigFirst).
_EXTRA_CONFIG_DIRS: list[str] = []


def _register_user_config_first() -> None:
    """Make a folder given with ``--config-dir`` (or ``compose_config(config_dir=...)``) searched before the project's
    cfg/. Hydra searches cfg/ first, so a user's ``train/AntPPO.yaml`` (IsaacGymEnvs' rl_games YAML, say) would be
    silently replaced by the project's file of the same name; with this, the user's file is the one used."""
    from hydra.core.config_search_path import ConfigSearchPath
    from hydra.core.plugins import Plugins
    from hydra.plugins.search_path_plugin import SearchPathPlugin

    class UserConfigFirst(SearchPathPlugin):
        def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
            path = search_path.get_path()
            main = next((i for i, e in enumerate(path) if e.provider == "main"), None)
            if main is None:
                return
            for folder in _EXTRA_CONFIG_DIRS:  # less what cannot replace ours (utils/user_config.py)
                search_path.append("command-line", f"file://{user_config_view(folder, CFG_DIR)}")
            users = [e for e in path if e.provider == "command-line"]
            rest = [e for e in path if e.provider != "command-line"]
            main = next(i for i, e in enumerate(rest) if e.provider == "main")
            path[:] = rest[:main] + users + rest[main:]

    UserConfigFirst.__module__ = __name__
    UserConfigFirst.__qualname__ = "UserConfigFirst"
    Plugins.instance().register(UserConfigFirst)


_register_user_config_first()


LEARNERS = ("rsl_rl", "rl_games")  # the run key `learner`: which library trains (docs/config.md#learners)


def with_learner_default(overrides: Sequence[str]) -> list[str]:
    """``learner=rl_games`` without ``train=``: the task's shipped rl_games recipe, ``cfg/train/rl_games/<Task>PPO``
    (Hydra's defaults list cannot depend on a plain key, so the choice is added as an override). A bad value of
    ``learner`` fails naming it; the train YAML's own schema is checked against it later (learning/train_config.py)."""
    overrides = list(overrides)
    learner = [o.split("=", 1)[1] for o in overrides if o.startswith("learner=")]
    if not learner:
        return overrides
    if learner[-1] not in LEARNERS:
        raise ConfigError(f"learner={learner[-1]!r} is invalid: choose one of {list(LEARNERS)}")
    if learner[-1] == "rl_games" and not any(o.split("=", 1)[0].lstrip("+~") == "train" for o in overrides):
        overrides.append("train=rl_games/${task}PPO")
    return overrides


def split_config_dirs(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """The folders of ``argv``'s ``--config-dir D`` / ``-cd D`` options, and the rest of ``argv``."""
    folders, rest, args = [], [], list(argv)
    while args:
        arg = args.pop(0)
        if arg in ("--config-dir", "-cd") and args:
            folders.append(args.pop(0))
        elif arg.startswith("--config-dir="):
            folders.append(arg.split("=", 1)[1])
        else:
            rest.append(arg)
    return folders, rest


def take_config_dirs(argv: Sequence[str]) -> list[str]:
    """``argv`` without its ``--config-dir D`` / ``-cd D`` options, whose folders are searched before cfg/ from now on
    in this process (Hydra would search them after it: see _register_user_config_first)."""
    folders, rest = split_config_dirs(argv)
    for folder in folders:
        path = Path(folder).expanduser().resolve()
        if not path.is_dir():
            raise MissingFileError(f"--config-dir {folder}: no such folder ({path}); give the folder that holds your "
                                   "task/ and train/ YAMLs")
        _EXTRA_CONFIG_DIRS.append(str(path))
    return rest


def compose_config(overrides: Sequence[str] = (), config_dir: str | Path | None = None) -> DictConfig:
    """The same config train.py would see for these command-line overrides (e.g. ['task=Cartpole', 'num_envs=8']).

    ``config_dir``: a folder of your own with ``task/<Name>.yaml`` and ``train/<Name>PPO.yaml``, searched before the
    repository's ``cfg/`` (as ``python train.py --config-dir <dir>`` is).
    """
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    overrides = with_learner_default(overrides)
    if config_dir is not None:
        folder = Path(config_dir).expanduser().resolve()
        if not folder.is_dir():
            raise MissingFileError(f"config_dir '{config_dir}' is not a folder (it should hold task/ and train/)")
        _EXTRA_CONFIG_DIRS.append(str(folder))
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CFG_DIR), version_base="1.3"):
            cfg = compose(config_name="config", overrides=overrides, return_hydra_config=True)
    finally:
        _EXTRA_CONFIG_DIRS.clear()
    record_task_dir(cfg, cfg.hydra)
    check_task_yaml_keys(cfg, cfg.hydra)
    with open_dict(cfg):
        del cfg["hydra"]  # train.py's config has no hydra node either
    return cfg


def task_yaml_path(hydra_cfg: DictConfig) -> Path | None:
    """The task YAML Hydra loaded, or None (a task from a package, not a folder).

    Hydra does not record which file a config group option came from, so this repeats its lookup: the first
    folder of the config search path (``hydra.runtime.config_sources``, in order) holding ``task/<choice>.yaml``.
    """
    choice = hydra_cfg.runtime.choices.get("task")
    if not choice:
        return None
    for source in hydra_cfg.runtime.config_sources:
        if source.get("schema") != "file":
            continue
        candidate = Path(source.path) / "task" / f"{choice}.yaml"
        if candidate.is_file():
            return candidate.resolve()
    return None


def check_task_yaml_keys(cfg: DictConfig, hydra_cfg: DictConfig) -> None:
    """Likely typos among the task YAML's keys, named with the file (utils/task_keys.py)."""
    if "task" in cfg and isinstance(cfg.task, DictConfig):
        check_task_keys(OmegaConf.to_container(cfg.task, resolve=False), task_yaml_path(hydra_cfg), CFG_DIR)


def record_task_dir(cfg: DictConfig, hydra_cfg: DictConfig) -> None:
    """Store the folder of the task YAML Hydra loaded as ``task.yaml_dir`` (relative ``assetRoot`` resolves there)."""
    path = task_yaml_path(hydra_cfg)
    if path is not None and "task" in cfg:
        with open_dict(cfg):
            cfg.task.yaml_dir = str(path.parent)


def check_task_yaml(cfg: DictConfig, hydra_cfg: DictConfig) -> None:
    """Fail naming the file when the task YAML is empty or lacks ``name:`` (OmegaConf would only say that the
    interpolation ``task.name`` of ``task_name`` is not found)."""
    choice = hydra_cfg.runtime.choices.get("task")
    path = task_yaml_path(hydra_cfg) or f"task/{choice}.yaml"
    task = cfg.get("task")
    if not task:
        raise ConfigError(f"task={choice}: {path} is empty; a task YAML needs name: (the registered task class) "
                          "and its env and sim sections")
    if "name" not in task:
        raise ConfigError(f"task={choice}: {path} has no name: key; give the registered task class to build, "
                          f"e.g. name: {choice}")


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
        raise ConfigError(f"{key}={value!r} is invalid: give a whole number >= {minimum}")
    return number


def check_entry(entry, key: str, keys: Sequence[str]) -> None:
    """``entry`` (one named entry of a YAML mapping, e.g. ``env.assets.<name>``) is a mapping of ``keys`` only;
    otherwise an error naming ``key``."""
    if not hasattr(entry, "items"):
        raise ConfigError(f"{key}={entry!r} is invalid: give a mapping with keys {list(keys)}")
    unknown = sorted(str(k) for k in entry if k not in keys)
    if unknown:
        raise ConfigError(f"{key}: unknown key(s) {unknown}; valid keys: {list(keys)}")


def real_number(value, key: str, low: float | None = None, high: float | None = None, low_open: bool = False) -> float:
    """``value`` as a float in [low, high] (``low_open``: above low); text, booleans, NaN fail naming ``key``."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok and low is not None:
        ok = value > low if low_open else value >= low
    if ok and high is not None:
        ok = value <= high
    if not ok:
        bounds = [f"{'>' if low_open else '>='} {low}" if low is not None else "", f"<= {high}" if high else ""]
        wanted = " and ".join(b for b in bounds if b)
        raise ConfigError(f"{key}={value!r} is invalid: give {f'a number {wanted}' if wanted else 'a finite number'}")
    return float(value)


def one_of(value, key: str, choices: tuple[str, ...]) -> str:
    """``value`` if it is one of ``choices``; anything else fails naming ``key`` and the choices."""
    if not isinstance(value, str) or value not in choices:
        raise ConfigError(f"{key}={value!r} is invalid: choose one of {list(choices)}")
    return value


def boolean(value, key: str) -> bool:
    """``value`` if it is True or False; anything else (1, 'yes', '') fails naming ``key``."""
    if not isinstance(value, bool):
        raise ConfigError(f"{key}={value!r} is invalid: give True or False")
    return value


# Run-level keys of cfg/config.yaml and what each takes; num_envs and max_iterations may also be '' (YAML default).
# num_envs has its own check (check_num_envs), shared with env.numEnvs and the Simulator.
_RUN_BOOLEANS = ("torch_deterministic", "deterministic", "headless", "test", "multi_gpu", "capture_video", "verbose",
                 "sweep_eval", "save_best", "pbt")
_RUN_WHOLE_NUMBERS = {"max_iterations": 0, "seed": -1, "graphics_device_id": -1,
                      "capture_video_freq": 1, "capture_video_len": 1}
MAX_WORLDS = 2**31 - 1  # Warp's array dimensions are signed 32-bit integers
_RUN_TEXT = ("task_module", "checkpoint", "runs_dir", "sim_device", "rl_device", "sweep_metric", "learner")
_RUN_NONEMPTY = ("runs_dir", "sim_device", "rl_device", "sweep_metric")


def check_run_config(cfg: DictConfig) -> None:
    """Fail on run-level keys that are out of range or of the wrong kind, before anything is allocated."""
    if cfg.get("num_envs", "") not in ("", None):
        check_num_envs(cfg.num_envs, "num_envs")
    for key, minimum in _RUN_WHOLE_NUMBERS.items():
        value = cfg.get(key, "")
        if not (value in ("", None) and key == "max_iterations"):
            whole_number(value, key, minimum)
    for key in _RUN_BOOLEANS:
        if key in cfg:
            boolean(cfg[key], key)
    if cfg.get("pbt", False) is True:
        raise ConfigError("pbt=True is not supported: population-based training (IsaacGymEnvs' DexPBT) restarts runs "
                          "from other runs' checkpoints; train one run, with pbt=False")
    cpu_threads(cfg.get("cpu_threads", 1))
    time_budget(cfg.get("max_train_time_s", ""))
    if cfg.get("learner", "rsl_rl") not in LEARNERS:
        raise ConfigError(f"learner={cfg.learner!r} is invalid: choose one of {list(LEARNERS)}")
    for key in _RUN_TEXT:
        value = cfg.get(key, "")
        if not isinstance(value, str) or (key in _RUN_NONEMPTY and not value.strip()):
            wanted = "a non-empty string" if key in _RUN_NONEMPTY else "a string"
            raise ConfigError(f"{key}={value!r} is invalid: give {wanted}")


def check_num_envs(value, key: str) -> int:
    """The number of envs (worlds) as an int from 1 to MAX_WORLDS, else a one-line error naming ``key`` as the user
    typed it: ``num_envs`` on the command line, ``env.numEnvs`` in a task YAML, ``numEnvs`` where the Simulator is
    built directly. The one check of it: the run config, the task settings and the Simulator all call this."""
    number = whole_number(value, key, 1)
    if number > MAX_WORLDS:
        raise ConfigError(f"{key}={value!r} is invalid: give a whole number from 1 to {MAX_WORLDS} "
                          "(MuJoCo Warp counts worlds in 32-bit integers)")
    return number


def time_budget(value) -> float | None:
    """The run key ``max_train_time_s``: None for '' (no budget), else seconds > 0."""
    if value in ("", None):
        return None
    return real_number(value, "max_train_time_s", low=0.0, low_open=True)


def cpu_threads(value) -> int:
    """The run key ``cpu_threads`` as a thread count: a whole number >= 1, or ``auto`` for all cores.

    One thread is the default: torch's OpenMP threads wait for each other by spinning, so beside one other busy
    process on 2 cores Cartpole trained at 15 k env-steps/s with two threads and 67 k with one (docs/BENCHMARKS.md)."""
    if isinstance(value, str) and value.strip().lower() == "auto":
        return os.cpu_count() or 1
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value)
    try:
        return whole_number(value, "cpu_threads", 1)
    except ConfigError:
        raise ConfigError(f"cpu_threads={value!r} is invalid: give a whole number >= 1 or auto (all "
                          f"{os.cpu_count()} cores)") from None


def to_dict(cfg: DictConfig) -> dict:
    """``cfg`` resolved into plain dicts and lists; a ``???`` (mandatory) value left unset fails naming its key."""
    try:
        return OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True)  # type: ignore[return-value]
    except MissingMandatoryValue as err:
        raise ConfigError(f"{err.full_key} has no value (??? in the YAML it comes from, e.g. cfg/legged/base.yaml "
                         "for the legged robots): set it in the task YAML or on the command line") from None
