"""Train or evaluate a task: python train.py task=Cartpole [num_envs=N seed=S max_iterations=K headless=True ...]

python train.py task=Cartpole test=True checkpoint=runs/Cartpole/<stamp>/model_60.pt   evaluates a policy.
python train.py --config-dir /my/project/cfg task=MyTask task_module=my_tasks   a task from outside the repository.
python train.py -m task=FrankaCubeLift seed=1,2,3,4   a sweep: the jobs side by side on the GPUs, then their table and
                                                      curves under runs/sweeps/ (isaacgymenvs_mw/learning/sweep.py).

A bad value (ours or one Hydra refuses) ends the run with one line on stderr and exit status 2; ``verbose=True`` or
HYDRA_FULL_ERROR=1 shows the traceback as well.
"""

import faulthandler
import os
import signal
import sys
import time

_STARTED_AT = time.perf_counter()
# A native crash (segfault, abort) in a simulator, renderer or CUDA library would otherwise end the run with no word in
# its log: Python's tracebacks of every thread go to stderr instead, naming where it died.
faulthandler.enable()

from isaacgymenvs_mw.utils.stop import PROCESS_STOP  # noqa: E402  (standard library only: imports in milliseconds)

# From here to the last line, SIGTERM and SIGINT stop the run with one line and the signal's exit status; while it
# trains, with its checkpoint and summary (isaacgymenvs_mw/utils/stop.py). Before this line they end it silently.
PROCESS_STOP.install()

from isaacgymenvs_mw.utils.compile_cache import use_cache_folder  # noqa: E402  (standard library only)

use_cache_folder()  # ISAACGYMENVS_MW_CACHE: every compile cache in one folder, set before torch and Warp read them

import hydra  # noqa: E402
from omegaconf import DictConfig  # noqa: E402

import isaacgymenvs_mw.utils.config  # noqa: E402,F401  (registers the YAML resolvers)
from isaacgymenvs_mw.utils.cli_errors import exit_on_input_error, report_input_errors  # noqa: E402


@hydra.main(version_base="1.3", config_path="cfg", config_name="config")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    from isaacgymenvs_mw.learning.train_config import check_before_start
    from isaacgymenvs_mw.utils.config import check_task_yaml, check_task_yaml_keys, record_task_dir

    with exit_on_input_error():
        check_task_yaml(cfg, HydraConfig.get())  # an empty task YAML, or one without name:, named by its path
        record_task_dir(cfg, HydraConfig.get())  # a relative env.asset.assetRoot resolves against the YAML's folder
        check_task_yaml_keys(cfg, HydraConfig.get())  # a misspelt key inside the task YAML, named with its file
        check_before_start(cfg)  # the run's keys and the train YAML, before the learning stack's 4 s of imports
        _say_starting(cfg)
        from isaacgymenvs_mw.learning.launch import run

        try:
            run(cfg, started_at=_STARTED_AT)
        except KeyboardInterrupt as err:  # Ctrl-C or SIGTERM: a training run saved its checkpoint and summary
            _stopped(err, evaluating=bool(cfg.get("test", False)))


def _say_starting(cfg: DictConfig) -> None:
    """One line as soon as the command is known to be good, so that the imports and a first run's kernel compiles
    (10-20 s on a small CPU) are not silence."""
    if os.getenv("RANK", "0") != "0":
        return
    what = "evaluating" if cfg.get("test", False) else "training"
    print(f"[train] {cfg.task_name}: {what}; loading torch, MuJoCo Warp and the learner, then building the worlds "
          f"({time.perf_counter() - _STARTED_AT:.1f} s after start)", flush=True)


def _stopped(err: KeyboardInterrupt, evaluating: bool = False) -> None:
    """End the process after a stop, with the shell's convention for its status: 130 for SIGINT, 143 for SIGTERM."""
    signum = int(getattr(err, "signum", signal.SIGINT))
    if getattr(err, "reported", False):  # the run wrote its checkpoint, its summary and its own stop line
        sys.exit(128 + signum)
    name = signal.Signals(signum).name
    if evaluating:
        print(f"[eval] stopped by {name}: no eval.json written", file=sys.stderr, flush=True)
    else:
        print(f"[train] stopped by {name} before the first training iteration ended: no checkpoint exists yet",
              file=sys.stderr, flush=True)
    sys.stdout.flush()
    # Nothing is left to save, so the process ends now: a normal exit would first wait for every Warp kernel module
    # still queued on the compile threads, which takes up to minutes on a cold cache.
    os._exit(128 + signum)


def sweep(argv: list[str]) -> None:
    """``python train.py -m ...``: one train.py process per job, side by side on the GPUs (learning/sweep.py)."""
    from pathlib import Path

    from isaacgymenvs_mw.learning.sweep import run_sweep

    with report_input_errors(), exit_on_input_error():
        sys.exit(run_sweep(argv, Path(__file__).resolve()))


if __name__ == "__main__":
    try:
        with exit_on_input_error():
            from isaacgymenvs_mw.utils.config import take_config_dirs, with_learner_default

            sys.argv[1:] = with_learner_default(sys.argv[1:])  # learner=rl_games: its train YAML by default
        if {"-m", "--multirun"} & set(sys.argv[1:]):
            sweep([arg for arg in sys.argv[1:] if arg not in ("-m", "--multirun")])
        with exit_on_input_error():
            sys.argv[1:] = take_config_dirs(sys.argv[1:])  # searched before cfg/, so that your files win
        with report_input_errors():
            main()
    except KeyboardInterrupt as stop:  # while Hydra composed the config, before main() began
        _stopped(stop)
