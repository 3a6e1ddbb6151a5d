"""rl_games' loss terms that SyncFreePPO (learning/ppo.py) offers as options: its bounds loss on the action means and
its KL divergence, each a plain function of tensors so that it can be checked against a formula written out by hand;
and the check of the auxiliary loss's coefficient (the loss itself is the image model's, learning/models.py)."""

from __future__ import annotations

import torch

from isaacgymenvs_mw.learning.train_config import IMAGE_MODEL
from isaacgymenvs_mw.utils.config import real_number
from isaacgymenvs_mw.utils.errors import ConfigError

# rl_games' soft bound on the action means: outside +-1.1 a mean costs its squared excess (its bounds_loss).
SOFT_BOUND = 1.1


def bounds_loss(mean: torch.Tensor, soft_bound: float = SOFT_BOUND) -> torch.Tensor:
    """rl_games' bounds loss (IsaacGymEnvs' PPO configs, ``bounds_loss_coef``): per sample the sum over actions of
    the squared distance of each action mean beyond +-``soft_bound``, averaged over the batch. Actions are clipped to
    [-1, 1] by the env, so a mean far outside gets no gradient from the surrogate; this pulls it back."""
    above = torch.clamp(mean - soft_bound, min=0.0)
    below = torch.clamp(mean + soft_bound, max=0.0)
    return (above.pow(2) + below.pow(2)).sum(dim=-1).mean()


# rl_games' policy_kl (rl_games/algos_torch/torch_ext.py) adds this to the std ratio inside its log and to the old
# variance in its denominator.
RL_GAMES_KL_EPS = 1e-5


def rl_games_kl(old_mean: torch.Tensor, old_std: torch.Tensor, new_mean: torch.Tensor,
                new_std: torch.Tensor) -> torch.Tensor:
    """rl_games' KL divergence per sample, summed over actions: KL(new || old) of diagonal Gaussians with 1e-5 in
    the log's ratio and in the old variance. Where the old std has collapsed (s**2 comparable to 1e-5) the terms
    shrink by about s**2 / (s**2 + 1e-5), so one action whose noise has collapsed does not dominate the sum the way
    it does in the exact KL, which rsl-rl-lib measures (KL(old || new), ``GaussianDistribution.kl_divergence``)."""
    log_ratio = torch.log(old_std / new_std + RL_GAMES_KL_EPS)
    spread = (new_std.square() + (old_mean - new_mean).square()) / (2.0 * (old_std.square() + RL_GAMES_KL_EPS))
    return (log_ratio + spread - 0.5).sum(dim=-1)


def check_aux_loss(coef, actor, critic) -> float:
    """``algorithm.aux_loss_coef`` as a float >= 0, checked against the models: > 0 needs an actor with an auxiliary
    head (``ImageCNNModel`` with ``actor.aux_target``). A head on the critic is refused: no loss ever trains it.
    An actor's head with 0 stays as initialised (an ablation keeps the network and its checkpoints' keys)."""
    coef = real_number(coef, "train.algorithm.aux_loss_coef", low=0)
    if getattr(critic, "aux_head", None) is not None:
        raise ConfigError("train.critic.aux_target is not read: the auxiliary loss trains the actor's head; move it "
                          "to train.actor.aux_target or remove it")
    if coef > 0.0 and getattr(actor, "aux_head", None) is None:
        raise ConfigError(f"train.algorithm.aux_loss_coef={coef!r} needs train.actor.aux_target (train.actor.class_name"
                          f"={IMAGE_MODEL} with aux_target: {{group: <observation group>}}), got "
                          f"{type(actor).__name__} without one; add it or give train.algorithm.aux_loss_coef=0")
    return coef
