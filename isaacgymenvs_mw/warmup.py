"""Fill the compile caches a training run of each listed task needs, without training:

    python -m isaacgymenvs_mw.warmup task=Go1,FrankaCabinet [num_envs=4096] [sim_device=cuda:0] [any train.py override]

A cold training run spends its first tens of seconds compiling: Warp's kernel modules for the task's model, and on a
GPU torch.compile's code for the post-physics step (Inductor, Triton). All of it lands in caches on disk that the next
process reads back. For each task this builds the task exactly as ``train.py`` would for the same overrides (the
same config composition), then runs one training iteration with no run folder: the env steps (the step compiled and,
on a GPU, captured after its eager steps) and one learner update. Nothing is saved: no run folder, no checkpoint, no
TensorBoard file. It prints one line per task: the seconds spent and what each cache folder gained.

torch.compile specialises the step on the tensors' shapes, so warm up with the ``num_envs`` (and task overrides) the
training runs will use; Warp's kernels do not depend on ``num_envs``. Every task name is checked before anything is
built: an unknown one ends the command with one line (docs/errors.md) and exit status 2.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from dataclasses import dataclass
from typing import Sequence

from isaacgymenvs_mw.utils.compile_cache import use_cache_folder
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.stop import PROCESS_STOP

PREFIX = "[warmup]"
USAGE = "task=Name[,Name...], e.g. task=Go1,FrankaCabinet"


@dataclass(frozen=True)
class CacheFolder:
    """One compile cache: the environment variable that moves it, its folder, and how many files it held."""

    variable: str
    path: str
    files: int


def count_files(path: str) -> int:
    """Files under ``path`` at any depth (0 where it does not exist)."""
    return sum(len(files) for _, _, files in os.walk(path))


def cache_folders(sim_device: str) -> list[CacheFolder]:
    """The folders a training run compiles into, as this process sees them: Warp's kernel cache, TorchInductor's
    cache, the one its Triton kernels go to (``TRITON_CACHE_DIR``; by default a ``triton`` folder inside Inductor's)
    and the CUDA driver's JIT cache (``CUDA_CACHE_PATH``; by default ``~/.nv/ComputeCache``)."""
    from torch._inductor.runtime.cache_dir_utils import default_cache_dir

    from isaacgymenvs_mw.sim.kernels import kernel_cache_dir
    from isaacgymenvs_mw.utils.device import resolve_device

    inductor = os.path.abspath(os.environ.get("TORCHINDUCTOR_CACHE_DIR") or default_cache_dir())
    folders = {"WARP_CACHE_PATH": kernel_cache_dir(resolve_device(sim_device, "sim_device")), "TORCHINDUCTOR_CACHE_DIR": inductor,
               "TRITON_CACHE_DIR": os.environ.get("TRITON_CACHE_DIR") or os.path.join(inductor, "triton"),
               "CUDA_CACHE_PATH": os.path.abspath(os.environ.get("CUDA_CACHE_PATH")
                                                  or os.path.expanduser(os.path.join("~", ".nv", "ComputeCache")))}
    return [CacheFolder(variable, path, count_files(path)) for variable, path in folders.items()]


def task_names(overrides: Sequence[str]) -> tuple[list[str], list[str]]:
    """The tasks of ``task=A,B`` (the last ``task=`` given, as Hydra takes it) and the other overrides."""
    given = [o.split("=", 1)[1] for o in overrides if o.startswith("task=")]
    rest = [o for o in overrides if not o.startswith("task=")]
    if not given:
        raise ConfigError(f"task is missing: give {USAGE}")
    names = list(dict.fromkeys(name.strip() for name in given[-1].split(",") if name.strip()))
    if not names:
        raise ConfigError(f"task={given[-1]!r} names no task: give {USAGE}")
    return names, rest


def warm_up(cfg) -> None:
    """Build the task of ``cfg`` as a training run does and run one iteration of it (env steps and one update),
    writing nothing but the compile caches."""
    from isaacgymenvs_mw.learning.launch import build_with_notice, seed_run
    from isaacgymenvs_mw.learning.learners import learner_for

    seed_run(cfg)
    learner = learner_for(cfg)
    learner.check()
    task = build_with_notice(cfg)
    make_runner, _ = learner.runner_factory(task)
    runner = make_runner()  # no log folder: learn() writes no checkpoint, summary or TensorBoard file
    runner.learn(1)
    task.close()


def report(name: str, seconds: float, before: list[CacheFolder], after: list[CacheFolder]) -> str:
    """One line: the task, the seconds spent, and each cache folder with the files it gained."""
    folders = ", ".join(f"{a.variable}={a.path} (+{a.files - b.files} files)" for b, a in zip(before, after))
    return f"{PREFIX} {name}: warmed up in {seconds:.1f} s; {folders}"


def main(argv: Sequence[str] | None = None) -> None:
    from isaacgymenvs_mw.utils.cli_errors import exit_on_input_error

    PROCESS_STOP.install()  # SIGINT / SIGTERM: one line and the signal's status, whatever is compiling
    use_cache_folder()  # ISAACGYMENVS_MW_CACHE: the one folder to ship (utils/compile_cache.py)
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        with exit_on_input_error("warmup"):
            from isaacgymenvs_mw.learning.train_config import check_before_start
            from isaacgymenvs_mw.utils.config import compose_config, split_config_dirs

            folders, overrides = split_config_dirs(argv)  # train.py's --config-dir (the last one given)
            config_dir = folders[-1] if folders else None
            names, rest = task_names(overrides)
            # Every task composed and its run keys and train YAML checked before the first one compiles for minutes.
            configs = []
            for name in names:
                cfg = compose_config([f"task={name}", "headless=True", *rest], config_dir=config_dir)
                check_before_start(cfg)
                configs.append((name, cfg))
            for name, cfg in configs:
                before, started = cache_folders(str(cfg.sim_device)), time.perf_counter()
                warm_up(cfg)
                print(report(name, time.perf_counter() - started, before, cache_folders(str(cfg.sim_device))),
                      flush=True)
    except KeyboardInterrupt as stop:  # Ctrl-C or SIGTERM: what was compiled so far stays in the caches
        signum = int(getattr(stop, "signum", signal.SIGINT))
        print(f"{PREFIX} stopped by {signal.Signals(signum).name}: the caches keep what was compiled before it",
              file=sys.stderr, flush=True)
        sys.stdout.flush()
        os._exit(128 + signum)  # without waiting for Warp modules still queued on the compile threads


if __name__ == "__main__":
    main()
