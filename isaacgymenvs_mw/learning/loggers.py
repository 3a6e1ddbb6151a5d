"""Where training metrics go: ``train.runner.logger`` = ``tensorboard`` (default) or ``wandb``.

The keys are rsl-rl-lib's: ``logger: wandb`` with ``wandb_project`` (default: the experiment name), or rsl-rl-lib 5's
dict form ``logger: {class_name: WandbLogWriter, project_name: ...}``. The W&B writer is a TensorBoard writer that
also sends every scalar to W&B (rsl-rl-lib's design), so both hold the same metrics, and the events file stays in
the run directory. W&B runs offline when ``WANDB_MODE`` is unset and api.wandb.ai cannot be reached; its files go
to ``<run dir>/wandb`` (``wandb sync <run dir>/wandb/offline-run-*`` uploads them later).
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import socket
from pathlib import Path

from rsl_rl.utils.log_writer import LogWriter
from torch.utils.tensorboard import SummaryWriter

from isaacgymenvs_mw.utils.errors import ConfigError

LOGGERS = ("tensorboard", "wandb")
KEY = "train.runner.logger"
_WANDB_CLASS_NAMES = ("wandb", "WandbLogWriter", "rsl_rl.utils:WandbLogWriter", "rsl_rl.utils.wandb_log_writer:"
                      "WandbLogWriter")


def logger_kind(cfg: dict) -> tuple[str, str | None]:
    """(kind, W&B project) from the flattened runner config; an unknown logger fails listing the valid ones."""
    value = cfg.get("logger", "tensorboard")
    project = cfg.get("wandb_project")
    if isinstance(value, dict):
        name = value.get("class_name")
        project = value.get("project_name", project)
        kind = "wandb" if name in _WANDB_CLASS_NAMES else name
    else:
        kind = value
    if kind not in LOGGERS:
        raise ConfigError(f"{KEY}={value!r} is not a logger this runner writes: give one of {list(LOGGERS)} "
                         "(or {class_name: WandbLogWriter, project_name: ...})")
    return kind, project


def check_logger(cfg: dict) -> None:
    """Fail before anything is built when the logger is unknown or its package is not installed."""
    kind, _ = logger_kind(cfg)
    if kind == "wandb" and importlib.util.find_spec("wandb") is None:
        raise ConfigError(f"{KEY}=wandb needs the wandb package, which is not installed: pip install wandb "
                          f"(or set {KEY}=tensorboard)")


def make_writer(cfg: dict, log_dir: str, experiment: str, config: dict | None = None) -> SummaryWriter:
    """The writer for ``cfg['logger']``, writing into ``log_dir``; ``config`` (the resolved run config) goes to W&B."""
    kind, project = logger_kind(cfg)
    if kind == "wandb":
        return WandbWriter(log_dir, project or experiment, config)
    return SummaryWriter(log_dir, flush_secs=10)


def _reachable(host: str = "api.wandb.ai", port: int = 443, timeout: float = 2.0) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


class WandbWriter(SummaryWriter, LogWriter):
    """TensorBoard events plus the same scalars on W&B (as rsl-rl-lib's WandbLogWriter, with the run dir as W&B's
    dir and the run config attached). ``Runner.save`` uploads checkpoints through rsl-rl-lib's Logger."""

    def __init__(self, log_dir: str, project: str, config: dict | None = None) -> None:
        try:
            wandb = importlib.import_module("wandb")
        except ModuleNotFoundError:
            raise ConfigError(f"{KEY}=wandb needs the wandb package, which is not installed: "
                              "pip install wandb") from None
        super().__init__(log_dir, flush_secs=10)
        if not os.environ.get("WANDB_MODE") and not _reachable():
            os.environ["WANDB_MODE"] = "offline"
            print(f"[wandb] api.wandb.ai is not reachable: logging offline to {Path(log_dir) / 'wandb'} "
                  f"(upload later with `wandb sync {Path(log_dir) / 'wandb'}/offline-run-*`)", flush=True)
        self.wandb = wandb
        self.run = wandb.init(project=project, entity=os.environ.get("WANDB_USERNAME"), name=Path(log_dir).name,
                              dir=str(log_dir), config={"log_dir": str(log_dir), **(config or {})})

    def add_scalar(self, tag, scalar_value, global_step=None, walltime=None, new_style=False) -> None:
        super().add_scalar(tag, scalar_value, global_step=global_step, walltime=walltime, new_style=new_style)
        # "<tag>/time" repeats a metric against training seconds: W&B keeps one step axis (it records wall time
        # itself) and drops steps that go backwards, so those stay in TensorBoard only, as in rsl-rl-lib.
        if not tag.endswith("/time"):
            self.wandb.log({tag: scalar_value}, step=global_step)

    def save_model(self, model_path: str, it: int) -> None:
        self.wandb.save(model_path, base_path=os.path.dirname(model_path))

    def save_file(self, path: str) -> None:
        self.wandb.save(path, base_path=os.path.dirname(path))

    def stop(self) -> None:
        self.wandb.finish()
