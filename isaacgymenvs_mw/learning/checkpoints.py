"""Where a run's files go and which of them count: the checkpoint a run is given (``checkpoint=``), the latest whole
checkpoint of a folder, and whether ``runs_dir`` can be written. Light on imports (no torch): train.py checks these
before the learning stack loads."""

from __future__ import annotations

import os
import re
import tempfile
import zipfile
from pathlib import Path
from typing import Iterable

from omegaconf import DictConfig

from isaacgymenvs_mw.utils.errors import ConfigError, MissingFileError

CHECKPOINT_NAME = re.compile(r"model_(\d+)(?:_interrupted)?\.pt")  # saved at an iteration (learning/runner.py)


def checkpoint_iteration(name: str) -> int | None:
    """The iteration in a checkpoint's file name (model_400.pt, model_212_interrupted.pt), or None (model_best.pt)."""
    match = CHECKPOINT_NAME.fullmatch(name)
    return None if match is None else int(match.group(1))


def latest_checkpoint(paths: Iterable[Path]) -> Path | None:
    """The checkpoint of the highest iteration among ``paths`` (by number: model_9 comes before model_10), or None.

    Only whole files count: torch.save writes a zip archive, whose directory is its last part, so a file cut short
    (a full disk, before writes became atomic) or left empty is never the one recommended."""
    numbered = [(n, p) for p in paths if (n := checkpoint_iteration(p.name)) is not None and zipfile.is_zipfile(p)]
    return max(numbered)[1] if numbered else None


def checkpoint_path(cfg: DictConfig) -> Path | None:
    """``checkpoint=`` as an existing file (None when not given, which test mode refuses); its contents are read by
    the launcher, which has torch."""
    if not cfg.checkpoint:
        if cfg.test:
            raise ConfigError("test=True needs checkpoint=PATH to a model_*.pt written by a training run")
        return None
    path = Path(str(cfg.checkpoint)).expanduser().resolve()
    if path.is_dir():  # a run directory: name the file wanted, and the run's latest when it holds any
        latest = latest_checkpoint(path.glob("model_*.pt"))
        hint = f"its latest: checkpoint={latest}" if latest else "none is in it"
        raise ConfigError(f"checkpoint='{cfg.checkpoint}': {path} is a directory; give a model_*.pt file written by "
                          f"a training run ({hint})")
    if not path.is_file():
        raise MissingFileError(f"checkpoint='{cfg.checkpoint}': no such file ({path})")
    return path


def check_runs_dir(runs_dir: str) -> None:
    """Fail naming ``runs_dir`` if a training run could not write there; leaves nothing behind.

    Permissions alone do not tell (root passes every access check, yet cannot create folders in /proc), so the check
    writes: a file in ``runs_dir`` if it exists, else a folder in the nearest folder above it that does, each under a
    name of its own and removed at once. Nothing shared is created or removed, so runs started side by side on one new
    folder tree (a round of seeds) cannot disturb each other's checks.
    """
    path = Path(runs_dir).expanduser().absolute()
    nearest = next(p for p in (path, *path.parents) if p.exists())
    try:
        if nearest == path:
            with tempfile.TemporaryFile(dir=path):
                pass
        else:
            os.rmdir(tempfile.mkdtemp(dir=nearest))
    except OSError as err:
        raise ConfigError(f"runs_dir={runs_dir!r} cannot be written to ({err.strerror or err}): give a folder "
                          "you can create and write in") from err
