"""PPO whose update never waits on the GPU, for rsl-rl-lib's OnPolicyRunner (`algorithm.class_name` in the train YAML).

rsl-rl-lib's ``PPO.update`` reads the GPU from the host several times per mini-batch: the adaptive learning-rate rule
compares the KL divergence on the host, multi-GPU runs broadcast the new rate and read it back, and every loss is
summed with ``.item()``. Each read stalls the Python thread until the GPU has drained its queue, so the next
mini-batch's kernels are launched into an idle GPU; with several GPUs, every stall also lines the ranks up with each
other. Here the learning rate lives in a device tensor that Adam reads directly, the KL divergence travels in the
same all-reduce as the gradients, and losses are summed on the device and read once per update. The rule and the
arithmetic are rsl-rl-lib's, so a run gives the same numbers (tests/learning/test_ppo.py checks this against rsl-rl-lib).

Without host reads the update is still thousands of small kernel launches from Python (the policy networks are
small, so launching costs more than computing). The whole update, all-reduces included, is therefore recorded once
as a CUDA graph and replayed (``capture_update``), which makes Go1's update 5x faster on a GPU (docs/BENCHMARKS.md).

rl_games' value normalisation (``normalize_value``, off by default) is a learner option here: the critic learns values
in units of running return statistics, the rollout and GAE stay in real units (``ValueNormalizer``).
"""

from __future__ import annotations

from collections.abc import Iterable
from itertools import chain

import torch
from rsl_rl.algorithms import PPO
from rsl_rl.modules import EmpiricalNormalization
from rsl_rl.modules.distribution import GaussianDistribution as RslRlGaussian
from rsl_rl.storage import RolloutStorage
from tensordict import TensorDict

# The normalisers, loss terms, learning rate, mini-batches and construction have modules of their own; the names
# tests and the runner import stay importable from here too.
from isaacgymenvs_mw.learning.normalizers import (
    VALUE_NORMALIZER_KEY,
    ClippedEmpiricalNormalization,
    ValueNormalizer,
    _RealUnitCritic,
)
from isaacgymenvs_mw.learning.ppo_batches import MiniBatchUpdate
from isaacgymenvs_mw.learning.ppo_construction import construct_algorithm
from isaacgymenvs_mw.learning.ppo_learning_rate import (
    LR_MAX,
    LR_MIN,
    DeviceLearningRate,
)
from isaacgymenvs_mw.learning.ppo_losses import bounds_loss, check_aux_loss, rl_games_kl
from isaacgymenvs_mw.learning.train_config import (
    GRAD_CLIP_SCOPES,
    KL_FORMS,
    KL_SCHEDULES,
    OBS_NORMALIZATION_FORMS,
)
from isaacgymenvs_mw.utils.config import boolean, one_of, real_number
from isaacgymenvs_mw.utils.errors import ConfigError


class SyncFreePPO(DeviceLearningRate, MiniBatchUpdate, PPO):
    """rsl-rl-lib's PPO with a host-sync-free update (the rollout side is inherited, un-normalising values only with
    ``normalize_value``).

    Supports what the shipped tasks use: feed-forward or recurrent actor/critic, Adam or AdamW, ``adaptive`` or
    ``fixed`` schedule, one or several GPUs. Random network distillation and symmetry augmentation are rejected with a
    pointer to rsl-rl-lib's own ``PPO``, which supports them.

    ``bounds_loss_coef`` (train YAML ``algorithm.bounds_loss_coef``, default 0: none): weight of rl_games' bounds
    loss on the action means (``bounds_loss``), which IsaacGymEnvs' configs use.

    ``aux_loss_coef`` (train YAML ``algorithm.aux_loss_coef``, default 0: none): weight of the actor's auxiliary loss
    (``ImageCNNModel.aux_loss``: its image encoders' features predict an observation group, ``actor.aux_target``),
    added to each mini-batch's loss; its mean over the update is logged as ``aux`` (Loss/aux). Captured with the
    rest of the update. > 0 needs an actor with ``aux_target``; with 0 such a head stays as initialised
    (``check_aux_loss``).

    ``learning_rate_min``, ``learning_rate_max`` (train YAML ``algorithm.learning_rate_min`` / ``_max``, default 1e-5
    and 1e-2: rsl-rl-lib's fixed bounds): the range in which the ``adaptive`` schedule keeps the learning rate. Both
    must be positive with min <= ``learning_rate`` <= max; a checkpoint's rate outside them is resumed at the nearest
    bound. They apply only to the ``adaptive`` schedule with a ``desired_kl``: with ``fixed`` (or no ``desired_kl``)
    the rate never moves, so a bound other than its default is refused rather than ignored.

    ``capture_update`` (``auto``, ``True``, ``False``; train YAML ``algorithm.capture_update``): replay the update as
    a CUDA graph. ``auto`` captures where it can: a CUDA device, feed-forward networks, no mixed precision
    (``use_mixed_precision``; an image model's ``cnn_precision: bfloat16`` is captured: its autocast keeps no cache).
    The first update runs eagerly (it creates Adam's state), the second captures. With several GPUs call
    ``release_graph`` before leaving the process group (the training launcher does).

    ``normalize_value`` (train YAML ``algorithm.normalize_value``, default False; IsaacGymEnvs' rl_games name):
    rl_games' value normalisation. The critic's output is a value in units of running statistics of the rollouts'
    values and returns (``value_normalizer``); the rollout un-normalises it before storing it, so time-out
    bootstrapping, GAE and the stored returns are in real units. Each update first merges the rollout's values, then
    its returns, into the statistics, then normalises the stored old values and returns with them, so the value
    loss (clipped or not) is computed in normalised units and so is the logged ``value`` loss. The statistics are
    saved in checkpoints; exported policies (the actor) do not use them. Several GPUs: the batch moments are
    all-reduced, every rank keeps the same statistics.

    rl_games' ways, each an option whose default is rsl-rl-lib's behaviour (docs/config.md, train YAML
    ``algorithm.<key>``):

    * ``kl_schedule``: ``per_mini_batch`` measures each mini-batch's KL against the rollout's policy and moves the
      rate before that mini-batch's step (rsl-rl-lib). ``per_epoch`` is rl_games' ``schedule_type: standard``: each
      sample's mean and std are stored as the mini-batch computes them, so from the second epoch on a mini-batch's
      KL measures the change since that sample was last seen (the rollout's in the first epoch); the rate moves once
      per epoch, after its last step, on the mean of its mini-batches' KLs, by rl_games' rule (no KL > 0 condition).
      The stored means and stds are device buffers written in place, so the update stays captured.
    * ``kl_form``: ``rsl_rl`` (the exact KL(old || new)) or ``rl_games`` (``rl_games_kl``).
    * ``grad_clip_scope``: ``per_network`` clips the actor's and the critic's gradient norms separately
      (rsl-rl-lib); ``global`` clips them together, as rl_games clips its one shared network.
    * ``obs_normalization_clip``: ``None``, or clamp the normalised observations of every model with
      ``obs_normalization`` to +-this (rl_games: 5, ``ClippedEmpiricalNormalization``).
    * ``obs_normalization_form``: ``rsl_rl`` ((x - mean) / (std + 1e-2)) or ``rl_games`` ((x - mean) /
      sqrt(var + 1e-5)), for every model with ``obs_normalization``.
    """

    def __init__(self, *args, capture_update: bool | str = "auto", bounds_loss_coef: float = 0.0,
                 normalize_value: bool = False, learning_rate_min: float = LR_MIN, learning_rate_max: float = LR_MAX,
                 kl_schedule: str = KL_SCHEDULES[0], kl_form: str = KL_FORMS[0],
                 grad_clip_scope: str = GRAD_CLIP_SCOPES[0], obs_normalization_clip: float | None = None,
                 obs_normalization_form: str = OBS_NORMALIZATION_FORMS[0], aux_loss_coef: float = 0.0,
                 **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.learning_rate_min, self.learning_rate_max = self._check_rate_bounds(learning_rate_min, learning_rate_max)
        self.kl_schedule = one_of(kl_schedule, "train.algorithm.kl_schedule", KL_SCHEDULES)
        self.kl_form = one_of(kl_form, "train.algorithm.kl_form", KL_FORMS)
        for name, value, default in (("kl_schedule", kl_schedule, KL_SCHEDULES[0]), ("kl_form", kl_form, KL_FORMS[0])):
            if value != default:
                self._refuse_without_adaptive(f"train.algorithm.{name}", value)
        if self.kl_form == "rl_games":
            self._need_gaussian("train.algorithm.kl_form=rl_games", "its KL is written for a mean and a std")
        self.grad_clip_scope = one_of(grad_clip_scope, "train.algorithm.grad_clip_scope", GRAD_CLIP_SCOPES)
        self._shape_observations(obs_normalization_clip, obs_normalization_form)
        self.bounds_loss_coef = real_number(bounds_loss_coef, "train.algorithm.bounds_loss_coef", low=0)
        self.normalize_value = boolean(normalize_value, "train.algorithm.normalize_value")
        self.value_normalizer = ValueNormalizer(self.device) if self.normalize_value else None
        self.aux_loss_coef = check_aux_loss(aux_loss_coef, self._raw_actor, self._raw_critic)
        if self.bounds_loss_coef > 0.0:
            self._need_gaussian("train.algorithm.bounds_loss_coef > 0", "it bounds the action means")
        unsupported = [key for key, used in (("rnd_cfg", self.rnd), ("symmetry_cfg", self.symmetry)) if used]
        if unsupported:
            raise ConfigError(
                f"train.algorithm.{unsupported[0]} is not supported by SyncFreePPO; "
                "set train.algorithm.class_name=PPO to use rsl-rl-lib's PPO, which supports it"
            )
        if type(self.optimizer) not in (torch.optim.Adam, torch.optim.AdamW):
            raise ConfigError(
                f"train.algorithm.optimizer={type(self.optimizer).__name__.lower()} is not supported by SyncFreePPO "
                "(valid: adam, adamw); set train.algorithm.class_name=PPO to use rsl-rl-lib's PPO with it"
            )
        self._params = [p for p in chain(self._raw_actor.parameters(), self._raw_critic.parameters())
                        if p.requires_grad]
        dtypes = {p.dtype for p in self._params}
        if len(dtypes) != 1:
            raise ConfigError(f"SyncFreePPO needs actor and critic parameters of one dtype, got "
                             f"{sorted(map(str, dtypes))}; set train.algorithm.class_name=PPO to use rsl-rl-lib's PPO")
        # All gradients are views into one flat buffer whose last element carries the mini-batch's KL divergence,
        # so a multi-GPU step needs a single all-reduce and no copies.
        sizes = [p.numel() for p in self._params]
        self._flat = torch.zeros(sum(sizes) + 1, dtype=dtypes.pop(), device=self.device)
        self._grad_views = [v.view_as(p) for v, p in zip(self._flat[:-1].split(sizes), self._params)]
        bucket = max(1, int(self.grad_reduce_bucket_mb * 2**20) // self._flat.element_size())
        self._flat_buckets = self._flat.split(bucket)  # the all-reduce's pieces, fixed views of the buffer
        self._on_cuda = torch.device(self.device).type == "cuda"
        self._recurrent = self.actor.is_recurrent or self.critic.is_recurrent
        # The shuffle and the advantages are copied into fixed buffers, which a captured update reads.
        samples = self.storage.num_envs * self.storage.num_transitions_per_env
        self._num_samples = self.num_mini_batches * (samples // self.num_mini_batches)
        self._perm = torch.empty(self._num_samples, dtype=torch.long, device=self.device)
        self._advantages = torch.zeros_like(self.storage.advantages)
        self.capture_update = self._resolve_capture(capture_update)
        # Optimiser steps skipped because their loss or gradient was not finite, counted on the device; the runner
        # reads the count when it logs (``take_skipped_steps``).
        self._skipped_steps = torch.zeros((), dtype=torch.long, device=self.device)
        self._step_ok = torch.ones((), dtype=torch.bool, device=self.device)
        self._graph: torch.cuda.CUDAGraph | None = None
        self._graph_loss_sums: torch.Tensor | None = None
        self._eager_updates = 0
        # kl_schedule=per_epoch: each sample's (mean, std) as last computed, allocated at the first update (the
        # storage allocates its own on the first transition); feed-forward in the order of the shuffle, so that a
        # mini-batch's share is a slice that its step writes in place.
        self._kl_reference: tuple[torch.Tensor, ...] | None = None
        self._install_device_learning_rate()

    @staticmethod
    def construct_algorithm(obs: TensorDict, env, cfg: dict, device: str) -> PPO:
        """rsl-rl-lib's construction; with ``algorithm.share_trunk`` the critic is the value head of the actor's
        trunk (``SharedTrunkCritic``, rl_games' ``separate: False``; learning/ppo_construction.py)."""
        return construct_algorithm(obs, env, cfg, device)

    def _need_gaussian(self, setting: str, why: str) -> None:
        if not isinstance(getattr(self.actor, "distribution", None), RslRlGaussian):
            raise ConfigError(f"{setting} needs a Gaussian action distribution (train.actor.distribution_cfg): {why}")

    def _shape_observations(self, clip, form: str) -> None:
        """``obs_normalization_clip`` and ``obs_normalization_form``: swap each model's observation normaliser for one
        that clamps its output and/or normalises as rl_games does."""
        keys = {"clip": "train.algorithm.obs_normalization_clip", "form": "train.algorithm.obs_normalization_form"}
        form = one_of(form, keys["form"], OBS_NORMALIZATION_FORMS)
        if clip is not None:
            clip = real_number(clip, keys["clip"], 0.0, low_open=True)
        given = [(keys["clip"], clip)] if clip is not None else []
        given += [(keys["form"], form)] if form != OBS_NORMALIZATION_FORMS[0] else []
        if not given:
            return
        models = [m for m in (self._raw_actor, self._raw_critic)
                  if isinstance(getattr(m, "obs_normalizer", None), EmpiricalNormalization)]
        if not models:
            key, value = given[0]
            raise ConfigError(f"{key}={value!r} has no effect: neither train.actor.obs_normalization nor "
                              "train.critic.obs_normalization is True; remove it or turn one on")
        for model in models:
            model.obs_normalizer = ClippedEmpiricalNormalization(model.obs_normalizer, clip,
                                                                 rl_games_form=form == "rl_games")

    def _resolve_capture(self, value: bool | str) -> bool:
        unmet = [need for need, missing in (
            ("a CUDA rl_device", not self._on_cuda), ("feed-forward actor and critic", self._recurrent),
            ("use_mixed_precision=False", self.use_mixed_precision)) if missing]
        if value == "auto":
            return not unmet
        if value is True:
            if unmet:
                raise ConfigError(f"train.algorithm.capture_update=True needs {' and '.join(unmet)}; "
                                 "use auto or False")
            return True
        if value is False:
            return False
        raise ConfigError(f"train.algorithm.capture_update={value!r} is not valid; valid: auto, True, False")

    # ------------------------------------------------------------------ rollout (value normalisation only)

    def act(self, obs: TensorDict) -> torch.Tensor:
        """rsl-rl-lib's act; with ``normalize_value`` the stored value is in real units, as the time-out bootstrap in
        ``process_env_step`` and GAE need."""
        actions = super().act(obs)
        if self.value_normalizer is not None:
            self.transition.values = self.value_normalizer.denormalize(self.transition.values)
        return actions

    def compute_returns(self, obs: TensorDict) -> None:
        """rsl-rl-lib's GAE; with ``normalize_value`` its last value (the critic's output) is un-normalised first."""
        if self.value_normalizer is None:
            super().compute_returns(obs)
            return
        critic = self.critic
        self.critic = _RealUnitCritic(critic, self.value_normalizer)  # type: ignore[assignment]
        try:
            super().compute_returns(obs)
        finally:
            self.critic = critic

    # ------------------------------------------------------------------ update

    def update(self) -> dict[str, float]:
        """PPO epochs over the stored rollout; returns the mean losses. Reads the GPU once, at the end."""
        if self.value_normalizer is not None:
            self._normalize_value_targets()
        loss_sums = self.run_mini_batches()
        observations = self.storage.observations.flatten(0, 1)
        for model in (self._raw_actor, self._raw_critic):
            normalizer = getattr(model, "obs_normalizer", None)
            std = getattr(normalizer, "_std", None)
            model.update_normalization(observations)  # type: ignore[operator]
            if isinstance(std, torch.Tensor) and normalizer._std is not std:
                # rsl-rl-lib replaces the std tensor; a captured update reads the one it was captured with
                normalizer._std = std.copy_(normalizer._std)
        num_updates = self.num_learning_epochs * self.num_mini_batches
        means = torch.cat([(loss_sums / num_updates).double(), self._lr64.view(1)]).tolist()
        value, surrogate, entropy, *aux, self.learning_rate = means
        self.storage.clear()
        losses = {"value": value, "surrogate": surrogate, "entropy": entropy}
        if aux:  # aux_loss_coef > 0: the auxiliary loss's mean, Loss/aux in TensorBoard
            losses["aux"] = aux[0]
        return losses

    def _normalize_value_targets(self) -> None:
        """rl_games' prepare_dataset: merge the rollout's values, then its returns, into the statistics, then bring
        the stored old values and returns into the critic's units. In place, outside the mini-batch loop: a captured
        update reads these same storage tensors, and the statistics change once per update, not per mini-batch.

        Both are normalised with the statistics after both merges, as rl_games' masked (RNN) path does; its
        feed-forward path normalises the old values before the returns are merged, which puts the clip's centre and
        the targets on slightly different scales (a difference that shrinks as the statistics' count grows)."""
        st = self.storage
        with torch.no_grad():
            self.value_normalizer.update(st.values, st.returns)  # type: ignore[union-attr]
            st.values.copy_(self.value_normalizer.normalize(st.values))  # type: ignore[union-attr]
            st.returns.copy_(self.value_normalizer.normalize(st.returns))  # type: ignore[union-attr]

    def _optimisation_steps(self, batches: Iterable[RolloutStorage.Batch]) -> torch.Tensor:
        adaptive, per_epoch = self._adaptive, self._per_epoch_kl
        use_aux = self.aux_loss_coef > 0.0
        loss_sums = torch.zeros(4 if use_aux else 3, device=self.device)
        epoch_kl = torch.zeros((), device=self.device)  # kl_schedule=per_epoch: the sum over the epoch's mini-batches
        for k, batch in enumerate(batches):
            if self.normalize_advantage_per_mini_batch:
                with torch.no_grad():
                    batch.advantages = (batch.advantages - batch.advantages.mean()) / (batch.advantages.std() + 1e-8)
            with torch.autocast(device_type=torch.device(self.device).type, enabled=self.use_mixed_precision,
                                dtype=torch.bfloat16):
                self.actor(batch.observations, masks=batch.masks, hidden_state=batch.hidden_states[0],
                           stochastic_output=True)
                log_prob = self.actor.get_output_log_prob(batch.actions)  # type: ignore[arg-type]
                values = self.critic(batch.observations, masks=batch.masks, hidden_state=batch.hidden_states[1])
                entropy = self.actor.output_entropy.mean()
                kl_mean = None
                if adaptive:
                    with torch.no_grad():
                        params = self.actor.output_distribution_params
                        kl_mean = self._kl_mean(batch.old_distribution_params, params)  # type: ignore[arg-type]
                        if per_epoch:  # what the next epoch measures its KL against (rl_games' update_mu_sigma)
                            for stored, new in zip(batch.old_distribution_params, params):  # type: ignore[arg-type]
                                stored.copy_(new)
                surrogate_loss = self._surrogate_loss(log_prob, batch)
                value_loss = self._value_loss(values, batch)
                loss = surrogate_loss + self.value_loss_coef * value_loss - self.entropy_coef * entropy
                if self.bounds_loss_coef > 0.0:
                    loss = loss + self.bounds_loss_coef * bounds_loss(self.actor.output_distribution_params[0])
                if use_aux:  # after the actor's forward on the same batch, whose image features it takes
                    aux_loss = self._raw_actor.aux_loss(batch.observations, masks=batch.masks)
                    loss = loss + self.aux_loss_coef * aux_loss

            self._flat.zero_()
            for param, view in zip(self._params, self._grad_views):
                param.grad = view  # re-attached each time: anything that set grads to None would detach them
            loss.backward()
            if self.is_multi_gpu:
                kl_mean = self._all_reduce_gradients(kl_mean)
            if kl_mean is not None and not per_epoch:
                self._adapt_learning_rate(kl_mean)
            # One non-finite sample (a blown-up world's state, a return that overflowed) makes the loss or the
            # gradient NaN, and one Adam step with it makes every weight NaN for good: such a step is skipped on the
            # device (fused Adam's found_inf) and counted, its losses left out of the sums. No host read.
            terms = [value_loss, surrogate_loss, entropy, *([aux_loss] if use_aux else [])]
            losses = torch.stack([t.detach().float() for t in terms])
            torch.logical_and(torch.isfinite(self._flat).all(), torch.isfinite(loss.detach()), out=self._step_ok)
            self.optimizer.found_inf = (~self._step_ok).float()
            self._skipped_steps += (~self._step_ok).long()
            if self.grad_clip_scope == "global":
                torch.nn.utils.clip_grad_norm_(self._params, self.max_grad_norm)
            else:
                torch.nn.utils.clip_grad_norm_(self.actor.parameters(), self.max_grad_norm)
                torch.nn.utils.clip_grad_norm_(self.critic.parameters(), self.max_grad_norm)
            self.optimizer.step()
            loss_sums += torch.where(self._step_ok, losses, torch.zeros_like(losses))
            if per_epoch:
                epoch_kl += kl_mean  # type: ignore[operator]
                if k % self.num_mini_batches == self.num_mini_batches - 1:  # the epoch's last step is taken
                    self._adapt_learning_rate(epoch_kl / self.num_mini_batches, rl_games_rule=True)
                    epoch_kl.zero_()
        return loss_sums

    def _kl_mean(self, old_params: tuple[torch.Tensor, ...], new_params: tuple[torch.Tensor, ...]) -> torch.Tensor:
        if self.kl_form == "rl_games":
            return rl_games_kl(*old_params, *new_params).mean()
        return self.actor.get_kl_divergence(old_params, new_params).mean()

    def take_skipped_steps(self) -> int:
        """Optimiser steps skipped since the last call (a host read: call it where the iteration syncs anyway)."""
        skipped = int(self._skipped_steps)
        self._skipped_steps.zero_()
        return skipped

    def _surrogate_loss(self, log_prob: torch.Tensor, batch) -> torch.Tensor:
        ratio = torch.exp(log_prob - torch.squeeze(batch.old_actions_log_prob))
        advantages = torch.squeeze(batch.advantages)
        clipped = torch.clamp(ratio, 1.0 - self.clip_param, 1.0 + self.clip_param)
        return torch.max(-advantages * ratio, -advantages * clipped).mean()

    def _value_loss(self, values: torch.Tensor, batch) -> torch.Tensor:
        if not self.use_clipped_value_loss:
            return (batch.returns - values).pow(2).mean()
        clipped = batch.values + (values - batch.values).clamp(-self.clip_param, self.clip_param)
        return torch.max((values - batch.returns).pow(2), (clipped - batch.returns).pow(2)).mean()

    def _all_reduce_gradients(self, kl_mean: torch.Tensor | None) -> torch.Tensor | None:
        """Average gradients (and the KL divergence) over the GPUs in ``grad_reduce_bucket_mb`` pieces.

        NCCL leaves identical results on every rank, so each rank applies the learning-rate rule to the same KL and
        arrives at rank 0's rate without the broadcast rsl-rl-lib needs.
        """
        if kl_mean is not None:
            self._flat[-1] = kl_mean
        for piece in self._flat_buckets:
            torch.distributed.all_reduce(piece, op=torch.distributed.ReduceOp.SUM)
        self._flat /= self.gpu_world_size
        return None if kl_mean is None else self._flat[-1]

    # ------------------------------------------------------------------ checkpoints

    def save(self) -> dict:
        """rsl-rl-lib's checkpoint, with the learning rate stored as a number so rsl-rl-lib's PPO can load it too,
        and with ``normalize_value`` the value statistics (a key rsl-rl-lib's PPO ignores)."""
        saved = super().save()
        if self.value_normalizer is not None:
            saved[VALUE_NORMALIZER_KEY] = self.value_normalizer.state_dict()
        for group in saved["optimizer_state_dict"]["param_groups"]:
            group["lr"] = float(group["lr"])
            group["capturable"] = False  # a graph-capture setting of this process, not of the checkpoint
        return saved

    def load(self, loaded_dict: dict, load_cfg: dict | None, strict: bool) -> bool:
        resume_iteration = super().load(loaded_dict, load_cfg, strict)
        # The statistics belong to the critic: they are loaded with it. load_state_dict copies into the existing
        # buffers, which a captured update keeps reading. A checkpoint without them (trained with normalize_value
        # False) leaves the statistics as they start.
        critic_loaded = load_cfg is None or bool(load_cfg.get("critic"))
        if self.value_normalizer is not None and critic_loaded and VALUE_NORMALIZER_KEY in loaded_dict:
            self.value_normalizer.load_state_dict(loaded_dict[VALUE_NORMALIZER_KEY])
        self._install_device_learning_rate()
        return resume_iteration
