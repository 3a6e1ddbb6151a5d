"""Training with rsl-rl-lib's PPO, configured by cfg/train/<Task>PPO.yaml: one iteration and its wiring.

rsl_rl's OnPolicyRunner builds PPO, saves and loads checkpoints and exports policies; its ``learn`` loop is
replaced by this project's (learning/training_run.py), whose iteration here is a rollout that never waits on the GPU
(episode statistics stay on the device and are read once per iteration) and PPO's update. What a run keeps and
reports whatever the learner is lives in learning/training_run.py, learning/reporting.py and
learning/best_checkpoint.py; test mode in learning/evaluation.py.
"""

from __future__ import annotations

import contextlib
import io
import time
from pathlib import Path
from typing import Callable

import torch
from rsl_rl.runners import OnPolicyRunner
from rsl_rl.utils.log_writer import LogWriter

from isaacgymenvs_mw.learning.amp import with_amp
from isaacgymenvs_mw.learning.guard import LearnerGuard, learner_tensors
from isaacgymenvs_mw.learning.learners import Learner
from isaacgymenvs_mw.learning.loggers import check_logger
from isaacgymenvs_mw.learning.ppo import LR_MIN
from isaacgymenvs_mw.learning.reporting import collapsed_noise, noise_collapse_line
from isaacgymenvs_mw.learning.train_config import check_train_config, recipe_reward_scale
from isaacgymenvs_mw.learning.training_run import Iteration, TrainingRun
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.utils.config import to_dict
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.files import atomic_save


def rsl_rl_config(train_cfg: dict) -> dict:
    """Flatten our train YAML (runner/algorithm/actor/critic) into the dict OnPolicyRunner expects."""
    check_train_config(train_cfg)
    runner = dict(train_cfg["runner"])
    runner.pop("reward_scale", None)  # the env adapter's (RslRlVecEnv), not OnPolicyRunner's
    runner.pop("test_actions", None)  # test mode's (Runner.get_inference_policy)
    for key in ("num_steps_per_env", "max_iterations", "save_interval", "obs_groups"):
        if key not in runner:
            raise ConfigError(f"train.runner.{key} is required")
    for key, name in _class_names(train_cfg):
        _check_class_name(key, name)
    return {**runner, "algorithm": dict(train_cfg["algorithm"]), "actor": dict(train_cfg["actor"]),
            "critic": dict(train_cfg["critic"])}


def _class_names(train_cfg: dict) -> list[tuple[str, str]]:
    """The train YAML's ``class_name`` keys as typed (``train.algorithm.class_name``, ...) and their values."""
    found = []
    for section in ("algorithm", "actor", "critic"):
        node = train_cfg.get(section) or {}
        if "class_name" in node:
            found.append((f"train.{section}.class_name", node["class_name"]))
        dist = node.get("distribution_cfg") or {}
        if "class_name" in dist:
            found.append((f"train.{section}.distribution_cfg.class_name", dist["class_name"]))
    return found


def _check_class_name(key: str, name: object) -> None:
    """rsl-rl-lib resolves a class_name when it builds the runner, and a name it cannot find is its traceback: tell
    it here in one line, with rsl-rl-lib's class names that are spelt alike."""
    import difflib
    import pkgutil

    import rsl_rl
    from rsl_rl.utils.utils import resolve_callable

    try:
        resolve_callable(name)
        return
    except (ValueError, ImportError, AttributeError, TypeError):
        pass
    known = sorted({attr for _, module, _ in pkgutil.iter_modules(rsl_rl.__path__, "rsl_rl.")
                    for attr in dir(__import__(module, fromlist=["_"])) if attr[:1].isupper()})
    close = difflib.get_close_matches(str(name), known, n=3)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    raise ConfigError(f"{key}={name!r} names no class{hint}: give one of rsl-rl-lib's (PPO, MLPModel, ...) or "
                      "module.path:ClassName")


# A checkpoint's entry for what an env wrapper learns alongside the policy (AMP's discriminator, learning/amp.py).
ENV_STATE_KEY = "env_state_dict"

class Runner(TrainingRun, OnPolicyRunner):
    """OnPolicyRunner with a sync-free rollout inside this project's training loop (``TrainingRun.learn``, which
    replaces OnPolicyRunner's)."""

    def __init__(self, env: RslRlVecEnv, train_cfg: dict, log_dir: str | None, device: str,
                 verbose: bool = False) -> None:
        # rsl_rl prints the observation groups and both networks layer by layer; only verbose runs show that.
        with contextlib.nullcontext() if verbose else contextlib.redirect_stdout(io.StringIO()):
            super().__init__(env, train_cfg, log_dir=log_dir, device=device)
        self.log_dir = log_dir
        self.init_training_run(LearnerGuard(lambda: learner_tensors(self.alg)),
                               is_main=not self.is_distributed or self.gpu_global_rank == 0)

    @property
    def steps_per_env(self) -> int:
        return int(self.cfg["num_steps_per_env"])

    def current_learning_rate(self) -> float:
        return float(self.alg.learning_rate)

    @property
    def save_interval(self) -> int:
        return int(self.cfg["save_interval"])

    def _logger_config(self) -> dict:
        return self.cfg

    def _attach_writer(self, writer) -> None:
        self.logger.writer = writer  # rsl-rl-lib's save() uploads checkpoints through it (W&B)

    def _detach_writer(self, writer) -> None:
        if isinstance(writer, LogWriter):
            writer.stop()
        self.logger.writer = None

    def _begin_learning(self) -> None:
        self._obs = self.env.get_observations().to(self.device)
        self.alg.train_mode()
        if self.is_distributed:
            self.alg.broadcast_parameters()
        # On CUDA the host queues the update while the GPU still runs the rollout, so host clocks cannot split an
        # iteration; events on the GPU mark where the rollout ends.
        on_cuda = torch.device(self.device).type == "cuda"
        self._rollout_end = torch.cuda.Event(enable_timing=True) if on_cuda else None
        self._update_end = torch.cuda.Event(enable_timing=True) if on_cuda else None

    def _train_iteration(self, it: int, writer) -> Iteration:
        """One rollout with a sync-free env step, then PPO's update."""
        env: RslRlVecEnv = self.env  # type: ignore[assignment]
        obs = self._obs
        t0 = time.perf_counter()  # the GPU is idle here: the last iteration ended with a host read
        with torch.inference_mode():
            for _ in range(self.steps_per_env):
                actions = self.alg.act(obs)
                obs, rewards, dones, extras = env.step(actions.to(env.device))
                obs, rewards, dones = obs.to(self.device), rewards.to(self.device), dones.to(self.device)
                self.alg.process_env_step(obs, rewards, dones, extras)
                self._step_done()
            self.alg.compute_returns(obs)
        self._obs = obs
        t1 = time.perf_counter()
        if self._rollout_end is not None:
            self._rollout_end.record()
        losses = self.alg.update()  # ends by reading its losses, so the GPU has finished
        t2 = time.perf_counter()
        learn_s = t2 - t1
        if self._update_end is not None:
            self._update_end.record()
            self._update_end.synchronize()
            learn_s = self._rollout_end.elapsed_time(self._update_end) / 1000.0
        skipped = self.alg.take_skipped_steps() if hasattr(self.alg, "take_skipped_steps") else 0
        return Iteration(t2 - t0 - learn_s, learn_s, losses, skipped)

    def release(self) -> None:
        release_graph = getattr(self.alg, "release_graph", None)  # SyncFreePPO; rsl-rl-lib's PPO captures nothing
        if release_graph is not None:
            release_graph()

    def save(self, path: str, infos: dict | None = None) -> None:
        """rsl-rl-lib's checkpoint, written whole or not at all (a full disk leaves no truncated model_*.pt), with the
        run's env steps, from which a resumed run's count goes on; the upload (W&B) then sends the finished file."""
        state = {**self.alg.save(), "iter": self.current_learning_iteration,
                 "infos": {**(infos or {}), "env_steps": self.total_env_steps}}
        learned_by_env = getattr(self.env, "state_dict", None)  # an env wrapper that learns too (AMP's discriminator)
        if learned_by_env is not None:
            state[ENV_STATE_KEY] = learned_by_env()
        atomic_save(path, lambda partial: torch.save(state, partial))
        self.logger.save_model(path, self.current_learning_iteration)

    def load_checkpoint(self, checkpoint: Path, task, state: dict | None = None) -> None:
        """Load a checkpoint after checking that its policy fits this task's observation and action sizes and the
        train YAML's networks; ``state``: the file's contents when the caller has read them already."""
        if state is None:
            state = torch.load(checkpoint, map_location="cpu", weights_only=False)
        actor = state.get("actor_state_dict", {})
        weights = [v for k, v in actor.items() if k.startswith("mlp.") and k.endswith(".weight")]
        if weights:
            ckpt_obs, ckpt_act = weights[0].shape[1], weights[-1].shape[0]
            recurrent = actor.get("rnn.rnn.weight_ih_l0")  # rsl-rl-lib's RNNModel: the RNN reads the observation
            if recurrent is not None:
                ckpt_obs = recurrent.shape[1]
            num_obs = task.observation_space.shape[0]  # with env.history: the stacked size the policy sees
            # An image model's first MLP layer also reads its CNNs' features: only the actions can be compared here.
            images = any(k.startswith("cnns.") for k in actor)
            if (ckpt_obs != num_obs and not images) or ckpt_act != task.num_actions:
                raise ConfigError(
                    f"checkpoint '{checkpoint}' was trained with {ckpt_obs} observations and {ckpt_act} actions, but "
                    f"task {type(task).__name__} has {num_obs} observations and {task.num_actions} actions"
                )
        check_network_sizes(self, state, checkpoint)
        infos = self.load(str(checkpoint), map_location=task.rl_device)
        if ENV_STATE_KEY in state and hasattr(self.env, "load_state_dict"):
            self.env.load_state_dict(state[ENV_STATE_KEY])
        steps_per_iteration = self.steps_per_env * task.num_envs
        # The run's env-step count goes on from the checkpoint's (saved since it was recorded; estimated before).
        estimate = self.current_learning_iteration * steps_per_iteration
        self.total_env_steps = int((infos or {}).get("env_steps", estimate))
        # Randomisation schedules and the penalty curriculum count env steps per env: a resumed run goes on from the
        # checkpoint's, and test mode evaluates under the conditions the policy had reached.
        task.set_train_info(self.current_learning_iteration * steps_per_iteration)

    def get_inference_policy(self, device: str | None = None) -> Callable:
        """Test mode's policy: the mean action, or (``runner.test_actions: sampled``) a draw from the policy's
        distribution, which the task clamps to its action range as every action."""
        policy = super().get_inference_policy(device)
        if self.test_actions != "sampled":
            return policy
        return lambda obs: policy(obs, stochastic_output=True)

    def export_modules(self) -> tuple[torch.nn.Module, torch.jit.ScriptModule]:
        """The deterministic policy (normaliser included) on the CPU, for ONNX and as TorchScript (rsl-rl-lib's
        exporters' modules: copies, the runner's own stay where they are)."""
        policy = self.alg.get_policy()
        return policy.as_onnx(verbose=False).to("cpu").eval(), torch.jit.script(policy.as_jit().to("cpu").eval())

    def _action_noise(self) -> dict[str, float]:
        """The policy's action noise as its parameters hold it after the update: the mean and the smallest standard
        deviation over the actions. The smallest is the one to watch: a few collapsed actions pin the KL-adaptive rate
        at its floor (seen on ShadowHand). One small read; empty for a policy without a state-independent
        Gaussian (rsl-rl-lib's GaussianDistribution and ours keep ``std_param`` or ``log_std_param``)."""
        distribution = getattr(self.alg.get_policy(), "distribution", None)
        with torch.no_grad():
            if isinstance(getattr(distribution, "std_param", None), torch.Tensor):
                std = distribution.std_param.clamp(*distribution.std_range)
            elif isinstance(getattr(distribution, "log_std_param", None), torch.Tensor):
                std = distribution.log_std_param.clamp(*distribution.log_std_range).exp()
            else:
                return {}
            low, mean, index = torch.stack([std.min(), std.mean(), std.argmin().to(std.dtype)]).tolist()
        return {"action_std_min": low, "action_std_mean": mean, "action_std_min_index": int(index)}

    def _noise_lever(self) -> str:
        """The override to try first against a collapse: the noise learned as a log (on AllegroHand no action's noise
        collapsed with it in two seeds), or, for a policy that has it already, a floor."""
        std_type = (self.cfg["actor"].get("distribution_cfg") or {}).get("std_type", "scalar")  # actor: checked
        if std_type == "log":  # ++: Hydra's add-or-override, right whether the recipe holds the key or not
            return "++train.actor.distribution_cfg.std_range=[0.1,10.0]"
        return "train.actor.distribution_cfg.std_type=log"

    def _notice_noise_collapse(self, record: dict) -> None:
        """The first collapse of an action's noise (learning/reporting.py), kept for summary.json and said once."""
        if self.noise_collapse is not None:
            return
        alg = self.alg
        adaptive = getattr(alg, "desired_kl", None) is not None and getattr(alg, "schedule", None) == "adaptive"
        self.noise_collapse = collapsed_noise(record, adaptive, getattr(alg, "learning_rate_min", LR_MIN),
                                              self.env.task.action_actuators())
        if self.noise_collapse is not None:
            print(noise_collapse_line(self.noise_collapse, self._noise_lever()), flush=True)


def _mlp_widths(weights: dict) -> list[int]:
    """The hidden layer widths of an MLP from its state dict (mlp.<layer>.weight, in layer order)."""
    layers = sorted((int(k.split(".")[1]), v.shape[0]) for k, v in weights.items()
                    if k.startswith("mlp.") and k.endswith(".weight") and k.split(".")[1].isdigit())
    return [width for _, width in layers[:-1]]


SHARED_VALUE_HEAD = "value_head.weight"  # in critic_state_dict: the critic was a shared trunk's value head


def check_network_sizes(runner: Runner, state: dict, checkpoint: Path) -> None:
    """The checkpoint's networks have the layer sizes the train config builds; else name the first layer that
    differs and the config key that sets it (rsl-rl-lib would stop with a page of 'size mismatch' lines)."""
    built = runner.alg.save()
    shared = {name: SHARED_VALUE_HEAD in d.get("critic_state_dict", {})
              for name, d in (("mine", built), ("saved", state))}
    if "critic_state_dict" in state and shared["mine"] != shared["saved"]:
        raise ConfigError(f"checkpoint='{checkpoint}' was trained with train.algorithm.share_trunk={shared['saved']}, "
                          f"this run builds share_trunk={shared['mine']}: give "
                          f"++train.algorithm.share_trunk={shared['saved']}")  # ++: the recipe may hold it
    for part in ("actor", "critic"):
        mine, saved = built.get(f"{part}_state_dict", {}), state.get(f"{part}_state_dict", {})
        for name, tensor in saved.items():
            if name not in mine or tuple(mine[name].shape) == tuple(tensor.shape):
                continue
            shapes = f"{tuple(tensor.shape)} in the checkpoint, {tuple(mine[name].shape)} as configured"
            if name.startswith("mlp."):
                key = f"train.{part}.hidden_dims"
                hint = f"give {key}={_mlp_widths(saved)} (the checkpoint's), not {_mlp_widths(mine)}"
            else:
                key, hint = f"train.{part}", f"give the train.{part} settings it was trained with"
            raise ConfigError(f"checkpoint='{checkpoint}' does not fit {key}: its {part} layer {name} is {shapes}; "
                              f"{hint}")


class RslRlLearner(Learner):
    """rsl-rl-lib's PPO (this project's default), configured by cfg/train/<Task>PPO.yaml."""

    name = "rsl_rl"

    def check(self) -> None:
        self.test_actions = str(self.cfg.train.runner.get("test_actions", "mean"))
        self.train_cfg = rsl_rl_config(to_dict(self.cfg.train))
        if not self.cfg.test:
            check_logger(self.train_cfg)
        self._max_iterations = int(self.train_cfg.pop("max_iterations"))

    def runner_factory(self, task) -> tuple[Callable[[], Runner], str]:
        env = RslRlVecEnv(task, recipe_reward_scale(to_dict(self.cfg.train)))
        env = with_amp(env, to_dict(self.cfg.train))  # a train YAML's amp section: the style reward (learning/amp.py)
        experiment = str(self.train_cfg.pop("experiment_name", None) or self.cfg.experiment or self.cfg.task_name)
        verbose = bool(self.cfg.get("verbose", False))
        def make_runner() -> Runner:
            runner = Runner(env, self.train_cfg, log_dir=None, device=task.rl_device, verbose=verbose)
            runner.test_actions = self.test_actions
            return runner

        return make_runner, experiment

    def max_iterations(self) -> int:
        return self._max_iterations

    def saved_iteration(self, state: dict) -> int:
        return int(state.get("iter", 0) or 0)

    def random_start(self) -> bool:
        return bool(self.cfg.train.runner.get("init_at_random_ep_len", False))
