"""The learning libraries a run can train with, behind one interface, chosen in one place.

``Learner`` is what the launcher (learning/launch.py) asks of a library: its config checks before the task is built,
the runner it trains with (a ``TrainingRun``, which owns the training loop and calls the runner's one iteration), the
iterations the run trains, and what its checkpoints hold. Each library has one implementation beside its runner and
env adapter (a ``TaskEnv``, learning/vecenv.py): rsl-rl-lib's in learning/runner.py, rl_games' in
learning/rl_games_runner.py. ``learner_for`` picks one from the train YAML's schema
(rl_games' YAMLs, IsaacGymEnvs' included, have a ``params:`` section), so IsaacGymEnvs' YAMLs run unchanged. A new
library is one module with a ``Learner`` subclass and its line in ``LEARNERS``.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Callable, ClassVar

import torch
from omegaconf import DictConfig

from isaacgymenvs_mw.learning.rl_games_config import is_rl_games_config
from isaacgymenvs_mw.learning.training_run import TrainingRun
from isaacgymenvs_mw.learning.checkpoints import checkpoint_path
from isaacgymenvs_mw.utils.errors import ConfigError, one_line

# learner name (the run key `learner`) -> "module:class". Modules are imported when chosen: an optional library
# (rl_games) is imported only by its own runs.
LEARNERS = {
    "rsl_rl": "isaacgymenvs_mw.learning.runner:RslRlLearner",
    "rl_games": "isaacgymenvs_mw.learning.rl_games_runner:RlGamesLearner",
}
# What each learner's checkpoints hold at their top level, to say which learner wrote a checkpoint given to another.
CHECKPOINT_KEYS = {"rsl_rl": "actor_state_dict", "rl_games": "model"}


class Learner:
    """One learning library as a run uses it. ``cfg``: the run's composed config."""

    name: ClassVar[str]

    def __init__(self, cfg: DictConfig) -> None:
        self.cfg = cfg

    def check(self) -> None:
        """Refuse bad train-YAML values before the task is built (minutes, on a big run); read the iterations."""

    def runner_factory(self, task) -> tuple[Callable[[], TrainingRun], str]:
        """A function that makes the runner for ``task`` (no log folder yet), and the run's experiment name."""
        raise NotImplementedError

    def max_iterations(self) -> int:
        """The iterations the run trains in total (known once ``check`` has run)."""
        raise NotImplementedError

    def saved_iteration(self, state: dict) -> int:
        """The iteration a checkpoint of this learner was written at."""
        raise NotImplementedError

    def random_start(self) -> bool:
        """Whether training starts its episodes at random points of their time limit (rsl-rl-lib's option)."""
        return False


def learner_for(cfg: DictConfig) -> Learner:
    """The learner of the run's train YAML: rl_games' schema (``params:``) or rsl-rl-lib's."""
    name = "rl_games" if is_rl_games_config(cfg.train) else "rsl_rl"
    module, cls = LEARNERS[name].split(":")
    return getattr(importlib.import_module(module), cls)(cfg)


def read_checkpoint(cfg: DictConfig, learner: Learner) -> tuple[Path | None, dict[str, Any] | None]:
    """``checkpoint=`` as a path and its contents (on the CPU), read before the simulator is built; a file the
    learner did not write is one line saying which learner did."""
    path = checkpoint_path(cfg)
    if path is None:
        return None, None
    try:  # before the simulator is built, which can take minutes
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:
        reason = one_line(str(err)).split(". ")[0]
        raise ConfigError(f"checkpoint='{cfg.checkpoint}': {path} is not a readable checkpoint (truncated or not "
                          f"written by torch.save: {reason}); give a model_*.pt of a training run") from err
    wanted = CHECKPOINT_KEYS[learner.name]
    if not isinstance(state, dict) or wanted not in state:
        written_by = next((f"; it was written by learner={name}" for name, key in CHECKPOINT_KEYS.items()
                           if isinstance(state, dict) and key in state), "")
        raise ConfigError(f"checkpoint='{cfg.checkpoint}': {path} holds no {learner.name} policy (no {wanted})"
                          f"{written_by}; give a model_*.pt of a training run with learner={learner.name}")
    return path, state


def check_resume_total(max_iterations: int, done: int, given: str) -> None:
    """Resuming trains up to ``max_iterations`` in total (IsaacGymEnvs' meaning): it must lie beyond the checkpoint's
    iteration ``done``."""
    if max_iterations <= done:
        raise ConfigError(f"max_iterations={max_iterations} is not above the iteration of checkpoint='{given}' "
                          f"({done}): on resume max_iterations is the total, so give max_iterations > {done} "
                          f"(e.g. {2 * max(done, 1)})")
