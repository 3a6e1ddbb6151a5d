"""PPO whose update never waits on the GPU, for rsl-rl-lib's OnPolicyRunner (`algorithm.class_name` in the train YAML).

rsl-rl-lib's ``PPO.update`` reads the GPU from the host several times per mini-batch: the adaptive learning-rate rule
compares the KL divergence on the host, multi-GPU runs broadcast the new rate and read it back, and every loss is
summed with ``.item()``. Each read stalls the Python thread until the GPU has drained its queue, so the next
mini-batch's kernels are launched into an idle GPU; with several GPUs, every stall also lines the ranks up with each
other. Here the learning rate lives in a device tensor that Adam reads directly, the KL divergence travels in the
same all-reduce as the gradients, and losses are summed on the device and read once per update. The rule and the
arithmetic are rsl-rl-lib's, so a run gives the same numbers (tests/test_ppo.py checks this against rsl-rl-lib).

Without host reads the update is still thousands of small kernel launches from Python (the policy networks are
small, so launching costs more than computing). The whole update, all-reduces included, is therefore recorded once
as a CUDA graph and replayed (``capture_update``), which made Go1's update 5x faster on an H100 (docs/PERFORMANCE.md).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from itertools import chain

import torch
from rsl_rl.algorithms import PPO
from rsl_rl.modules.distribution import GaussianDistribution as RslRlGaussian
from rsl_rl.storage import RolloutStorage

from isaacgymenvs_mw.utils.config import real_number
from isaacgymenvs_mw.utils.errors import ConfigError

LR_MIN, LR_MAX, LR_FACTOR = 1e-5, 1e-2, 1.5  # rsl-rl-lib's adaptive-schedule constants
EAGER_UPDATES_BEFORE_CAPTURE = 1


# rl_games' soft bound on the action means: outside +-1.1 a mean costs its squared excess (its bounds_loss).
SOFT_BOUND = 1.1


def bounds_loss(mean: torch.Tensor, soft_bound: float = SOFT_BOUND) -> torch.Tensor:
    """rl_games' bounds loss (IsaacGymEnvs' PPO configs, ``bounds_loss_coef``): per sample the sum over actions of
    the squared distance of each action mean beyond +-``soft_bound``, averaged over the batch. Actions are clipped to
    [-1, 1] by the env, so a mean far outside gets no gradient from the surrogate; this pulls it back."""
    above = torch.clamp(mean - soft_bound, min=0.0)
    below = torch.clamp(mean + soft_bound, max=0.0)
    return (above.pow(2) + below.pow(2)).sum(dim=-1).mean()


class SyncFreePPO(PPO):
    """rsl-rl-lib's PPO with a host-sync-free update (the rollout side is inherited unchanged).

    Supports what the shipped tasks use: feed-forward or recurrent actor/critic, Adam or AdamW, ``adaptive`` or
    ``fixed`` schedule, one or several GPUs. Random network distillation and symmetry augmentation are rejected with a
    pointer to rsl-rl-lib's own ``PPO``, which supports them.

    ``bounds_loss_coef`` (train YAML ``algorithm.bounds_loss_coef``, default 0: none): weight of rl_games' bounds
    loss on the action means (``bounds_loss``), which IsaacGymEnvs' configs use.

    ``capture_update`` (``auto``, ``True``, ``False``; train YAML ``algorithm.capture_update``): replay the update as
    a CUDA graph. ``auto`` captures where it can: a CUDA device, feed-forward networks, no mixed precision.
    The first update runs eagerly (it creates Adam's state), the second captures. With several GPUs call
    ``release_graph`` before leaving the process group (the training launcher does).
    """

    def __init__(self, *args, capture_update: bool | str = "auto", bounds_loss_coef: float = 0.0, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.bounds_loss_coef = real_number(bounds_loss_coef, "train.algorithm.bounds_loss_coef", low=0)
        if self.bounds_loss_coef > 0.0 and not isinstance(getattr(self.actor, "distribution", None), RslRlGaussian):
            raise ConfigError("train.algorithm.bounds_loss_coef > 0 needs a Gaussian action distribution "
                              "(train.actor.distribution_cfg): it bounds the action means")
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
        self._install_device_learning_rate()

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

    # ------------------------------------------------------------------ learning rate on the device

    def _install_device_learning_rate(self) -> None:
        """Put the optimizer's current rate into device tensors that Adam reads at each step."""
        rate = float(self.optimizer.param_groups[0]["lr"])
        self.learning_rate = rate
        # The rule runs in float64 like rsl-rl-lib's Python floats; Adam reads the float32 copy.
        self._lr64 = torch.tensor(rate, dtype=torch.float64, device=self.device)
        self._lr = torch.tensor(rate, dtype=torch.float32, device=self.device)
        # Fused Adam takes a device-tensor rate without reading it, and skips a step on the device when told to
        # (``found_inf``, set per mini-batch by ``_optimisation_steps``), on CUDA and on the CPU.
        flags = {"fused": True, "foreach": False, "capturable": False}
        for group in self.optimizer.param_groups:
            group["lr"] = self._lr
            group.update(flags)
        for param, state in self.optimizer.state.items():
            if "step" in state:
                state["step"] = state["step"].to(device=param.device if self._on_cuda else "cpu",
                                                 dtype=torch.float32)
        # A captured update reads the old rate and optimizer state: capture again from the next update on.
        self.release_graph()

    def _adapt_learning_rate(self, kl_mean: torch.Tensor) -> None:
        too_far = kl_mean > self.desired_kl * 2.0
        too_close = (kl_mean < self.desired_kl / 2.0) & (kl_mean > 0.0)
        lowered = torch.clamp(self._lr64 / LR_FACTOR, min=LR_MIN)
        raised = torch.clamp(self._lr64 * LR_FACTOR, max=LR_MAX)
        self._lr64.copy_(torch.where(too_far, lowered, torch.where(too_close, raised, self._lr64)))
        self._lr.copy_(self._lr64)

    # ------------------------------------------------------------------ update

    def update(self) -> dict[str, float]:
        """PPO epochs over the stored rollout; returns the mean losses. Reads the GPU once, at the end."""
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
        value, surrogate, entropy, rate = torch.cat([(loss_sums / num_updates).double(), self._lr64.view(1)]).tolist()
        self.learning_rate = rate
        self.storage.clear()
        return {"value": value, "surrogate": surrogate, "entropy": entropy}

    def run_mini_batches(self) -> torch.Tensor:
        """All optimisation steps of one update, queued without a host read.

        Returns the device tensor of summed [value loss, surrogate loss, entropy] over the mini-batches; with a
        captured update it is the graph's output, overwritten by the next update.
        """
        if self._recurrent:
            return self._optimisation_steps(
                self.storage.recurrent_mini_batch_generator(self.num_mini_batches, self.num_learning_epochs))
        # rsl-rl-lib's shuffle: one permutation per update, shared by its epochs
        torch.randperm(self._num_samples, out=self._perm)
        self._advantages.copy_(self.storage.advantages)
        if not self.capture_update:
            return self._optimisation_steps(self._feedforward_batches())
        if self._graph is None:
            if self._eager_updates < EAGER_UPDATES_BEFORE_CAPTURE:
                return self._warm_up_update()
            self._capture()
        self._graph.replay()  # type: ignore[union-attr]
        return self._graph_loss_sums  # type: ignore[return-value]

    def release_graph(self) -> None:
        """Free the captured update. With several GPUs the graph holds NCCL work, and leaving the process group
        while it exists hangs every rank (pytorch/pytorch#115388): call this before ``destroy_process_group``."""
        if self._graph is not None:
            torch.cuda.synchronize(self.device)
            self._graph.reset()
        self._graph, self._graph_loss_sums, self._eager_updates = None, None, 0

    def _warm_up_update(self) -> torch.Tensor:
        """An eager update on a side stream, as CUDA graph capture asks: it creates Adam's state, cuBLAS workspaces
        and autograd's stream bookkeeping before the graph records them."""
        stream = torch.cuda.Stream(self.device)
        stream.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(stream):
            loss_sums = self._optimisation_steps(self._feedforward_batches())
        torch.cuda.current_stream(self.device).wait_stream(stream)
        self._eager_updates += 1
        return loss_sums

    def _capture(self) -> None:
        """Record every mini-batch step of an update (forward, backward, rate, clip, Adam) as one CUDA graph over
        fixed buffers, so that an update is one launch instead of thousands of kernel launches."""
        for group in self.optimizer.param_groups:
            group["capturable"] = True  # Adam keeps its step count on the device already (fused)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            self._graph_loss_sums = self._optimisation_steps(self._feedforward_batches())
        self._graph = graph

    def _feedforward_batches(self) -> Iterator[RolloutStorage.Batch]:
        """The mini-batches of rsl-rl-lib's feed-forward generator, read through the fixed shuffle and advantages."""
        st = self.storage
        size = self._num_samples // self.num_mini_batches
        observations = st.observations.flatten(0, 1)
        actions, values, returns = st.actions.flatten(0, 1), st.values.flatten(0, 1), st.returns.flatten(0, 1)
        old_log_prob, advantages = st.actions_log_prob.flatten(0, 1), self._advantages.flatten(0, 1)
        old_params = tuple(p.flatten(0, 1) for p in st.distribution_params)  # type: ignore[union-attr]
        for _ in range(self.num_learning_epochs):
            for i in range(self.num_mini_batches):
                idx = self._perm[i * size:(i + 1) * size]
                yield RolloutStorage.Batch(
                    observations=observations[idx], actions=actions[idx], values=values[idx],  # type: ignore[arg-type]
                    advantages=advantages[idx], returns=returns[idx], old_actions_log_prob=old_log_prob[idx],
                    old_distribution_params=tuple(p[idx] for p in old_params))

    def _optimisation_steps(self, batches: Iterable[RolloutStorage.Batch]) -> torch.Tensor:
        adaptive = self.desired_kl is not None and self.schedule == "adaptive"
        loss_sums = torch.zeros(3, device=self.device)
        for batch in batches:
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
                        kl_mean = self.actor.get_kl_divergence(  # type: ignore[arg-type]
                            batch.old_distribution_params, self.actor.output_distribution_params).mean()
                surrogate_loss = self._surrogate_loss(log_prob, batch)
                value_loss = self._value_loss(values, batch)
                loss = surrogate_loss + self.value_loss_coef * value_loss - self.entropy_coef * entropy
                if self.bounds_loss_coef > 0.0:
                    loss = loss + self.bounds_loss_coef * bounds_loss(self.actor.output_distribution_params[0])

            self._flat.zero_()
            for param, view in zip(self._params, self._grad_views):
                param.grad = view  # re-attached each time: anything that set grads to None would detach them
            loss.backward()
            if self.is_multi_gpu:
                kl_mean = self._all_reduce_gradients(kl_mean)
            if kl_mean is not None:
                self._adapt_learning_rate(kl_mean)
            # One non-finite sample (a blown-up world's state, a return that overflowed) makes the loss or the
            # gradient NaN, and one Adam step with it makes every weight NaN for good: such a step is skipped on the
            # device (fused Adam's found_inf) and counted, its losses left out of the sums. No host read.
            losses = torch.stack([value_loss.detach(), surrogate_loss.detach(), entropy.detach()]).float()
            torch.logical_and(torch.isfinite(self._flat).all(), torch.isfinite(loss.detach()), out=self._step_ok)
            self.optimizer.found_inf = (~self._step_ok).float()
            self._skipped_steps += (~self._step_ok).long()
            torch.nn.utils.clip_grad_norm_(self.actor.parameters(), self.max_grad_norm)
            torch.nn.utils.clip_grad_norm_(self.critic.parameters(), self.max_grad_norm)
            self.optimizer.step()
            loss_sums += torch.where(self._step_ok, losses, torch.zeros_like(losses))
        return loss_sums

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
        """rsl-rl-lib's checkpoint, with the learning rate stored as a number so rsl-rl-lib's PPO can load it too."""
        saved = super().save()
        for group in saved["optimizer_state_dict"]["param_groups"]:
            group["lr"] = float(group["lr"])
            group["capturable"] = False  # a graph-capture setting of this process, not of the checkpoint
        return saved

    def load(self, loaded_dict: dict, load_cfg: dict | None, strict: bool) -> bool:
        resume_iteration = super().load(loaded_dict, load_cfg, strict)
        self._install_device_learning_rate()
        return resume_iteration
