"""Adversarial motion priors (Peng et al. 2021, "AMP: Adversarial Motion Priors for Stylized Physics-Based Character
Control", arXiv:2104.02180) as a wrapper around the learner's env: PPO sees r = w_task r_task + w_style r_style.

A discriminator D (an MLP on one AMP observation: ``numAMPObsSteps`` consecutive states) learns to tell the motion
library's transitions (``task.fetch_amp_obs_demo``) from the policy's (``task.amp_obs`` each step). Least-squares GAN
loss (the paper's eq. 6, halved as IsaacGymEnvs halves its loss):

    0.5 (E_motion[(D - 1)^2] + E_policy[(D + 1)^2]) + grad_penalty E_motion[|grad_x D|^2]
        + logit_reg |W_logit|^2 + weight_decay sum |W|^2

and style reward r_style = disc_reward_scale max(0, 1 - 0.25 (D - 1)^2) (paper eq. 7). ``loss: bce`` is IsaacGymEnvs'
form instead (isaacgymenvs/learning/amp_continuous.py): binary cross-entropy on the logits and
r_style = -disc_reward_scale log(max(1 - sigmoid(D), 1e-4)). Weights and sizes: IsaacGymEnvs' HumanoidAMPPPO.yaml
(task_reward_w, disc_reward_w, disc_*, amp_replay_*). The input is normalised by running statistics of the samples
D trains on (``normalize_input``; rl_games' RunningMeanStd: (x - mean) / sqrt(var + 1e-5), clamped to +-5).

Each step the wrapper scores the step's transitions and stores them; every ``num_steps_per_env`` steps (one rollout)
it makes ``updates_per_rollout`` discriminator steps on mini-batches of half this rollout's, half replayed policy
transitions against as many motion samples, then adds the rollout to the replay buffer (ring; once full, each new
transition is kept with ``replay_keep_prob``, as IsaacGymEnvs keeps it).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import torch
from torch import nn

from isaacgymenvs_mw.utils.config import check_entry, one_of, real_number, whole_number
from isaacgymenvs_mw.utils.errors import ConfigError

LOSSES = ("lsgan", "bce")
ACTIVATIONS = {"relu": nn.ReLU, "elu": nn.ELU, "tanh": nn.Tanh}


@dataclass
class AMPConfig:
    """The train YAML's ``amp`` section (module docstring)."""

    task_reward_w: float = 0.0
    disc_reward_w: float = 1.0
    disc_reward_scale: float = 2.0
    loss: str = "lsgan"
    hidden_dims: tuple[int, ...] = (1024, 512)
    activation: str = "relu"
    learning_rate: float = 5e-5
    updates_per_rollout: int = 12
    minibatch_size: int = 4096
    grad_penalty: float = 5.0
    logit_reg: float = 0.05
    weight_decay: float = 1e-4
    replay_buffer_size: int = 1_000_000
    replay_keep_prob: float = 0.01
    normalize_input: bool = True

    @classmethod
    def from_dict(cls, section: dict, key: str = "train.amp") -> AMPConfig:
        check_entry(section, key, tuple(f.name for f in fields(cls)))
        cfg = cls(**{k: v for k, v in section.items()})
        for name in ("task_reward_w", "disc_reward_w", "disc_reward_scale", "grad_penalty", "logit_reg",
                     "weight_decay"):
            real_number(getattr(cfg, name), f"{key}.{name}", 0.0)
        real_number(cfg.learning_rate, f"{key}.learning_rate", 0.0, low_open=True)
        real_number(cfg.replay_keep_prob, f"{key}.replay_keep_prob", 0.0, 1.0)
        for name in ("updates_per_rollout", "minibatch_size", "replay_buffer_size"):
            whole_number(getattr(cfg, name), f"{key}.{name}", 1)
        one_of(cfg.loss, f"{key}.loss", LOSSES)
        one_of(cfg.activation, f"{key}.activation", tuple(ACTIVATIONS))
        dims = list(cfg.hidden_dims)
        if not dims:
            raise ConfigError(f"{key}.hidden_dims={dims!r} is invalid: give a list of layer sizes, e.g. [1024, 512]")
        cfg.hidden_dims = tuple(whole_number(d, f"{key}.hidden_dims", 1) for d in dims)
        return cfg


class Discriminator(nn.Module):
    """MLP from an AMP observation to one logit; ``logit`` is the last (linear) layer."""

    def __init__(self, num_inputs: int, hidden_dims: tuple[int, ...], activation: str) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        width = num_inputs
        for dim in hidden_dims:
            layers += [nn.Linear(width, dim), ACTIVATIONS[activation]()]
            width = dim
        self.trunk = nn.Sequential(*layers)
        self.logit = nn.Linear(width, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.logit(self.trunk(x)).squeeze(-1)

    def weights(self) -> list[torch.Tensor]:
        return [m.weight for m in self.modules() if isinstance(m, nn.Linear)]


def style_reward(d: torch.Tensor, loss: str = "lsgan", scale: float = 1.0) -> torch.Tensor:
    """The style reward of discriminator outputs ``d`` (module docstring)."""
    if loss == "lsgan":
        return scale * torch.clamp(1.0 - 0.25 * (d - 1.0) ** 2, min=0.0)
    prob = torch.sigmoid(d)
    return -scale * torch.log(torch.clamp(1.0 - prob, min=1e-4))


def discriminator_loss(disc: Discriminator, policy_obs: torch.Tensor, motion_obs: torch.Tensor,
                       cfg: AMPConfig) -> dict[str, torch.Tensor]:
    """The loss (module docstring) on normalised policy and motion samples, and its parts."""
    motion_obs = motion_obs.detach().requires_grad_(True)
    d_policy, d_motion = disc(policy_obs), disc(motion_obs)
    if cfg.loss == "lsgan":
        gan = 0.5 * (torch.mean((d_motion - 1.0) ** 2) + torch.mean((d_policy + 1.0) ** 2))
    else:
        bce = nn.functional.binary_cross_entropy_with_logits
        gan = 0.5 * (bce(d_motion, torch.ones_like(d_motion)) + bce(d_policy, torch.zeros_like(d_policy)))
    grad, = torch.autograd.grad(d_motion.sum(), motion_obs, create_graph=True)
    penalty = torch.mean(torch.sum(grad ** 2, dim=-1))
    logit = torch.sum(disc.logit.weight ** 2)
    decay = sum(torch.sum(w ** 2) for w in disc.weights())
    total = gan + cfg.grad_penalty * penalty + cfg.logit_reg * logit + cfg.weight_decay * decay
    return {"loss": total, "gan": gan, "grad_penalty": penalty, "d_policy": d_policy.mean().detach(),
            "d_motion": d_motion.mean().detach()}


class RunningNorm:
    """rl_games' RunningMeanStd on the device: batch-merged mean and variance, (x - mean) / sqrt(var + 1e-5), +-5."""

    def __init__(self, size: int, device: torch.device | str, enabled: bool = True) -> None:
        self.mean = torch.zeros(size, device=device)
        self.var = torch.ones(size, device=device)
        self.count = torch.full((), 1e-4, device=device)
        self.enabled = enabled

    def update(self, x: torch.Tensor) -> None:
        if not self.enabled:
            return
        n = x.shape[0]
        mean, var = x.mean(dim=0), x.var(dim=0, unbiased=False)
        total = self.count + n
        delta = mean - self.mean
        self.var.copy_((self.var * self.count + var * n + delta ** 2 * self.count * n / total) / total)
        self.mean.add_(delta * n / total)
        self.count.copy_(total)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        if not self.enabled:
            return x
        return torch.clamp((x - self.mean) / torch.sqrt(self.var + 1e-5), -5.0, 5.0)


class ReplayBuffer:
    """A ring of policy AMP observations on the device; once full, new rows are kept with ``keep_prob``."""

    def __init__(self, capacity: int, size: int, device: torch.device | str, keep_prob: float) -> None:
        self.data = torch.zeros(capacity, size, device=device)
        self.capacity, self.keep_prob = capacity, keep_prob
        self.head, self.count = 0, 0

    def store(self, rows: torch.Tensor) -> None:
        if self.count >= self.capacity and self.keep_prob < 1.0:
            rows = rows[torch.rand(rows.shape[0], device=rows.device) < self.keep_prob]
        rows = rows[-self.capacity:]
        n = rows.shape[0]
        idx = (self.head + torch.arange(n, device=rows.device)) % self.capacity
        self.data[idx] = rows
        self.head = (self.head + n) % self.capacity
        self.count = min(self.count + n, self.capacity)

    def sample(self, n: int) -> torch.Tensor:
        return self.data[torch.randint(0, self.count, (n,), device=self.data.device)]


class AMPVecEnv:
    """The learner's env (``RslRlVecEnv``) with the style reward mixed into each step's reward (module docstring).
    Everything but ``step`` is the wrapped env's."""

    def __init__(self, env: Any, cfg: AMPConfig, steps_per_rollout: int) -> None:
        task = env.task
        if not hasattr(task, "amp_obs") or not hasattr(task, "fetch_amp_obs_demo"):
            raise ConfigError(f"train.amp is set, but task {type(task).__name__} has no AMP observations "
                              "(amp_obs, fetch_amp_obs_demo): remove the amp section or use an AMP task")
        self.__dict__["env"] = env
        self.amp_cfg, self.steps_per_rollout = cfg, int(steps_per_rollout)
        dev, n, size = env.device, task.num_envs, task.amp_obs.shape[1]
        self.disc = Discriminator(size, cfg.hidden_dims, cfg.activation).to(dev)
        self.optimizer = torch.optim.Adam(self.disc.parameters(), lr=cfg.learning_rate)
        self.norm = RunningNorm(size, dev, cfg.normalize_input)
        self.replay = ReplayBuffer(cfg.replay_buffer_size, size, dev, cfg.replay_keep_prob)
        self.rollout = torch.zeros(self.steps_per_rollout * n, size, device=dev)
        self.step_in_rollout = 0
        # Device scalars reported with the iteration's statistics (AMP/<name>).
        self.info = {k: torch.zeros((), device=dev) for k in ("style_reward", "disc_loss", "d_policy", "d_motion")}
        env.stats.set_running(self.info, group="AMP")

    def __getattr__(self, name: str) -> Any:
        return getattr(self.__dict__["env"], name)

    @property
    def episode_length_buf(self) -> torch.Tensor:
        return self.env.episode_length_buf

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        self.env.episode_length_buf = value

    def step(self, actions: torch.Tensor):
        obs, rew, dones, extras = self.env.step(actions)
        amp_obs = self.env.task.amp_obs.to(self.env.device)
        with torch.no_grad():
            style = style_reward(self.disc(self.norm(amp_obs)), self.amp_cfg.loss, self.amp_cfg.disc_reward_scale)
        style = style * (~extras["nonfinite_resets"].to(style.device)).float()
        self.info["style_reward"].copy_(style.mean())
        n = amp_obs.shape[0]
        self.rollout[self.step_in_rollout * n:(self.step_in_rollout + 1) * n] = amp_obs
        self.step_in_rollout += 1
        if self.step_in_rollout == self.steps_per_rollout:
            self.step_in_rollout = 0
            self.train_discriminator()
        return obs, self.amp_cfg.task_reward_w * rew + self.amp_cfg.disc_reward_w * style, dones, extras

    def train_discriminator(self) -> None:
        """One rollout's discriminator steps, then the rollout joins the replay buffer."""
        cfg, task = self.amp_cfg, self.env.task
        with torch.inference_mode(False), torch.enable_grad():
            rollout = self.rollout.clone()
            half = max(cfg.minibatch_size // 2, 1)
            for _ in range(cfg.updates_per_rollout):
                policy = rollout[torch.randint(0, rollout.shape[0], (half,), device=rollout.device)]
                replayed = self.replay.sample(half) if self.replay.count else policy
                policy = torch.cat((policy, replayed))
                motion = task.fetch_amp_obs_demo(policy.shape[0]).to(rollout.device).clone()
                self.norm.update(torch.cat((policy, motion)))
                parts = discriminator_loss(self.disc, self.norm(policy), self.norm(motion), cfg)
                self.optimizer.zero_grad()
                parts["loss"].backward()
                self.optimizer.step()
            self.replay.store(rollout)
        self.info["disc_loss"].copy_(parts["loss"].detach())
        self.info["d_policy"].copy_(parts["d_policy"])
        self.info["d_motion"].copy_(parts["d_motion"])

    def test_mode_scores(self) -> AMPScores:
        """Test mode's measure of the imitation (``AMPScores``), with this wrapper's discriminator."""
        return AMPScores(self)

    def state_dict(self) -> dict[str, Any]:
        """What a checkpoint needs to resume the discriminator."""
        return {"disc": self.disc.state_dict(), "optimizer": self.optimizer.state_dict(),
                "norm": (self.norm.mean, self.norm.var, self.norm.count)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.disc.load_state_dict(state["disc"])
        self.optimizer.load_state_dict(state["optimizer"])
        for mine, saved in zip((self.norm.mean, self.norm.var, self.norm.count), state["norm"]):
            mine.copy_(saved)


class AMPScores:
    """How close the policy's motion is to the motion library's, as the trained discriminator sees it: its mean logit
    and style reward over the policy's transitions in each env's first episode (test mode's deterministic policy),
    and over as many transitions drawn from the motion library (at most ``MOTION_SAMPLES``). eval.json gets them as
    ``amp_d_policy``, ``amp_d_motion``, ``amp_style_reward_policy`` and ``amp_style_reward_motion``: a policy the
    discriminator cannot tell from the motions scores as the motions do."""

    MOTION_SAMPLES = 65536

    def __init__(self, wrapper: AMPVecEnv) -> None:
        self.wrapper = wrapper
        dev = wrapper.env.device
        self.sums = {key: torch.zeros((), device=dev) for key in ("d", "style", "count")}

    def _scores(self, amp_obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        cfg = self.wrapper.amp_cfg
        d = self.wrapper.disc(self.wrapper.norm(amp_obs.to(self.wrapper.env.device)))
        return d, style_reward(d, cfg.loss, cfg.disc_reward_scale)

    def observe(self, active: torch.Tensor) -> None:
        """After each test-mode step: score the transitions of the envs still in their first episode."""
        with torch.no_grad():
            d, style = self._scores(self.wrapper.env.task.amp_obs)
            weight = active.to(d.device).float()
            self.sums["d"] += (d * weight).sum()
            self.sums["style"] += (style * weight).sum()
            self.sums["count"] += weight.sum()

    def result(self) -> dict[str, float]:
        count = max(int(self.sums["count"]), 1)
        with torch.no_grad():
            motion = self.wrapper.env.task.fetch_amp_obs_demo(min(count, self.MOTION_SAMPLES))
            d_motion, style_motion = self._scores(motion)
        return {"amp_d_policy": float(self.sums["d"]) / count, "amp_d_motion": float(d_motion.mean()),
                "amp_style_reward_policy": float(self.sums["style"]) / count,
                "amp_style_reward_motion": float(style_motion.mean())}


def with_amp(env: Any, train_cfg: dict) -> Any:
    """``env`` wrapped by ``AMPVecEnv`` when the train YAML has an ``amp`` section; otherwise ``env`` itself."""
    section = train_cfg.get("amp")
    if not section:
        return env
    if not isinstance(section, dict):
        raise ConfigError(f"train.amp={section!r} is invalid: give a mapping of AMP settings (learning/amp.py)")
    steps = (train_cfg.get("runner") or {}).get("num_steps_per_env")
    return AMPVecEnv(env, AMPConfig.from_dict(section), whole_number(steps, "train.runner.num_steps_per_env", 1))
