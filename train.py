"""Train or evaluate a task: python train.py task=Cartpole [num_envs=N seed=S max_iterations=K headless=True ...]

python train.py task=Cartpole test=True checkpoint=runs/Cartpole/<stamp>/model_60.pt   evaluates a policy.
python train.py --config-dir /my/project/cfg task=MyTask task_module=my_tasks   a task from outside the repository.
"""

import signal
import sys
import time

_STARTED_AT = time.perf_counter()

import hydra  # noqa: E402
from omegaconf import DictConfig  # noqa: E402

import isaacgymenvs_mw.utils.config  # noqa: E402,F401  (registers the YAML resolvers)


@hydra.main(version_base="1.3", config_path="cfg", config_name="config")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    from isaacgymenvs_mw.learning.launch import run
    from isaacgymenvs_mw.utils.config import record_task_dir

    record_task_dir(cfg, HydraConfig.get())  # a relative env.asset.assetRoot resolves against the task YAML's folder
    try:
        run(cfg, started_at=_STARTED_AT)
    except KeyboardInterrupt as err:  # Ctrl-C or SIGTERM: the run saved its checkpoint and summary
        signum = int(getattr(err, "signum", signal.SIGINT))
        print(f"[train] stopped by {signal.Signals(signum).name}", file=sys.stderr, flush=True)
        sys.exit(128 + signum)  # the shell's convention: 130 for SIGINT, 143 for SIGTERM


if __name__ == "__main__":
    main()
