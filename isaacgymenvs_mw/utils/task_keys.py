"""Misspelt keys inside a task YAML, told in one line (a command-line typo already is: Hydra refuses the key).

A key a task does not read is silently ignored by the task (``clipAction`` leaves action clipping at its default), and
a required key spelt wrong is a KeyError deep in the task. Which keys a task reads is known only to its code, so the
check works by spelling: a key name that no YAML of this project uses and docs/config.md does not name, but that is
spelt almost like one that does (``resetDst`` / ``resetDist``, ``defaultDriveMod`` / ``defaultDriveMode``), is taken
for a typo. For a task of this project (its YAML's ``name:`` is one of ``cfg/task``'s) that is an error; for a task of
the user's own, whose code may read the key, a warning line.
"""

from __future__ import annotations

import difflib
import functools
import re
import warnings
from pathlib import Path
from typing import Any, Iterator

import yaml

from isaacgymenvs_mw.utils.errors import ConfigError

SECTIONS = ("env", "task")  # the sections checked here (the sim section's keys are checked exactly, sim/request.py)
CUTOFF = 0.85  # difflib's similarity above which an unknown key is taken for a known one misspelt


def _yaml_keys(node: Any) -> Iterator[str]:
    if isinstance(node, dict):
        for key, value in node.items():
            yield str(key)
            yield from _yaml_keys(value)
    elif isinstance(node, list):
        for value in node:
            yield from _yaml_keys(value)


@functools.lru_cache(maxsize=None)
def known_names(cfg_dir: Path) -> frozenset[str]:
    """Every key name the project's task YAMLs (``cfg/task``, ``cfg/legged``) use, and every name docs/config.md
    writes in backquotes (the keys read with a code default, absent from the shipped YAMLs)."""
    names: set[str] = set()
    for folder in ("task", "legged"):
        for path in sorted((cfg_dir / folder).glob("*.yaml")):
            names.update(_yaml_keys(yaml.safe_load(path.read_text(encoding="utf-8"))))
    docs = cfg_dir.parent / "docs" / "config.md"
    if docs.is_file():
        for token in re.findall(r"`([A-Za-z_][A-Za-z0-9_.]*)", docs.read_text(encoding="utf-8")):
            names.update(token.split("."))
    return frozenset(names)


@functools.lru_cache(maxsize=None)
def shipped_task_names(cfg_dir: Path) -> frozenset[str]:
    return frozenset(path.stem for path in (cfg_dir / "task").glob("*.yaml"))


def _paths(node: Any, prefix: str) -> Iterator[tuple[str, str]]:
    """(dotted path, key name) of every key under ``node``."""
    if isinstance(node, dict):
        for key, value in node.items():
            path = f"{prefix}.{key}"
            yield path, str(key)
            yield from _paths(value, path)


def misspelt_keys(task_cfg: dict, cfg_dir: Path) -> list[tuple[str, str]]:
    """(the key as typed on the command line, the known name it is spelt like) for each likely typo."""
    known = known_names(cfg_dir)
    found = []
    for section in SECTIONS:
        for path, name in _paths(task_cfg.get(section), f"task.{section}"):
            if name in known:
                continue
            close = difflib.get_close_matches(name, known, n=1, cutoff=CUTOFF)
            if close:
                found.append((path, close[0]))
    return found


def check_task_keys(task_cfg: dict, yaml_path: Path | None, cfg_dir: Path) -> None:
    """Refuse (a task of this project) or warn about (a user's own task) the likely typos in the task YAML."""
    typos = misspelt_keys(task_cfg, cfg_dir)
    if not typos:
        return
    where = f"{yaml_path}" if yaml_path is not None else f"task/{task_cfg.get('name')}.yaml"
    listing = "; ".join(f"{path} (did you mean {path.rsplit('.', 1)[0]}.{name}?)" for path, name in typos)
    if str(task_cfg.get("name")) in shipped_task_names(cfg_dir):
        raise ConfigError(f"{where}: {listing}: no such key is read by task {task_cfg.get('name')} "
                          "(docs/config.md lists its keys)")
    warnings.warn(f"{where}: {listing}: not a key of the framework's; if your task reads it, ignore this",
                  RuntimeWarning, stacklevel=2)
