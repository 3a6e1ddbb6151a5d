"""The learner's last good state, kept in memory and put back when its weights, optimiser state or normaliser
statistics stop being finite.

A non-finite optimiser step is already skipped inside the update (``SyncFreePPO``) and non-finite observations and
rewards are replaced before the learner sees them (``VecTask``); this is the layer behind those two. Once per
iteration, where the runner reads the GPU anyway, it checks every tensor of the learner in one reduction. Finite:
the tensors are copied into a snapshot (in place, so a captured CUDA graph's addresses stay valid). Not finite: the
snapshot is copied back, or, before any snapshot exists, the run's last checkpoint is loaded.
"""

from __future__ import annotations

from typing import Callable

import torch


class LearnerGuard:
    """Keeps the last finite copy of ``tensors()`` (the learner's weights, buffers, optimiser state, learning rate)
    and restores it when they stop being finite."""

    def __init__(self, tensors: Callable[[], list[torch.Tensor]]) -> None:
        self._tensors = tensors
        self._ids: list[int] = []
        self._snapshot: list[torch.Tensor] = []
        self.restores = 0  # how often the last good state (or a checkpoint) was put back

    def all_finite(self, tensors: list[torch.Tensor]) -> bool:
        """One reduction per dtype and one host read: the check runs between iterations, whose rollouts are bound
        by how fast the host launches kernels, so it launches few."""
        by_dtype: dict[torch.dtype, list[torch.Tensor]] = {}
        for t in tensors:
            if t.is_floating_point():
                by_dtype.setdefault(t.dtype, []).append(t.detach().reshape(-1))
        if not by_dtype:
            return True
        finite = [torch.isfinite(torch.cat(group)).all() for group in by_dtype.values()]
        return bool(torch.stack(finite).all() if len(finite) > 1 else finite[0])

    def check(self) -> bool:
        """True when the learner was finite (its state is now the snapshot); False when the snapshot was put back.
        Raises ``NoGoodState`` when it is not finite and no snapshot exists yet."""
        tensors = self._tensors()
        if self.all_finite(tensors):
            self._keep(tensors)
            return True
        ids = [id(t) for t in tensors]
        if ids != self._ids:  # the tensors were replaced (a checkpoint loaded) since the last snapshot
            raise NoGoodState()
        with torch.no_grad():
            torch._foreach_copy_(tensors, self._snapshot)
        self.restores += 1
        return False

    def _keep(self, tensors: list[torch.Tensor]) -> None:
        ids = [id(t) for t in tensors]
        with torch.no_grad():
            if ids != self._ids:  # first snapshot, or the optimiser made or replaced its state
                self._snapshot = [t.detach().clone() for t in tensors]
                self._ids = ids
            else:
                torch._foreach_copy_(self._snapshot, [t.detach() for t in tensors])


class NoGoodState(RuntimeError):
    """The learner is not finite and no finite copy of it exists in memory."""


def learner_tensors(alg) -> list[torch.Tensor]:
    """Every tensor that defines an rsl-rl-lib PPO learner: actor and critic parameters and buffers (observation
    normalisers included), the value normaliser's statistics, the optimiser's per-parameter state, and a
    device-tensor learning rate."""
    tensors: list[torch.Tensor] = []
    value_normalizer = getattr(alg, "value_normalizer", None)  # SyncFreePPO with normalize_value=True
    for model in (alg.actor, alg.critic, value_normalizer):
        if model is not None:
            tensors += list(model.parameters()) + list(model.buffers())
    for state in alg.optimizer.state.values():
        tensors += [v for v in state.values() if isinstance(v, torch.Tensor)]
    for name in ("_lr", "_lr64"):  # SyncFreePPO's rate, which Adam reads from the device
        rate = getattr(alg, name, None)
        if isinstance(rate, torch.Tensor):
            tensors.append(rate)
    return tensors
