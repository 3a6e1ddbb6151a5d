"""SyncFreePPO's mini-batches and captured update (learning/ppo.py): the shuffle and advantages in fixed buffers,
rsl-rl-lib's feed-forward and recurrent batches read through them, and the whole update recorded once as a CUDA graph
and replayed."""

from __future__ import annotations

from collections.abc import Iterator

import torch
from rsl_rl.storage import RolloutStorage

EAGER_UPDATES_BEFORE_CAPTURE = 1


class MiniBatchUpdate:
    """Mixin of SyncFreePPO: one update's optimisation steps over fixed buffers, eager or as a replayed graph."""

    def run_mini_batches(self) -> torch.Tensor:
        """All optimisation steps of one update, queued without a host read.

        Returns the device tensor of summed [value loss, surrogate loss, entropy(, auxiliary loss)] over the
        mini-batches; with a captured update it is the graph's output, overwritten by the next update.
        """
        if self._per_epoch_kl and self._kl_reference is None:  # outside any capture: the first update is eager
            params = self.storage.distribution_params  # type: ignore[union-attr]
            self._kl_reference = tuple(
                torch.empty_like(p) if self._recurrent else p.new_empty((self._num_samples, *p.shape[2:]))
                for p in params)
        if self._recurrent:
            return self._optimisation_steps(self._recurrent_batches())
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

    @property
    def _per_epoch_kl(self) -> bool:
        return self._adaptive and self.kl_schedule == "per_epoch"

    def _feedforward_batches(self) -> Iterator[RolloutStorage.Batch]:
        """The mini-batches of rsl-rl-lib's feed-forward generator, read through the fixed shuffle and advantages.
        With ``kl_schedule=per_epoch`` a batch's old distribution parameters are its slice of the stored ones (views
        that ``_optimisation_steps`` overwrites), which start each update as the rollout's, in shuffled order."""
        st = self.storage
        size = self._num_samples // self.num_mini_batches
        observations = st.observations.flatten(0, 1)
        actions, values, returns = st.actions.flatten(0, 1), st.values.flatten(0, 1), st.returns.flatten(0, 1)
        old_log_prob, advantages = st.actions_log_prob.flatten(0, 1), self._advantages.flatten(0, 1)
        old_params = tuple(p.flatten(0, 1) for p in st.distribution_params)  # type: ignore[union-attr]
        if self._per_epoch_kl:
            for stored, rollout in zip(self._kl_reference, old_params):  # type: ignore[arg-type]
                torch.index_select(rollout, 0, self._perm, out=stored)
        for _ in range(self.num_learning_epochs):
            for i in range(self.num_mini_batches):
                idx = self._perm[i * size:(i + 1) * size]
                reference = (tuple(p[i * size:(i + 1) * size] for p in self._kl_reference)  # type: ignore[union-attr]
                             if self._per_epoch_kl else tuple(p[idx] for p in old_params))
                yield RolloutStorage.Batch(
                    observations=observations[idx], actions=actions[idx], values=values[idx],  # type: ignore[arg-type]
                    advantages=advantages[idx], returns=returns[idx], old_actions_log_prob=old_log_prob[idx],
                    old_distribution_params=reference)

    def _recurrent_batches(self) -> Iterator[RolloutStorage.Batch]:
        """rsl-rl-lib's recurrent mini-batches (contiguous blocks of envs); with ``kl_schedule=per_epoch`` their old
        distribution parameters are the block of the stored ones, as in ``_feedforward_batches``."""
        batches = self.storage.recurrent_mini_batch_generator(self.num_mini_batches, self.num_learning_epochs)
        if not self._per_epoch_kl:
            yield from batches
            return
        for stored, rollout in zip(self._kl_reference, self.storage.distribution_params):  # type: ignore[arg-type]
            stored.copy_(rollout)
        size = self.storage.num_envs // self.num_mini_batches
        for k, batch in enumerate(batches):
            i = k % self.num_mini_batches
            batch.old_distribution_params = tuple(
                p[:, i * size:(i + 1) * size] for p in self._kl_reference)  # type: ignore[union-attr]
            yield batch
