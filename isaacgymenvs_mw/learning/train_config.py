"""The schema of the train YAML (rsl-rl-lib's OnPolicyRunner config): checked here before rsl_rl reads it."""

from __future__ import annotations

import importlib.util
import math

from omegaconf import DictConfig

from isaacgymenvs_mw.learning.checkpoints import checkpoint_path
from isaacgymenvs_mw.learning.ige_amp import use_ige_amp_recipe
from isaacgymenvs_mw.learning.rl_games_config import check_rl_games_config, is_rl_games_config
from isaacgymenvs_mw.utils.config import boolean, check_run_config, one_of, real_number, to_dict, whole_number
from isaacgymenvs_mw.utils.errors import ConfigError

TRAIN_SECTIONS = ("runner", "algorithm", "actor", "critic")  # the train YAML's sections, as OnPolicyRunner reads them

# SyncFreePPO's rl_games options (learning/ppo.py): the first choice of each is the default, rsl-rl-lib's behaviour.
KL_SCHEDULES = ("per_mini_batch", "per_epoch")
KL_FORMS = ("rsl_rl", "rl_games")
GRAD_CLIP_SCOPES = ("per_network", "global")
OBS_NORMALIZATION_FORMS = ("rsl_rl", "rl_games")
# ImageCNNModel's options (learning/models.py): the precision of its convolutions, the first the default.
CNN_PRECISIONS = ("float32", "bfloat16")
# Test mode's actions (runner.test_actions): the policy's mean, or draws from its distribution as rl_games' player
# makes them with player.deterministic False (IsaacGymEnvs' AllegroKuka recipes).
TEST_ACTIONS = ("mean", "sampled")
IMAGE_MODEL = "isaacgymenvs_mw.learning.models:ImageCNNModel"


# Train YAML keys that rsl_rl would otherwise take as they come: (section, key) -> check.
_TRAIN_CHECKS = {
    ("runner", "num_steps_per_env"): lambda v, k: whole_number(v, k, 1),
    ("runner", "max_iterations"): lambda v, k: whole_number(v, k, 0),
    ("runner", "save_interval"): lambda v, k: whole_number(v, k, 1),
    ("runner", "init_at_random_ep_len"): boolean,
    ("runner", "reward_scale"): lambda v, k: real_number(v, k, 0.0, low_open=True),
    ("runner", "test_actions"): lambda v, k: one_of(v, k, TEST_ACTIONS),
    ("algorithm", "learning_rate"): lambda v, k: real_number(v, k, 0.0, low_open=True),
    ("algorithm", "desired_kl"): lambda v, k: v is None or real_number(v, k, 0.0, low_open=True),
    ("algorithm", "num_learning_epochs"): lambda v, k: whole_number(v, k, 1),
    ("algorithm", "num_mini_batches"): lambda v, k: whole_number(v, k, 1),
    ("algorithm", "clip_param"): lambda v, k: real_number(v, k, 0.0, low_open=True),
    ("algorithm", "gamma"): lambda v, k: real_number(v, k, 0.0, 1.0),
    ("algorithm", "lam"): lambda v, k: real_number(v, k, 0.0, 1.0),
    ("algorithm", "value_loss_coef"): lambda v, k: real_number(v, k, 0.0),
    ("algorithm", "entropy_coef"): lambda v, k: real_number(v, k),
    # .inf: no clipping (IsaacGymEnvs' truncate_grads: False, learning/ige_amp.py)
    ("algorithm", "max_grad_norm"): lambda v, k: v if v == math.inf else real_number(v, k, 0.0, low_open=True),
    ("algorithm", "use_clipped_value_loss"): boolean,
    ("algorithm", "kl_schedule"): lambda v, k: one_of(v, k, KL_SCHEDULES),
    ("algorithm", "kl_form"): lambda v, k: one_of(v, k, KL_FORMS),
    ("algorithm", "grad_clip_scope"): lambda v, k: one_of(v, k, GRAD_CLIP_SCOPES),
    ("algorithm", "obs_normalization_clip"): lambda v, k: v is None or real_number(v, k, 0.0, low_open=True),
    ("algorithm", "obs_normalization_form"): lambda v, k: one_of(v, k, OBS_NORMALIZATION_FORMS),
    ("algorithm", "share_trunk"): boolean,
    ("actor", "obs_normalization"): boolean,
    ("critic", "obs_normalization"): boolean,
    ("actor", "cnn_precision"): lambda v, k: one_of(v, k, CNN_PRECISIONS),
    ("critic", "cnn_precision"): lambda v, k: one_of(v, k, CNN_PRECISIONS),
    ("actor", "cnn_channels_last"): boolean,
    ("critic", "cnn_channels_last"): boolean,
}
_SCHEDULES = ("adaptive", "fixed")


def check_before_start(cfg: DictConfig) -> None:
    """The checks that need no task and no torch: the run-level keys, the checkpoint's path and the train YAML.
    train.py and the sweep make them before the learning stack is imported (torch, rsl-rl-lib and the simulator take
    about 4 s), so that a mistyped value is told at once; the launcher makes them again for its own callers. An
    IsaacGymEnvs AMP YAML becomes its rsl-rl-lib recipe first (learning/ige_amp.py)."""
    check_run_config(cfg)
    use_ige_amp_recipe(cfg)
    checkpoint_path(cfg)
    check_train_config(to_dict(cfg.train), cfg.get("learner"))


def check_train_config(train_cfg: dict, learner: str | None = None) -> None:
    """Fail on train YAML values of the wrong kind or range, naming ``train.<section>.<key>``, before rsl_rl runs.
    An rl_games YAML (``params:``) is checked by its own schema; ``learner`` (the run key) must agree with the
    YAML when it is rl_games."""
    if is_rl_games_config(train_cfg):
        check_rl_games_config(train_cfg)
        if importlib.util.find_spec("rl_games") is None:
            raise ConfigError("learner=rl_games (an rl_games train YAML) needs rl_games, which is not installed: "
                              "pip install -e \".[rl-games]\" (or pip install \"rl-games>=1.6.5,<1.7\")")
        return
    if learner == "rl_games":
        raise ConfigError("learner=rl_games, but the train YAML is rsl-rl-lib's (runner/algorithm/actor/critic): give "
                          "an rl_games YAML (params: ...) as train=<name>, or leave train= out for the task's "
                          "cfg/train/rl_games/<Task>PPO.yaml")
    missing = [s for s in TRAIN_SECTIONS if s not in train_cfg]
    if missing:
        raise ConfigError(f"train config lacks section(s) {missing}; expected {list(TRAIN_SECTIONS)}")
    for (section, key), check in _TRAIN_CHECKS.items():
        if key in (train_cfg.get(section) or {}):
            check(train_cfg[section][key], f"train.{section}.{key}")
    for section in ("actor", "critic"):
        model = train_cfg.get(section) or {}
        for key in ("cnn_precision", "cnn_channels_last"):
            if key in model and model.get("class_name") != IMAGE_MODEL:
                raise ConfigError(f"train.{section}.{key} is read only by the image model: set "
                                  f"train.{section}.class_name={IMAGE_MODEL} or remove it "
                                  f"(train.{section}.class_name={model.get('class_name')!r})")
    schedule = (train_cfg.get("algorithm") or {}).get("schedule", "adaptive")
    one_of(schedule, "train.algorithm.schedule", _SCHEDULES)
    for section in ("actor", "critic"):
        dims = (train_cfg.get(section) or {}).get("hidden_dims", [])
        if not isinstance(dims, list) or not dims:
            raise ConfigError(f"train.{section}.hidden_dims={dims!r} is invalid: give a list of layer sizes, "
                             "e.g. [64, 64]")
        for dim in dims:
            whole_number(dim, f"train.{section}.hidden_dims", 1)
    init_std = ((train_cfg.get("actor") or {}).get("distribution_cfg") or {}).get("init_std")
    if init_std is not None:
        real_number(init_std, "train.actor.distribution_cfg.init_std", 0.0, low_open=True)


def recipe_reward_scale(train_cfg: dict) -> float:
    """The factor the learner recipe puts on the task's reward: ``runner.reward_scale`` of an rsl-rl-lib YAML,
    ``params.config.reward_shaper.scale_value`` of an rl_games one (IsaacGymEnvs' place for it); 1 when absent. A task
    YAML holds IsaacGymEnvs' reward unscaled, so an IsaacGymEnvs train YAML scales it once, as in IsaacGymEnvs."""
    if is_rl_games_config(train_cfg):
        shaper = (train_cfg["params"].get("config") or {}).get("reward_shaper") or {}
        return float(shaper.get("scale_value", 1.0))
    return float((train_cfg.get("runner") or {}).get("reward_scale", 1.0))
