"""A task's reward as named terms: value x scale (x dt where the task asks), summed, optionally clamped at zero,
with an optional penalty curriculum and the per-term episode sums every task reports the same way.

A term is a method ``_reward_<name>`` of the task returning (num_envs,) values (the legged_gym pattern); its scale
comes from the YAML or from the task. A zero scale removes the term: it is not computed. The YAML convention of new
tasks is one mapping, ``env.rewards.scales: {<name>: scale}`` (``RewardTerms.from_env``); a port from IsaacGymEnvs
may keep its flat keys (``distRewardScale``, ...), which ``from_env`` reads through a {term: key} map. IsaacGymEnvs'
global ``rewardScale`` (rl_games' reward shaper) stays with the ported tasks that have it; a new task puts that
factor in its scales. ``VecTask.reset_envs`` reports the finished episodes' sums in ``extras["episode_terms"]``
({term: sum over the episodes ending now}; the learner divides by their count).
"""

from __future__ import annotations

from typing import Callable, Mapping

import torch

from isaacgymenvs_mw.utils.config import real_number
from isaacgymenvs_mw.utils.errors import ConfigError

PREFIX = "_reward_"


def reward_methods(task: object) -> dict[str, Callable[[], torch.Tensor]]:
    """Every ``_reward_<name>`` method of ``task`` by name, sorted."""
    return {name[len(PREFIX):]: getattr(task, name) for name in sorted(dir(task)) if name.startswith(PREFIX)}


class RewardTerms:
    """Weighted reward terms of a batch of envs.

    Args:
        task: the object whose ``_reward_<name>`` methods compute the terms.
        scales: {term: scale}; the order is the terms' order. A name without a method fails naming ``key``.
        num_envs, device: batch and device of the episode sums.
        dt: factor on every scale (legged_gym weighs terms per second of policy time: the policy dt); 1: none.
        only_positive: clamp the sum of the terms at zero (legged_gym's ``only_positive_rewards``), except the
            ``unclamped`` terms, added after the clamp (a fall still costs something when all else is clamped).
        penalty_curriculum: ``{start, steps}`` (``key``.penaltyCurriculum) or None; see ``_init_penalty_curriculum``.
        step_count: env steps per env so far (the episode's clock, Episode.run_steps), read by the curriculum.
        key: the YAML section the scales come from, for error messages.
    """

    def __init__(self, task: object, scales: Mapping[str, float], num_envs: int, device: torch.device | str, *,
                 dt: float = 1.0, only_positive: bool = False, unclamped: tuple[str, ...] = (),
                 penalty_curriculum: Mapping | None = None, step_count: torch.Tensor | None = None,
                 key: str = "env.rewards") -> None:
        methods = reward_methods(task)
        unknown = [k for k in scales if k not in methods]
        if unknown:
            raise ConfigError(f"{key}.scales.{unknown[0]}: unknown reward term (all unknown: {unknown}); "
                              f"available terms: {sorted(methods)}")
        active = [(name, float(s)) for name, s in scales.items() if float(s) != 0.0]
        self.names = [name for name, _ in active]
        self.fns = [methods[name] for name in self.names]
        self.weights = torch.tensor([s * dt for _, s in active], device=device)
        self.only_positive = only_positive
        self._clamped = torch.tensor([name not in unclamped for name in self.names], dtype=torch.float32,
                                     device=device)
        # One column per active term, kept as one tensor so that the bookkeeping is a few kernels.
        self.episode_sums = torch.zeros(num_envs, len(active), device=device)
        self.step_count = step_count
        self._init_penalty_curriculum(penalty_curriculum, f"{key}.penaltyCurriculum")

    @classmethod
    def from_env(cls, task: object, env: Mapping, num_envs: int, device: torch.device | str, *,
                 ige_keys: Mapping[str, str] | None = None, **options) -> "RewardTerms":
        """The terms of a task YAML's ``env`` section, scaled as it says: ``env.rewards.scales`` ({term: scale}),
        or, for a port that keeps IsaacGymEnvs' flat keys, ``ige_keys`` ({term: key of ``env``}, e.g.
        ``{"dist": "distRewardScale"}``). ``options``: the constructor's (``dt``, ``only_positive``, ...)."""
        if ige_keys is not None:
            for term, key in ige_keys.items():
                if env.get(key) is None:
                    raise ConfigError(f"env.{key} is required: give the scale of the reward term {term}")
            scales = {term: real_number(env[key], f"env.{key}") for term, key in ige_keys.items()}
            return cls(task, scales, num_envs, device, key="env", **options)
        given = (env.get("rewards") or {}).get("scales")
        if not hasattr(given, "items"):
            raise ConfigError(f"env.rewards.scales is required: give {{term: scale}} (terms: "
                              f"{sorted(reward_methods(task))})")
        scales = {term: real_number(s, f"env.rewards.scales.{term}") for term, s in given.items()}
        return cls(task, scales, num_envs, device, key="env.rewards", **options)

    def _init_penalty_curriculum(self, cfg: Mapping | None, key: str) -> None:
        """Penalties (negative scales, unclamped terms aside) start at ``start`` x their scale and reach the full
        scale linearly over ``steps`` env steps per env (Hwangbo et al. 2019's cost curriculum for ANYmal, made
        linear). Early random actions then cost less than tracking earns: a clamped reward is not 0 from the start,
        and an unclamped one does not make falling early the cheapest way out."""
        self._curriculum: tuple[float, float] | None = None
        if cfg is None:
            return
        if not hasattr(cfg, "keys") or set(cfg.keys()) != {"start", "steps"}:
            raise ConfigError(f"{key} must be a mapping with exactly the keys start and steps, got {cfg!r}")
        try:
            start, steps = float(cfg["start"]), cfg["steps"]
        except (TypeError, ValueError):
            raise ConfigError(f"{key}.start must be a number in (0, 1], got {cfg['start']!r}") from None
        if not 0.0 < start <= 1.0:
            raise ConfigError(f"{key}.start must be in (0, 1] (the penalties' first scale factor), got {start}")
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ConfigError(f"{key}.steps must be a whole number >= 1 (env steps per env), got {steps!r}")
        self._curriculum = (start, float(steps))
        self._penalty_terms = (self.weights < 0.0).float() * self._clamped

    def penalty_factor(self) -> torch.Tensor | float:
        """The factor on the penalties now: 1 without a curriculum."""
        if self._curriculum is None:
            return 1.0
        start, steps = self._curriculum
        progress = torch.clamp(self.step_count / steps, max=1.0)
        return start + (1.0 - start) * progress

    def compute(self, earns_nothing: torch.Tensor) -> torch.Tensor:
        """The step's (num_envs,) reward; the ``earns_nothing`` envs' terms count 0, in the reward and in the sums
        (a blown-up world's terms read NaN states, and one NaN in a sum would stay for the rest of the run)."""
        if not self.fns:
            return torch.zeros_like(earns_nothing, dtype=torch.float)
        terms = torch.stack([fn() for fn in self.fns], dim=1) * self.weights
        if self._curriculum is not None:
            terms = terms * (1.0 + self._penalty_terms * (self.penalty_factor() - 1.0))
        terms = terms.masked_fill(earns_nothing.unsqueeze(1), 0.0)
        self.episode_sums += terms
        if self.only_positive:
            return (terms @ self._clamped).clamp(min=0.0) + terms @ (1.0 - self._clamped)
        return terms.sum(dim=1)

    def finish_episodes(self, mask: torch.Tensor) -> dict[str, torch.Tensor]:
        """{term: sum over the masked envs of their episode sums}; those envs' sums restart at zero."""
        finished = torch.where(mask.unsqueeze(1), self.episode_sums, 0.0).sum(dim=0)
        self.episode_sums.masked_fill_(mask.unsqueeze(1), 0.0)
        return dict(zip(self.names, finished.unbind()))
