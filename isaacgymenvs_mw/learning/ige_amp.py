"""IsaacGymEnvs' AMP train YAMLs (rl_games' schema with ``algo.name: amp_continuous``: IsaacGymEnvs' own learner,
which rl_games lacks) train with this project's adversarial motion priors (learning/amp.py) on the rsl_rl learner.

``ige_amp_recipe`` rewrites such a YAML, key by key, into an rsl-rl-lib recipe with an ``amp`` section before
anything else reads the train config (``use_ige_amp_recipe``); one line says so and names the keys read but not used.
What maps where (IsaacGymEnvs' key -> this project's):

- ``horizon_length`` -> ``runner.num_steps_per_env``; ``max_epochs`` -> ``runner.max_iterations``; ``save_frequency``
  -> ``runner.save_interval``; ``name`` -> ``runner.experiment_name``; ``reward_shaper.scale_value`` ->
  ``runner.reward_scale``
- ``learning_rate``, ``lr_schedule`` (``constant`` -> ``fixed``; ``adaptive`` with ``kl_threshold`` as
  ``desired_kl``), ``mini_epochs`` -> ``num_learning_epochs``, ``minibatch_size`` -> ``num_mini_batches`` (an
  iteration's samples / it, fitted to a divisor as rl_games needs), ``e_clip`` -> ``clip_param``, ``gamma``, ``tau`` ->
  ``lam``, ``critic_coef`` -> ``value_loss_coef``, ``clip_value`` -> ``use_clipped_value_loss``, ``entropy_coef``,
  ``bounds_loss_coef``, ``normalize_value``; ``grad_norm`` -> ``max_grad_norm`` (``truncate_grads: False``: no
  clipping); ``normalize_input`` -> both networks' input normalisation in rl_games' form (clamped to +-5)
- ``network.mlp`` (``units``, ``activation``) -> the actor's and critic's ``hidden_dims`` and ``activation``;
  ``space.continuous.sigma_init.val`` -> the actor's std exp(val), learned only with ``learn_sigma: True``
- ``network.disc`` -> ``amp.hidden_dims``, ``amp.activation``; ``disc_reward_scale``, ``task_reward_w``,
  ``disc_reward_w``, ``disc_grad_penalty``, ``disc_logit_reg``, ``disc_weight_decay``, ``amp_replay_buffer_size``,
  ``amp_replay_keep_prob``, ``amp_minibatch_size``, ``normalize_amp_input`` -> ``amp.*``; the discriminator learns at
  the policy's rate, ``mini_epochs`` x mini-batches steps per rollout, with IsaacGymEnvs' BCE loss and style reward
"""

from __future__ import annotations

import math
from typing import Any

from omegaconf import DictConfig, OmegaConf, open_dict

from isaacgymenvs_mw.learning.rl_games_config import fitted_minibatch
from isaacgymenvs_mw.utils.config import real_number, whole_number
from isaacgymenvs_mw.utils.errors import ConfigError

ALGO = "amp_continuous"
# Read and not used, with why (the one line names them):
UNUSED = {
    "score_to_win": "the run ends at max_epochs or max_train_time_s",
    "print_stats": "the progress line is this project's",
    "full_experiment_name": "the run folder is runs_dir/<name>/<timestamp>/",
    "save_best_after": "model_best.pt follows save_best and sweep_metric",
    "seq_len": "the networks are feed-forward",
    "amp_obs_demo_buffer_size": "motion samples are drawn fresh from the motion library at each discriminator step",
    "amp_batch_size": "motion samples are drawn fresh from the motion library at each discriminator step",
    "disc_coef": "the discriminator has an Adam optimiser of its own, whose steps a constant weight on its loss would "
                 "not change",
    "env_name": "the env is the task",
    "multi_gpu": "the run key multi_gpu decides",
    "player": "test mode runs the mean action",
    "kl_threshold": "read with lr_schedule: adaptive only",
    "schedule_type": "an adaptive rate follows rsl-rl-lib's rule",
}
# Keys whose only supported value is IsaacGymEnvs' (another would change what this learner cannot change).
FIXED = {"ppo": True, "normalize_advantage": True, "value_bootstrap": True, "mixed_precision": False}
MAPPED = ("name", "num_actors", "reward_shaper", "gamma", "tau", "learning_rate", "lr_schedule", "max_epochs",
          "save_frequency", "grad_norm", "truncate_grads", "entropy_coef", "e_clip", "horizon_length",
          "minibatch_size", "mini_epochs", "critic_coef", "clip_value", "bounds_loss_coef", "normalize_input",
          "normalize_value", "amp_replay_buffer_size", "amp_replay_keep_prob", "amp_minibatch_size", "disc_logit_reg",
          "disc_grad_penalty", "disc_reward_scale", "disc_weight_decay", "normalize_amp_input", "task_reward_w",
          "disc_reward_w")
_ACTIVATIONS = ("relu", "elu", "tanh")


def is_ige_amp_config(train_cfg: Any) -> bool:
    """Whether a train config is one of IsaacGymEnvs' AMP YAMLs (``params.algo.name: amp_continuous``)."""
    params = train_cfg.get("params") if hasattr(train_cfg, "get") else None
    algo = params.get("algo") if hasattr(params, "get") else None
    return hasattr(algo, "get") and algo.get("name") == ALGO


def use_ige_amp_recipe(cfg: DictConfig) -> None:
    """Replace the run's train config, if it is an IsaacGymEnvs AMP YAML, by its rsl-rl-lib recipe (module docstring),
    with one line; a second call finds the recipe and does nothing."""
    if not is_ige_amp_config(cfg.train):
        return
    if cfg.get("learner") == "rl_games":
        raise ConfigError(f"learner=rl_games cannot train train.params.algo.name={ALGO} (IsaacGymEnvs' AMP learner, "
                          "not part of rl_games): leave learner out, and this project's AMP trains it with rsl_rl")
    train = OmegaConf.to_container(cfg.train, resolve=True)
    recipe, unused = ige_amp_recipe(train, int(cfg.task.env.numEnvs))
    if not cfg.get("test"):
        told = ", ".join(f"{k} ({why})" for k, why in unused.items())
        print(f"[train] note: train.params.algo.name={ALGO} (IsaacGymEnvs' AMP) trains with this project's AMP on the "
              f"rsl_rl learner, its keys mapped (docs/config.md#isaacgymenvs-amp-train-yamls)"
              + (f"; read, not used: {told}" if told else ""), flush=True)
    with open_dict(cfg):
        cfg.train = OmegaConf.create(recipe)


def ige_amp_recipe(train: dict, num_envs: int) -> tuple[dict, dict[str, str]]:
    """The rsl-rl-lib recipe of an IsaacGymEnvs AMP train YAML (a plain dict, interpolations resolved) for
    ``num_envs`` envs, and the keys it read without use, each with why."""
    params = train["params"]
    extra = sorted(set(train) - {"params"})
    if extra:
        raise ConfigError(f"train.{extra[0]}: not a key of an IsaacGymEnvs AMP train YAML (everything sits under "
                          "params:)")
    _expect(params.get("model", {}).get("name"), "train.params.model.name", "continuous_amp")
    network, config = params.get("network") or {}, params.get("config") or {}
    _expect(network.get("name"), "train.params.network.name", "amp")
    _keys(network, "train.params.network", ("name", "separate", "space", "mlp", "disc"))
    if network.get("separate", True) is not True:
        raise ConfigError(f"train.params.network.separate={network['separate']!r} is not supported with {ALGO} here: "
                          "only True (a policy and a value network of their own, as IsaacGymEnvs' AMP YAMLs have)")
    sigma = _sigma(network.get("space") or {})
    mlp = _mlp(network.get("mlp") or {}, "train.params.network.mlp")
    disc = _mlp(network.get("disc") or {}, "train.params.network.disc")
    _keys(config, "train.params.config", (*MAPPED, *UNUSED, *FIXED))
    for key, value in FIXED.items():
        if key in config and config[key] != value:
            raise ConfigError(f"train.params.config.{key}={config[key]!r} is not supported with {ALGO} here: only "
                              f"{value} (IsaacGymEnvs' value)")
    actors = config.get("num_actors", num_envs)
    if int(actors) != num_envs:
        raise ConfigError(f"train.params.config.num_actors={actors} differs from the task's {num_envs} envs: write "
                          "num_actors: ${....task.env.numEnvs}")
    horizon = _whole(config, "horizon_length")
    samples = horizon * num_envs
    size = fitted_minibatch(samples, _whole(config, "minibatch_size"))  # rl_games' minibatches divide the samples
    mini_batches, epochs = samples // size, _whole(config, "mini_epochs")
    schedule = config.get("lr_schedule", "constant")
    if schedule not in ("constant", "adaptive", None, "None"):
        raise ConfigError(f"train.params.config.lr_schedule={schedule!r} is not supported with {ALGO} here: give "
                          "constant or adaptive")
    unused = {k: why for k, why in UNUSED.items() if k in config}
    algorithm = {
        "class_name": "isaacgymenvs_mw.learning.ppo:SyncFreePPO",
        "learning_rate": _number(config, "learning_rate"),
        "schedule": "adaptive" if schedule == "adaptive" else "fixed",
        "num_learning_epochs": epochs,
        "num_mini_batches": mini_batches,
        "clip_param": _number(config, "e_clip"),
        "gamma": _number(config, "gamma"),
        "lam": _number(config, "tau"),
        "value_loss_coef": _number(config, "critic_coef"),
        "entropy_coef": float(config.get("entropy_coef", 0.0)),
        "max_grad_norm": _number(config, "grad_norm") if config.get("truncate_grads", False) else math.inf,
        "use_clipped_value_loss": bool(config.get("clip_value", False)),
        "bounds_loss_coef": float(config.get("bounds_loss_coef", 0.0)),
        "normalize_value": bool(config.get("normalize_value", False)),
        "obs_normalization_clip": 5.0,
        "obs_normalization_form": "rl_games",
    }
    if schedule == "adaptive":
        algorithm["desired_kl"] = _number(config, "kl_threshold")
        unused.pop("kl_threshold", None)
    normalize = bool(config.get("normalize_input", False))
    actor = {"class_name": "MLPModel", **mlp, "obs_normalization": normalize,
             "distribution_cfg": {"class_name": "isaacgymenvs_mw.learning.distributions:GaussianDistribution",
                                  "init_std": math.exp(sigma["val"]), "std_type": "scalar",
                                  "learn_std": sigma["learn"]}}
    recipe = {
        "runner": {"num_steps_per_env": horizon, "max_iterations": _whole(config, "max_epochs"),
                   "save_interval": int(config.get("save_frequency", 50)),
                   "experiment_name": str(config.get("name") or "HumanoidAMP"),
                   "reward_scale": float((config.get("reward_shaper") or {}).get("scale_value", 1.0)),
                   "obs_groups": {"actor": ["policy"], "critic": ["policy"]}, "logger": "tensorboard"},
        "algorithm": algorithm,
        "actor": actor,
        "critic": {"class_name": "MLPModel", **mlp, "obs_normalization": normalize},
        "amp": {"task_reward_w": float(config.get("task_reward_w", 0.0)),
                "disc_reward_w": float(config.get("disc_reward_w", 1.0)),
                "disc_reward_scale": float(config.get("disc_reward_scale", 1.0)),
                "loss": "bce", **disc,
                "learning_rate": algorithm["learning_rate"],
                "updates_per_rollout": epochs * mini_batches,
                "minibatch_size": _whole(config, "amp_minibatch_size"),
                "grad_penalty": float(config.get("disc_grad_penalty", 0.0)),
                "logit_reg": float(config.get("disc_logit_reg", 0.0)),
                "weight_decay": float(config.get("disc_weight_decay", 0.0)),
                "replay_buffer_size": _whole(config, "amp_replay_buffer_size"),
                "replay_keep_prob": _number(config, "amp_replay_keep_prob"),
                "normalize_input": bool(config.get("normalize_amp_input", False))},
    }
    return recipe, unused


def _sigma(space: dict) -> dict:
    """The policy's std: IsaacGymEnvs' fixed sigma (a parameter, not a network output), its log from sigma_init."""
    continuous = space.get("continuous") or {}
    key = "train.params.network.space.continuous"
    if continuous.get("fixed_sigma") is not True:
        raise ConfigError(f"{key}.fixed_sigma={continuous.get('fixed_sigma')!r} is not supported with {ALGO} here: "
                          "only True (the std a parameter, as IsaacGymEnvs' AMP YAMLs have it)")
    for name in ("mu_activation", "sigma_activation"):
        if continuous.get(name, "None") not in ("None", None):
            raise ConfigError(f"{key}.{name}={continuous[name]!r} is not supported with {ALGO} here: only None")
    init = continuous.get("sigma_init") or {}
    if init.get("name") != "const_initializer" or not isinstance(init.get("val"), (int, float)):
        raise ConfigError(f"{key}.sigma_init={init!r} is not supported with {ALGO} here: give {{name: "
                          "const_initializer, val: <log std>}}")
    return {"val": float(init["val"]), "learn": bool(continuous.get("learn_sigma", True))}


def _mlp(section: dict, key: str) -> dict:
    _keys(section, key, ("units", "activation", "d2rl", "initializer", "regularizer"))
    units = section.get("units")
    if not isinstance(units, list) or not units or not all(isinstance(u, int) and u > 0 for u in units):
        raise ConfigError(f"{key}.units={units!r} is invalid: give a list of layer sizes, e.g. [1024, 512]")
    activation = section.get("activation", "relu")
    if activation not in _ACTIVATIONS:
        raise ConfigError(f"{key}.activation={activation!r} is not supported with {ALGO} here: give one of "
                          f"{list(_ACTIVATIONS)}")
    if section.get("d2rl", False):
        raise ConfigError(f"{key}.d2rl=True is not supported with {ALGO} here: plain MLPs only")
    return {"hidden_dims": list(units), "activation": activation}


def _keys(section: dict, key: str, valid: tuple) -> None:
    unknown = sorted(set(section) - set(valid))
    if unknown:
        raise ConfigError(f"{key}.{unknown[0]}: not a key of an IsaacGymEnvs AMP train YAML this project reads "
                          f"(docs/config.md#isaacgymenvs-amp-train-yamls)")


def _expect(value: Any, key: str, wanted: str) -> None:
    if value != wanted:
        raise ConfigError(f"{key}={value!r} is not supported with {ALGO}: give {wanted}")


def _whole(config: dict, key: str) -> int:
    return whole_number(config.get(key), f"train.params.config.{key}", 1)


def _number(config: dict, key: str) -> float:
    return real_number(config.get(key), f"train.params.config.{key}", 0.0)
