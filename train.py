"""Train or evaluate a task: python train.py task=Cartpole [num_envs=N seed=S max_iterations=K headless=True ...]

python train.py task=Cartpole test=True checkpoint=runs/Cartpole/<stamp>/model_60.pt   evaluates a policy.
"""

import time

_STARTED_AT = time.perf_counter()

import hydra  # noqa: E402
from omegaconf import DictConfig  # noqa: E402

import isaacgymenvs_mw.utils.config  # noqa: E402,F401  (registers the YAML resolvers)


@hydra.main(version_base="1.3", config_path="cfg", config_name="config")
def main(cfg: DictConfig) -> None:
    from isaacgymenvs_mw.learning.launch import run

    run(cfg, started_at=_STARTED_AT)


if __name__ == "__main__":
    main()
