"""SyncFreePPO's construction (learning/ppo.py): rsl-rl-lib's, or with ``algorithm.share_trunk`` a critic that is the
value head of the actor's trunk (rl_games' ``separate: False``)."""

from __future__ import annotations

from rsl_rl.algorithms import PPO
from rsl_rl.models import MLPModel
from rsl_rl.utils import resolve_class, resolve_obs_groups
from tensordict import TensorDict

from isaacgymenvs_mw.learning.models import SharedTrunkActor, SharedTrunkCritic
from isaacgymenvs_mw.utils.config import boolean
from isaacgymenvs_mw.utils.errors import ConfigError


def construct_algorithm(obs: TensorDict, env, cfg: dict, device: str) -> PPO:
    """rsl-rl-lib's construction; with ``algorithm.share_trunk`` the critic is the value head of the actor's
    trunk (``SharedTrunkCritic``, rl_games' ``separate: False``) instead of the ``critic`` section's model."""
    if "share_trunk" not in cfg["algorithm"]:
        return PPO.construct_algorithm(obs, env, cfg, device)
    algorithm = dict(cfg["algorithm"])
    share = boolean(algorithm.pop("share_trunk"), "train.algorithm.share_trunk")
    built = {**cfg, "algorithm": algorithm}
    if share:
        groups = resolve_obs_groups(obs, cfg["obs_groups"], ["actor", "critic"])
        if _same_observations(obs, groups["critic"], groups["actor"]):
            # A task without privileged states hands the policy's tensor to the critic group too (the hands'
            # `critic: [critic]` then means the policy's observation): the trunk reads the actor's groups.
            built["obs_groups"] = {**groups, "critic": list(groups["actor"])}
        else:
            raise ConfigError(
                f"train.algorithm.share_trunk=True needs train.runner.obs_groups.critic equal to "
                f"train.runner.obs_groups.actor (the value reads the policy's trunk), got "
                f"{list(groups['critic'])} and {list(groups['actor'])} (a privileged critic state, e.g. "
                f"task.env.asymmetric_observations=True); give train.runner.obs_groups.critic="
                f"{list(groups['actor'])} or train.algorithm.share_trunk=False")
        # rsl-rl-lib builds the actor, then the critic from the class its section names: the actor is kept on
        # the way so that the critic can be its value head. An MLPModel is built as the same network that hands
        # its trunk's features to the value head (any other class is refused by SharedTrunkCritic).
        actor_class, actor_cfg = resolve_class(dict(cfg["actor"]))
        if actor_class is MLPModel:
            actor_class = SharedTrunkActor
        models: list = []

        def actor(*args, **kwargs):
            models.append(actor_class(*args, **kwargs))
            return models[0]

        built["actor"] = {**actor_cfg, "class_name": actor}
        built["critic"] = {"class_name": lambda *args, **kwargs: SharedTrunkCritic(models[0])}
    alg = PPO.construct_algorithm(obs, env, built, device)
    cfg["obs_groups"] = built["obs_groups"]  # resolved in place by rsl-rl-lib, which the runner reads after
    return alg


def _same_observations(obs: TensorDict, groups: list[str], other: list[str]) -> bool:
    """Whether two observation groups give the same tensors (the same names, or names bound to one tensor)."""
    return len(groups) == len(other) and all(
        obs[a].data_ptr() == obs[b].data_ptr() and obs[a].shape == obs[b].shape for a, b in zip(groups, other))
