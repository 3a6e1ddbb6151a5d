"""Training and evaluation with rl_games (IsaacGymEnvs' own learner), configured by an rl_games train YAML:
``cfg/train/rl_games/<Task>PPO.yaml`` (``learner=rl_games``) or one written for IsaacGymEnvs, given as ``train=<name>``.

rl_games' ``A2CAgent`` collects a rollout and updates the policy (its ``train_epoch``: PPO, its KL-adaptive
learning rate, normalisers and losses, unchanged); the loop around it is this project's (``training_run.py``), so a
rl_games run has the run folder, checkpoints (periodic, interrupted, best), progress line, TensorBoard scalars,
summary.json, stop requests and learner guard of an rsl-rl-lib run. The env side is the same VecTask step.

Which keys of the YAML are read, and which are refused: learning/rl_games_config.py and docs/config.md.
"""

from __future__ import annotations

import contextlib
import copy
import io
import tempfile
from pathlib import Path
from typing import Any, Callable

import torch
from omegaconf import DictConfig, open_dict

from isaacgymenvs_mw.learning.guard import LearnerGuard
from isaacgymenvs_mw.learning.learners import Learner
from isaacgymenvs_mw.learning.rl_games_config import LEARNER, check_rl_games_config, fitted_minibatch, seq_length
from isaacgymenvs_mw.learning.train_config import check_train_config, recipe_reward_scale
from isaacgymenvs_mw.learning.training_run import Iteration, TrainingRun
from isaacgymenvs_mw.learning.vecenv import TaskEnv
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.utils.config import to_dict
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.files import atomic_save

def rl_games_params(cfg: DictConfig, task: VecTask) -> dict:
    """The checked ``train.params`` of the run, with what the run decides (envs, device, multi-GPU) put in."""
    train_cfg = to_dict(cfg.train)
    check_rl_games_config(train_cfg)
    params = train_cfg["params"]
    config = params["config"]
    if "seed" in params and params["seed"] not in (None, "") and int(params["seed"]) != int(cfg.seed):
        raise ConfigError(f"train.params.seed={params['seed']} differs from the run's seed={cfg.seed}: the run key "
                          "seeds the run (IsaacGymEnvs' YAMLs write seed: ${...seed})")
    load_path = params.get("load_path") or ""
    if load_path and Path(str(load_path)).expanduser().resolve() != Path(str(cfg.checkpoint)).expanduser().resolve():
        raise ConfigError(f"train.params.load_path={load_path!r} differs from the run's checkpoint="
                          f"{cfg.checkpoint!r}: the run key names the checkpoint (IsaacGymEnvs' YAMLs write "
                          "load_path: ${...checkpoint})")
    actors = config.get("num_actors", task.num_envs)
    if int(actors) != task.num_envs:
        raise ConfigError(f"train.params.config.num_actors={actors} differs from the task's {task.num_envs} envs: "
                          "write num_actors: ${....task.env.numEnvs}")
    if train_cfg.get("asymmetric_obs") and task.num_states == 0:
        raise ConfigError(f"train.asymmetric_obs=True, but task {cfg.task_name} gives its critic no state (numStates "
                          "0): turn the task's asymmetric observations on (Trifinger: task.env.asymmetric_obs=True) "
                          "or set train.asymmetric_obs=False")
    if task.observations.images is not None:
        raise ConfigError(f"task={cfg.task_name} observes camera images, which learner=rl_games does not feed to a "
                          "CNN here: train it with the rsl_rl learner")
    config["num_actors"] = task.num_envs
    if params["network"].get("rnn"):
        config["seq_length"] = seq_length(config)  # IsaacGymEnvs' LSTM YAMLs say seq_len, which rl_games 1.6 skips
        config.pop("seq_len", None)
    fit_minibatches(config, task.num_envs, announce=not cfg.test,
                    multiple=config["seq_length"] if params["network"].get("rnn") else 1)
    config["device"] = config["device_name"] = task.rl_device
    config["multi_gpu"] = bool(cfg.get("multi_gpu", False))
    config.setdefault("name", cfg.task_name)
    if not str(task.rl_device).startswith("cuda"):
        config["mixed_precision"] = False
    return params


def fit_minibatches(config: dict, num_envs: int, announce: bool, multiple: int = 1) -> None:
    """rl_games refuses a ``minibatch_size`` that does not divide an iteration's samples (``horizon_length`` x envs):
    IsaacGymEnvs' YAMLs size it for their default envs (AntPPO's 32768 at 4096 envs), so a run with fewer envs (a
    CPU, a test) takes the largest divisor below it instead, with one line when it trains (``announce``); test mode
    builds the same agent but never updates, so it adapts silently. ``central_value_config`` alike. An RNN's
    minibatches hold whole sequences: ``multiple`` (its ``seq_length``) divides the size too."""
    samples = int(config.get("horizon_length", 0)) * num_envs
    sections = [("train.params.config", config)]
    if isinstance(config.get("central_value_config"), dict):
        sections.append(("train.params.config.central_value_config", config["central_value_config"]))
    for where, section in sections:
        size = section.get("minibatch_size") or num_envs * int(section.get("minibatch_size_per_env", 0) or 0)
        if samples <= 0 or int(size) <= 0 or (samples % int(size) == 0 and int(size) % multiple == 0):
            continue
        fitted = fitted_minibatch(samples, int(size), multiple)
        section["minibatch_size"] = fitted
        if announce:
            print(f"[train] note: {where}.minibatch_size={size} does not divide an iteration's {samples} samples "
                  f"({num_envs} envs x horizon_length {config.get('horizon_length')})"
                  + (f" in whole sequences of seq_length {multiple}" if multiple > 1 else "")
                  + f", as rl_games requires: using {fitted}", flush=True)


class RlGamesVecEnv(TaskEnv):
    """Presents a VecTask to rl_games (its IVecEnv contract: ``step`` returns the obs dict, rewards, dones and
    extras, ``extras['time_outs']`` bootstraps). ``reward_scale`` is reward_shaper.scale_value: rl_games applies it
    to the reward it is given, and the statistics report the scaled reward it learns from. ``on_step`` (set by the
    runner) runs after each step: stop requests and progress lines."""

    def __init__(self, task: VecTask, reward_scale: float = 1.0) -> None:
        super().__init__(task, reward_scale)
        self.on_step: Callable[[], None] | None = None

    def step(self, actions: torch.Tensor) -> tuple[dict, torch.Tensor, torch.Tensor, dict]:
        obs_dict, rew, _, reset, extras = self.step_task(actions)
        if self.on_step is not None:
            self.on_step()
        return _rl_games_obs(obs_dict), rew, reset, extras

    def reset(self) -> dict:
        return _rl_games_obs(self.task.reset())

    def get_number_of_agents(self) -> int:
        return 1

    def has_action_masks(self) -> bool:
        return False

    def get_env_info(self) -> dict:
        info = {"action_space": self.task.action_space, "observation_space": self.task.observation_space,
                "agents": 1, "value_size": 1}
        if self.task.num_states > 0:
            info["state_space"] = self.task.state_space  # with env.history.critic: the stacked size
        return info

    def set_train_info(self, env_frames: int, *args, **kwargs) -> None:
        pass  # the task counts its own env steps (VecTask.set_train_info is called on resume)

    def get_env_state(self) -> None:
        return self.task.get_env_state()

    def set_env_state(self, env_state: Any) -> None:
        self.task.set_env_state(env_state)

    def seed(self, seed: int) -> None:
        pass  # the run seeds torch, and the task's draws come from it


def _rl_games_obs(obs_dict: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """rl_games reads 'obs' and, with a central value network, 'states' (the actor's inputs when the task has none)."""
    return {"obs": obs_dict["obs"], "states": obs_dict.get("states", obs_dict["obs"])}


class _NoWriter:
    """rl_games writes its scalars to ``agent.writer``; where this process logs nothing (test mode, ranks > 0)."""

    def add_scalar(self, *args, **kwargs) -> None:
        pass

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass


class RlGamesRunner(TrainingRun):
    """rl_games' A2CAgent inside this project's training loop (the module's docstring)."""

    def __init__(self, env: RlGamesVecEnv, params: dict, log_dir: str | None, device: str,
                 verbose: bool = False) -> None:
        from rl_games.algos_torch.a2c_continuous import A2CAgent
        from rl_games.common.algo_observer import AlgoObserver
        from rl_games.common.tr_helpers import DefaultRewardsShaper

        self.env = env
        self.device = device
        self.log_dir = log_dir
        self.params = params
        config = params["config"]
        self.save_interval = int(config.get("save_frequency", 0) or 0)
        self.max_frames = int(config.get("max_frames", -1) or -1)
        self.score_to_win = config.get("score_to_win")
        self.max_iterations = int(config.get("max_epochs", -1))
        agent_params = {**params, "config": {
            **config, "env_info": env.get_env_info(), "vec_env": env,
            "reward_shaper": DefaultRewardsShaper(**(config.get("reward_shaper") or {})),
            "features": {"observer": AlgoObserver()}, "print_stats": False, "player": None}}
        # rl_games makes <train_dir>/<name>/{nn,summaries} and a SummaryWriter there: a folder of its own that goes
        # away; this runner's checkpoints and scalars go to the run folder.
        with tempfile.TemporaryDirectory(prefix="rl_games.") as scratch:
            agent_params["config"].update(train_dir=scratch, full_experiment_name="scratch")
            with contextlib.nullcontext() if verbose else contextlib.redirect_stdout(io.StringIO()):
                self.agent = A2CAgent(base_name="run", params=agent_params)
            if self.agent.writer is not None:  # rl_games makes a writer on rank 0 only
                self.agent.writer.close()
        self.agent.writer = _NoWriter()
        self.gpu_world_size = self.agent.world_size
        self.is_distributed = self.agent.multi_gpu
        self.current_learning_iteration = 0
        self.steps_per_env = int(self.agent.horizon_length)
        self._started = False
        self.init_training_run(LearnerGuard(self._learner_tensors), is_main=self.agent.global_rank == 0)
        self.best_after = int(config.get("save_best_after", 0) or 0)
        # test mode's actions: the mean, or samples of the policy as IsaacGymEnvs' player draws them
        self.test_actions = "mean" if (config.get("player") or {}).get("deterministic", True) else "sampled"
        self.log_std_model = params["model"]["name"] == "continuous_a2c_logstd"
        self.is_recurrent = bool(self.agent.is_rnn)

    def _learner_tensors(self) -> list[torch.Tensor]:
        """Every tensor that defines the learner: the model's parameters and buffers (normalisers included), a
        central value network's, and the optimisers' per-parameter state."""
        agent = self.agent
        modules = [agent.model] + ([agent.central_value_net] if agent.has_central_value else [])
        optimizers = [agent.optimizer] + ([agent.central_value_net.optimizer] if agent.has_central_value else [])
        tensors: list[torch.Tensor] = []
        for module in modules:
            tensors += list(module.parameters()) + list(module.buffers())
        for optimizer in optimizers:
            for state in optimizer.state.values():
                tensors += [v for v in state.values() if isinstance(v, torch.Tensor)]
        return tensors

    def current_learning_rate(self) -> float:
        return float(self.agent.last_lr)

    def _action_noise(self) -> dict[str, float]:
        sigma = getattr(self.agent.model.a2c_network, "sigma", None)
        if not isinstance(sigma, torch.Tensor) or not getattr(self.agent.model.a2c_network, "fixed_sigma", False):
            return {}
        with torch.no_grad():
            std = sigma.exp() if self.params["model"]["name"] == "continuous_a2c_logstd" else sigma
            low, mean, index = torch.stack([std.min(), std.mean(), std.argmin().to(std.dtype)]).tolist()
        return {"action_std_min": low, "action_std_mean": mean, "action_std_min_index": int(index)}

    def _start(self) -> None:
        """What rl_games' own ``train()`` does before its first epoch: buffers, the first observation, and with
        several GPUs rank 0's weights on every rank."""
        if self._started:
            return
        agent = self.agent
        agent.init_tensors()
        agent.obs = agent.env_reset()
        agent.curr_frames = agent.batch_size_envs
        if self.is_distributed:
            weights = [agent.model.state_dict()]
            torch.distributed.broadcast_object_list(weights, 0)
            agent.model.load_state_dict(weights[0])
        self._started = True

    def _attach_writer(self, writer) -> None:
        self.agent.writer = writer  # rl_games' own scalars too, under its names, for curves from IsaacGymEnvs

    def _detach_writer(self, writer) -> None:
        self.agent.writer = _NoWriter()

    def _begin_learning(self) -> None:
        self.env.on_step = self._step_done
        self._start()

    def _end_learning(self) -> None:
        self.env.on_step = None

    def _train_iteration(self, it: int, writer) -> Iteration:
        """One rl_games ``train_epoch`` (its rollout calls ``_step_done`` through the env's ``on_step``)."""
        agent = self.agent
        agent.epoch_num = it + 1
        (step_s, play_s, update_s, total_s, a_losses, c_losses, b_losses, entropies, kls, last_lr,
         lr_mul) = agent.train_epoch()
        agent.dataset.update_values_dict(None)  # the rollout's tensors are not needed until the next one
        frames = agent.curr_frames * self.gpu_world_size
        agent.frame += frames
        losses = _mean_losses(surrogate=a_losses, value=c_losses, entropy=entropies, kl=kls, bounds=b_losses)
        if writer is not None:
            agent.write_stats(total_s, it + 1, max(step_s, 1e-9), play_s, update_s, a_losses, c_losses, entropies,
                              kls, last_lr, lr_mul, agent.frame, total_s, play_s, frames)
        return Iteration(play_s, update_s, losses)

    def _reached_goal(self) -> bool:
        """rl_games' own ends: ``max_frames`` env steps, or a mean episode reward above ``score_to_win``."""
        if self.max_frames > 0 and self.total_env_steps >= self.max_frames:
            print(f"[train] max_frames={self.max_frames} env steps reached", flush=True)
            return True
        reward = self.recent_means().get("mean_episode_reward")
        if self.score_to_win is not None and reward is not None and reward > float(self.score_to_win):
            print(f"[train] the mean episode reward {reward:.2f} is above score_to_win={self.score_to_win}",
                  flush=True)
            return True
        return False

    def save(self, path: str) -> None:
        """rl_games' checkpoint (model, optimiser, epoch, frame) with this run's iteration and env steps; written
        whole or not at all."""
        state = self.agent.get_full_state_weights()
        state.update(learner=LEARNER, iteration=self.current_learning_iteration,
                     total_env_steps=self.total_env_steps)
        atomic_save(path, lambda partial: torch.save(state, partial))

    def load(self, path: str, map_location: str | None = None, state: dict | None = None) -> None:
        if state is None:
            state = torch.load(path, map_location=map_location or self.device, weights_only=False)
        state = _to_device(state, self.device)
        self.agent.set_full_state_weights(state, set_epoch=True)
        self.current_learning_iteration = int(state.get("iteration", state.get("epoch", 0)))
        self.total_env_steps = int(state.get("total_env_steps", state.get("frame", 0)))

    def load_checkpoint(self, path: Path, task: VecTask, state: dict) -> None:
        """Load a checkpoint (this runner's, or rl_games' own .pth) after checking its network fits the task."""
        model = state.get("model", {})
        ours = self.agent.model.state_dict()
        for key, value in model.items():
            if key in ours and tuple(ours[key].shape) != tuple(value.shape):
                raise ConfigError(f"checkpoint '{path}' does not fit this task and train YAML: its {key} has shape "
                                  f"{tuple(value.shape)}, this run's {tuple(ours[key].shape)} (task "
                                  f"{type(task).__name__}: {task.num_obs} observations, {task.num_actions} actions; "
                                  "network sizes: train.params.network.mlp.units)")
        missing = sorted(set(ours) - set(model))
        if missing:
            raise ConfigError(f"checkpoint '{path}' lacks {missing[0]}: it was written for another network "
                              "(train.params.network) or another learner")
        self.load(str(path), state=state)
        task.set_train_info(self.total_env_steps)

    def policy_module(self) -> torch.nn.Module:
        """The deterministic policy as a module: raw observations -> the action the env receives (rl_games clamps
        the mean to [-1, 1] and maps it onto the action space, as in training). A recurrent policy also takes its
        state and returns the next (``_RlGamesRecurrentPolicy``)."""
        return _RlGamesRecurrentPolicy(self.agent) if self.is_recurrent else _RlGamesPolicy(self.agent)

    def export_modules(self) -> tuple[torch.nn.Module, torch.jit.ScriptModule]:
        """The deterministic policy on the CPU, for ONNX and traced as TorchScript (a copy of the agent's)."""
        module = self.policy_module().to("cpu").eval()
        with torch.no_grad():
            return module, torch.jit.trace(module, module.get_dummy_inputs())

    def get_inference_policy(self, device: str | None = None) -> Callable:
        """Test mode's policy: the mean action, or (``player.deterministic: False``) a sample of the policy's
        Gaussian, clamped and mapped as the mean is (rl_games' player)."""
        kind = _RlGamesRecurrentPolicy if self.is_recurrent else _RlGamesPolicy
        module = kind(self.agent, sample=self.test_actions == "sampled", log_std=self.log_std_model)
        module = module.to(device or self.device).eval()
        if self.is_recurrent:
            return RecurrentPolicy(module)

        def policy(obs) -> torch.Tensor:
            with torch.no_grad():
                return module(obs["policy"])

        return policy


class _RlGamesPolicy(torch.nn.Module):
    """A trained rl_games agent's deterministic policy, copied out of it for test mode and export: its input
    normaliser ((x - mean) / sqrt(var + 1e-5), clamped to +-5, as rl_games' RunningMeanStd computes it; written out
    here because its TorchScript module cannot be traced as a submodule), its network's mean action, and rl_games'
    action mapping (the mean clamped to [-1, 1], then onto the action space's bounds). ``sample``: a draw from the
    policy's Gaussian (std exp(log std) for ``continuous_a2c_logstd``, the network's sigma for ``continuous_a2c``)
    takes the mean's place, as rl_games' player draws with ``deterministic: False``; test mode only, never exported."""

    def __init__(self, agent, sample: bool = False, log_std: bool = True) -> None:
        super().__init__()
        self.sample, self.log_std = sample, log_std
        model = agent.model
        self.network = copy.deepcopy(model.a2c_network)
        self.obs_shape = tuple(model.obs_shape)
        normaliser = model.running_mean_std if model.normalize_input else None
        self.normalize = normaliser is not None
        if normaliser is not None:
            self.register_buffer("obs_mean", normaliser.running_mean.detach().float().clone())
            self.register_buffer("obs_std", (normaliser.running_var.detach().float() + normaliser.epsilon).sqrt())
        self.clip = bool(agent.clip_actions)
        self.register_buffer("low", agent.actions_low.detach().clone())
        self.register_buffer("high", agent.actions_high.detach().clone())
        self.input_names = ["obs"]

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        mu, sigma = self.network({"obs": self.normalized(obs)})[:2]
        return self.action(mu, sigma)

    def normalized(self, obs: torch.Tensor) -> torch.Tensor:
        if not self.normalize:
            return obs
        return ((obs - self.obs_mean) / self.obs_std).clamp(-5.0, 5.0)

    def action(self, mu: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        """The env's action from the network's mean (or a draw around it, ``sample``)."""
        if self.sample:
            mu = mu + (sigma.exp() if self.log_std else sigma) * torch.randn_like(mu)
        if not self.clip:
            return mu
        return self.low + (mu.clamp(-1.0, 1.0) + 1.0) * 0.5 * (self.high - self.low)

    def get_dummy_inputs(self) -> tuple[torch.Tensor, ...]:
        return (torch.zeros(1, *self.obs_shape, device=self.low.device),)


class _RlGamesRecurrentPolicy(_RlGamesPolicy):
    """An rl_games LSTM or GRU policy, one step at a time: (observation, state) -> (action, next state), the state as
    rsl-rl-lib's recurrent exports carry it (``h_in``, and ``c_in`` for an LSTM, each layers x batch x units; zeros
    when an episode starts). The actor's path of rl_games' ``actor_critic`` forward, its layers reused: the RNN on
    the observation (``before_mlp``) or on the MLP's output (with the observation beside it, ``concat_input``), then
    its layer norm and ``concat_output``; with ``separate`` networks the critic's RNN is not needed for the action.
    A module of its own, since rl_games' forward sizes its sequences from Python integers, which a trace would
    freeze at one batch size."""

    is_recurrent = True

    def __init__(self, agent, sample: bool = False, log_std: bool = True) -> None:
        super().__init__(agent, sample=sample, log_std=log_std)
        net = self.network
        self.rnn_type = "lstm" if isinstance(self.rnn, torch.nn.LSTM) else "gru"
        self.num_layers, self.hidden_size = self.rnn.num_layers, self.rnn.hidden_size
        self.layer_norm = (net.a_layer_norm if net.separate else net.layer_norm) if net.rnn_ln else None
        self.before_mlp, self.concat_input = net.is_rnn_before_mlp, net.rnn_concat_input
        self.concat_output = net.rnn_concat_output
        states = ["h", "c"] if self.rnn_type == "lstm" else ["h"]
        self.input_names = ["obs", *(f"{s}_in" for s in states)]
        self.output_names = ["actions", *(f"{s}_out" for s in states)]

    @property
    def rnn(self) -> torch.nn.Module:
        """Torch's layer inside the copied network's RNN (rl_games wraps it in LSTMWithDones / GRUWithDones)."""
        return (self.network.a_rnn if self.network.separate else self.network.rnn).rnn

    def forward(self, obs: torch.Tensor, *state: torch.Tensor) -> tuple[torch.Tensor, ...]:
        mu, sigma, state = self.step(obs, state)
        return (self.action(mu, sigma), *state)

    def step(self, obs: torch.Tensor, state: tuple[torch.Tensor, ...]) -> tuple:
        """The network's mean and sigma for one step, and the RNN's next state."""
        net, x = self.network, self.normalized(obs).flatten(1)
        out = x if self.before_mlp else net.actor_mlp(x)
        if not self.before_mlp and self.concat_input:
            out = torch.cat([out, x], dim=1)
        out, state = self.rnn(out.unsqueeze(0), tuple(state) if self.rnn_type == "lstm" else state[0])
        out = out.squeeze(0)
        state = state if isinstance(state, tuple) else (state,)
        if self.layer_norm is not None:
            out = self.layer_norm(out)
        if self.concat_output:
            out = torch.cat([out, x], dim=1)
        if self.before_mlp:
            out = net.actor_mlp(out)
        mu = net.mu_act(net.mu(out))
        sigma = net.sigma_act(net.sigma) if net.fixed_sigma else net.sigma_act(net.sigma(out))
        return mu, mu * 0.0 + sigma, state

    def initial_state(self, batch: int) -> tuple[torch.Tensor, ...]:
        shape = (self.num_layers, batch, self.hidden_size)
        return tuple(torch.zeros(shape, device=self.low.device) for _ in self.input_names[1:])

    def get_dummy_inputs(self) -> tuple[torch.Tensor, ...]:
        return (*super().get_dummy_inputs(), *self.initial_state(1))


class RecurrentPolicy:
    """Test mode's recurrent policy: keeps each env's state between steps (zeros at the start), and ``reset(dones)``
    zeroes the state of the envs whose episode just ended, as rl_games' player does."""

    def __init__(self, module: _RlGamesRecurrentPolicy) -> None:
        self.module = module
        self.state: tuple[torch.Tensor, ...] | None = None

    def __call__(self, obs) -> torch.Tensor:
        x = obs["policy"]
        if self.state is None:
            self.state = self.module.initial_state(x.shape[0])
        with torch.no_grad():
            action, *state = self.module(x, *self.state)
        self.state = tuple(state)
        return action

    def reset(self, dones: torch.Tensor) -> None:
        if self.state is not None:
            keep = (dones == 0).to(self.state[0].device, self.state[0].dtype).view(1, -1, 1)
            self.state = tuple(s * keep for s in self.state)


def _mean_losses(**lists: list) -> dict[str, float]:
    """rl_games' per-minibatch loss tensors averaged per kind (one host read for all)."""
    present = {k: v for k, v in lists.items() if v}
    if not present:
        return {}
    means = torch.stack([torch.stack([x.detach().float().reshape(()) for x in v]).mean()
                         for v in present.values()]).tolist()
    return dict(zip(present, means))


def _to_device(state: Any, device: str) -> Any:
    if isinstance(state, torch.Tensor):
        return state.to(device)
    if isinstance(state, dict):
        return {k: _to_device(v, device) for k, v in state.items()}
    return state


class RlGamesLearner(Learner):
    """rl_games (IsaacGymEnvs' learner), configured by an rl_games train YAML (``params:``)."""

    name = LEARNER

    def check(self) -> None:
        train_cfg = to_dict(self.cfg.train)
        check_train_config(train_cfg, self.cfg.get("learner"))
        written = train_cfg["params"]["config"].get("max_epochs")
        self._max_epochs = int(written if written is not None else -1)
        wanted = self.cfg.get("max_iterations", "")
        if wanted not in ("", None) and int(wanted) != self._max_epochs:
            # A YAML that writes max_epochs as a number (IsaacGymEnvs' AllegroKukaPPO: 100000) does not interpolate
            # the run key, and one may leave it out (rl_games then trains without end: IGE's ShadowHandPPOLSTM); the
            # command line's value wins, and rl_games' linear schedules count to it too.
            told = " is not set" if written is None else f"={written}, which does not read it,"
            print(f"[train] note: train.params.config.max_epochs{told} and max_iterations={wanted} gives it",
                  flush=True)
            with open_dict(self.cfg.train.params.config):
                self.cfg.train.params.config.max_epochs = self._max_epochs = int(wanted)
        if written is None and self._max_epochs < 0:
            raise ConfigError("train.params.config.max_epochs is not set, and rl_games would train without end: give "
                              "max_iterations=N on the command line (or max_epochs in the YAML)")
        if self._max_epochs < 0:
            raise ConfigError(f"train.params.config.max_epochs={self._max_epochs} is invalid: give the iterations to "
                              "train (or max_iterations=N on the command line)")

    def runner_factory(self, task: VecTask) -> tuple[Callable[[], RlGamesRunner], str]:
        params = rl_games_params(self.cfg, task)
        experiment = str(params["config"]["name"] or self.cfg.experiment or self.cfg.task_name)
        env = RlGamesVecEnv(task, recipe_reward_scale({"params": params}))
        verbose = bool(self.cfg.get("verbose", False))
        return lambda: RlGamesRunner(env, params, log_dir=None, device=task.rl_device, verbose=verbose), experiment

    def max_iterations(self) -> int:
        return self._max_epochs

    def saved_iteration(self, state: dict) -> int:
        return int(state.get("iteration", state.get("epoch", 0)) or 0)
