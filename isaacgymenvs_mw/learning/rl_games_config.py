"""The schema of an rl_games train YAML (``params: {algo, model, network, config}``): which keys this project reads
and which it refuses, checked before the learning stack is imported (no torch here)."""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig

from isaacgymenvs_mw.utils.config import whole_number
from isaacgymenvs_mw.utils.errors import ConfigError

LEARNER = "rl_games"  # the value of the run key `learner` and of a checkpoint's "learner" entry

# train.params.config keys this runner reads, beside what rl_games' A2CAgent reads itself (docs/config.md lists
# them all); the value of each key here replaces or checks what the YAML says.
# - num_actors:      must equal the task's number of envs (IsaacGymEnvs writes ${....task.env.numEnvs})
# - device / device_name: the run's rl_device (IsaacGymEnvs writes ${....rl_device})
# - multi_gpu:       the run key multi_gpu
# - name:            the experiment: runs/<name>/<timestamp>/
# - max_epochs:      the iterations to train (IsaacGymEnvs writes ${resolve_default:N,${....max_iterations}})
# - max_frames:      also end the run once this many env steps are done (-1: no limit)
# - save_frequency:  a checkpoint every this many iterations (0: only the last, the interrupted and the best)
# - save_best_after: model_best.pt considers checkpoints from this iteration on (save_best=True)
# - score_to_win:    end the run once the mean episode reward exceeds it
# - mixed_precision: honoured on CUDA; on the CPU there is no autocast, so it is off
# - player:          test mode runs one episode per env: the mean action (deterministic: True, the default) or a
#                    sampled one (deterministic: False, as IsaacGymEnvs' AllegroKuka recipes evaluate)
# - defer_summaries_sec, summaries_interval_sec_min / _max: rl_games' throttle of its TensorBoard writer; not used,
#                    this project's writer takes the scalars once per iteration
READ_KEYS = ("name", "full_experiment_name", "env_name", "num_actors", "device", "device_name", "multi_gpu",
             "max_epochs", "max_frames", "save_frequency", "save_best_after", "score_to_win", "mixed_precision",
             "player", "ppo", "normalize_input", "normalize_value", "normalize_advantage", "value_bootstrap",
             "reward_shaper", "gamma", "tau", "learning_rate", "lr_schedule", "schedule_type", "kl_threshold",
             "grad_norm", "entropy_coef", "truncate_grads", "e_clip", "clip_value", "horizon_length",
             "minibatch_size", "minibatch_size_per_env", "mini_epochs", "critic_coef", "bounds_loss_coef",
             "bound_loss_type", "seq_len", "seq_length", "print_stats", "central_value_config", "use_smooth_clamp",
             "clip_actions", "weight_decay", "use_experimental_cv", "normalize_rms_advantage", "games_to_track",
             "use_diagnostics", "schedule_entropy", "freeze_critic", "adv_rms_momentum", "defer_summaries_sec",
             "summaries_interval_sec_min", "summaries_interval_sec_max")
# Keys of train.params: the four sections, and what IsaacGymEnvs derives from run keys (checked against them).
PARAMS_KEYS = ("algo", "model", "network", "config", "seed", "load_checkpoint", "load_path")
# Keys whose meaning this runner cannot give, with why (a one-line error names them).
REFUSED_KEYS = {
    "self_play_config": "self-play needs several agents per env; a VecTask has one",
    "self_play": "self-play needs several agents per env; a VecTask has one",
    "population_based_training": "population-based training restarts runs from other runs' checkpoints",
    "use_action_masks": "a VecTask's actions are continuous and unmasked",
    "env_config": "the task is built from the task YAML (task.*), not from rl_games' env_config",
    "epochs_between_resets": "a VecTask resets its own envs when their episodes end",
    "features": "rl_games' observer hooks are this runner's own",
}
_ALGOS = ("a2c_continuous",)
_MODELS = ("continuous_a2c_logstd", "continuous_a2c")
_NETWORKS = ("actor_critic",)
_RNNS = ("lstm", "gru")
# network.rnn keys rl_games' actor_critic reads: before_mlp puts the RNN on the observation (else after the MLP, where
# concat_input also feeds it the observation); concat_output adds the observation to its output; layer_norm after it
RNN_KEYS = ("name", "units", "layers", "before_mlp", "concat_input", "concat_output", "layer_norm")
# rl_games keeps the rate fixed for any schedule but adaptive and linear; IsaacGymEnvs' YAMLs write constant or None
_SCHEDULES = ("adaptive", "linear", "constant", None, "None", "identity")
# Keys of an rl_games train YAML beside params: IsaacGymEnvs' TrifingerPPO.yaml states asymmetric_obs, which its
# code never reads; here True is checked against the task (rl_games_runner.rl_games_params).
TOP_KEYS = ("params", "asymmetric_obs")


def is_rl_games_config(train_cfg: dict | DictConfig) -> bool:
    """Whether a train YAML is rl_games' (``params: {algo, model, network, config}``), not rsl-rl-lib's."""
    return "params" in train_cfg


def check_rl_games_config(train_cfg: dict) -> None:
    """Fail, naming ``train.params.<...>``, on what rl_games would take badly or this runner cannot honour."""
    params = train_cfg.get("params")
    if not isinstance(params, dict):
        raise ConfigError(f"train.params={params!r} is invalid: an rl_games train YAML holds params: {{algo, model, "
                          "network, config}}")
    for section in ("algo", "model", "network", "config"):
        if not isinstance(params.get(section), dict):
            raise ConfigError(f"train.params.{section} is missing: an rl_games train YAML holds params.algo, "
                              "params.model, params.network and params.config")
    unknown_sections = sorted(set(params) - set(PARAMS_KEYS))
    if unknown_sections:
        raise ConfigError(f"train.params.{unknown_sections[0]}: not an rl_games key this project reads (valid: "
                          f"{list(PARAMS_KEYS)})")
    extra = sorted(set(train_cfg) - set(TOP_KEYS))
    if extra:
        raise ConfigError(f"train.{extra[0]}: not a key of an rl_games train YAML (everything sits under params:, "
                          "beside IsaacGymEnvs' asymmetric_obs)")
    if not isinstance(train_cfg.get("asymmetric_obs", False), bool):
        raise ConfigError(f"train.asymmetric_obs={train_cfg['asymmetric_obs']!r} is invalid: give True or False")
    _choice(params["algo"].get("name"), "train.params.algo.name", _ALGOS, "rl_games' PPO for continuous actions")
    _choice(params["model"].get("name"), "train.params.model.name", _MODELS, "a Gaussian policy over continuous "
            "actions")
    network = params["network"]
    _choice(network.get("name"), "train.params.network.name", _NETWORKS, "an MLP actor-critic")
    if network.get("cnn"):
        raise ConfigError("train.params.network.cnn is not supported with learner=rl_games: the task's observation "
                          "is a vector here (use the rsl_rl learner for images)")
    config = params["config"]
    if network.get("rnn"):
        _check_rnn(network["rnn"], config)
    for key, why in REFUSED_KEYS.items():
        if config.get(key) not in (None, False, {}, 0):
            raise ConfigError(f"train.params.config.{key}={config[key]!r} is not supported with learner=rl_games: "
                              f"{why}")
    unknown = sorted(set(config) - set(READ_KEYS) - set(REFUSED_KEYS))
    if unknown:
        raise ConfigError(f"train.params.config.{unknown[0]}: not an rl_games key this project reads (a typo? the "
                          "keys read and refused are listed in docs/config.md#rl_games-train-yamls-the-keys-read-and-refused)")
    for key in ("learning_rate", "horizon_length", "mini_epochs", "gamma", "tau", "e_clip", "critic_coef",
                "grad_norm", "entropy_coef", "normalize_input", "normalize_advantage", "clip_value", "lr_schedule"):
        if key not in config:
            raise ConfigError(f"train.params.config.{key} is required by rl_games' PPO")
    if "minibatch_size" not in config and "minibatch_size_per_env" not in config:
        raise ConfigError("train.params.config.minibatch_size (or minibatch_size_per_env) is required by rl_games' "
                          "PPO")
    _choice(config["lr_schedule"], "train.params.config.lr_schedule", _SCHEDULES, "rl_games' schedules")
    if config["lr_schedule"] == "adaptive" and "kl_threshold" not in config:
        raise ConfigError("train.params.config.kl_threshold is required with lr_schedule: adaptive")
    _choice(config.get("schedule_type", "legacy"), "train.params.config.schedule_type", ("legacy", "standard"),
            "rl_games' KL schedules (legacy: after each minibatch; standard: once per mini-epoch)")
    if config.get("env_name", "rlgpu") != "rlgpu":
        raise ConfigError(f"train.params.config.env_name={config['env_name']!r} is invalid: the env is the task "
                          "(IsaacGymEnvs' YAMLs say rlgpu, the only value read)")
    player = config.get("player") or {}
    if not isinstance(player.get("deterministic", True), bool):
        raise ConfigError(f"train.params.config.player.deterministic={player['deterministic']!r} is invalid: give "
                          "True (test mode runs the mean action) or False (it samples the policy's actions)")


def fitted_minibatch(samples: int, size: int, multiple: int = 1) -> int:
    """The largest minibatch size up to ``size`` that divides an iteration's ``samples`` and is a multiple of
    ``multiple`` (an RNN's whole sequences), as rl_games requires; ``samples`` is a multiple of ``multiple``."""
    return max(d for d in range(multiple, max(min(size, samples), multiple) + 1, multiple) if samples % d == 0)


def seq_length(config: dict) -> int:
    """The RNN's training sequence length: ``seq_length``, or ``seq_len`` as older rl_games named it (IsaacGymEnvs'
    LSTM YAMLs write it; rl_games 1.6 reads only ``seq_length`` and would fall back to 4 without a word)."""
    return int(config.get("seq_length", config.get("seq_len", 4)))


def _check_rnn(rnn: Any, config: dict) -> None:
    """``network.rnn``: rl_games' LSTM or GRU, trained on sequences of ``seq_length`` steps of the rollout."""
    if not isinstance(rnn, dict):
        raise ConfigError(f"train.params.network.rnn={rnn!r} is invalid: give {{name: lstm or gru, units, layers}}")
    unknown = sorted(set(rnn) - set(RNN_KEYS))
    if unknown:
        raise ConfigError(f"train.params.network.rnn.{unknown[0]}: not an rl_games RNN key (valid: {list(RNN_KEYS)})")
    _choice(rnn.get("name"), "train.params.network.rnn.name", _RNNS, "rl_games' recurrent layers")
    for key in ("units", "layers"):
        whole_number(rnn.get(key), f"train.params.network.rnn.{key}", 1)
    if "seq_len" in config and "seq_length" in config and int(config["seq_len"]) != int(config["seq_length"]):
        raise ConfigError(f"train.params.config.seq_len={config['seq_len']} and seq_length={config['seq_length']} "
                          "disagree: give one (seq_length, as rl_games 1.6 names it)")
    length, horizon = seq_length(config), int(config.get("horizon_length", 0))
    if length < 1 or horizon % length:
        raise ConfigError(f"train.params.config.seq_length={length} is invalid with horizon_length={horizon}: the "
                          "rollout is cut into sequences of seq_length steps, so give a divisor of horizon_length")


def _choice(value: Any, key: str, valid: tuple, what: str) -> None:
    if value not in valid:
        raise ConfigError(f"{key}={value!r} is not supported with learner=rl_games: give one of "
                          f"{[v for v in valid if v not in ('None', 'identity')]} ({what})")
