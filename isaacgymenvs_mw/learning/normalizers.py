"""The normalisers of SyncFreePPO (learning/ppo.py): observations clamped and scaled as rl_games does, and rl_games'
value normalisation (the critic learns values in units of running return statistics; the rollout and GAE stay in real
units)."""

from __future__ import annotations

import torch
from rsl_rl.modules import EmpiricalNormalization


# rl_games' RunningMeanStd divides by sqrt(var + 1e-5); rsl-rl-lib's EmpiricalNormalization by std + 1e-2.
RL_GAMES_OBS_VAR_EPS = 1e-5


class ClippedEmpiricalNormalization(EmpiricalNormalization):
    """rsl-rl-lib's observation normaliser, optionally clamped to +-``clip`` and optionally in rl_games' form.

    The clamp is rl_games' (its RunningMeanStd clamps normalised inputs to +-5): one observation far outside what the
    statistics have seen (a contact spike, a cube flung away) then cannot feed the first layer a value of hundreds.
    ``rl_games_form`` divides by sqrt(var + 1e-5) as rl_games does, instead of rsl-rl-lib's std + 1e-2: an input
    whose spread is about 0.01-0.1 then reaches the network with unit spread rather than shrunk by up to 2x. Both read
    the same buffers (rsl-rl-lib updates its variance in place), so checkpoints load either way; exported policies
    (ONNX, TorchScript) copy it, clamp and form included."""

    def __init__(self, source: EmpiricalNormalization, clip: float | None = None,
                 rl_games_form: bool = False) -> None:
        super().__init__(tuple(source._mean.shape[1:]), eps=source.eps, until=source.until)
        self.to(source._mean.device)
        self.load_state_dict(source.state_dict())
        self.clamps = clip is not None
        self.clip = float(clip) if clip is not None else 0.0
        self.rl_games_form = rl_games_form
        self.variance_eps = RL_GAMES_OBS_VAR_EPS  # an attribute: TorchScript reads no module-level floats

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # written out rather than calling the parent's: TorchScript (the exported policy.pt) has no super()
        if self.rl_games_form:
            scaled = (x - self._mean) / torch.sqrt(self._var + self.variance_eps)
        else:
            scaled = (x - self._mean) / (self._std + self.eps)
        if self.clamps:
            scaled = scaled.clamp(-self.clip, self.clip)
        return scaled


# rl_games' RunningMeanStd (rl_games/algos_torch/running_mean_std.py): variance epsilon, and the clamp of normalised
# values (and of the critic's output before it is un-normalised) to +-5 standard deviations.
VALUE_NORM_EPS = 1e-5
VALUE_NORM_CLAMP = 5.0
VALUE_NORMALIZER_KEY = "value_normalizer_state_dict"  # the statistics' checkpoint key


class ValueNormalizer(torch.nn.Module):
    """rl_games' ``value_mean_std``: running mean and variance of scalar values and returns (float64, in place).

    Starts like rl_games' RunningMeanStd (mean 0, variance 1, count 1) and merges each batch's moments with Chan's
    parallel formula. The statistics are buffers updated with ``copy_`` and ``torch.where`` on the device, never
    replaced and never read on the host, so anything holding them (a checkpoint being written, the rollout's
    un-normalisation) sees the same tensors. SyncFreePPO updates them before the mini-batches, outside a captured
    update, which only reads the storage that they normalise. With ``torch.distributed``
    initialised, the batch moments are those of every rank's batch together (all-reduced), so the ranks keep
    identical statistics, as rsl-rl-lib's EmpiricalNormalization does for observations.
    """

    def __init__(self, device: str | torch.device) -> None:
        super().__init__()
        self.register_buffer("running_mean", torch.zeros((), dtype=torch.float64, device=device))
        self.register_buffer("running_var", torch.ones((), dtype=torch.float64, device=device))
        self.register_buffer("count", torch.ones((), dtype=torch.float64, device=device))

    def normalize(self, values: torch.Tensor) -> torch.Tensor:
        """Real units -> the critic's units, clamped to +-5 like rl_games."""
        scaled = (values.double() - self.running_mean) / torch.sqrt(self.running_var + VALUE_NORM_EPS)
        return scaled.clamp(-VALUE_NORM_CLAMP, VALUE_NORM_CLAMP).to(values.dtype)

    def denormalize(self, values: torch.Tensor) -> torch.Tensor:
        """The critic's units -> real units; rl_games clamps the critic's output to +-5 first."""
        clamped = values.double().clamp(-VALUE_NORM_CLAMP, VALUE_NORM_CLAMP)
        return (clamped * torch.sqrt(self.running_var + VALUE_NORM_EPS) + self.running_mean).to(values.dtype)

    @torch.no_grad()
    def update(self, *batches: torch.Tensor) -> None:
        """Merge each batch into the statistics, in the order given (rl_games: the rollout's values, then returns).

        A batch whose moments are not finite (a blown-up world's return) leaves the statistics as they were:
        one NaN merged in would make every later value target NaN.
        """
        batches = tuple(b.double() for b in batches)
        means = torch.stack([b.mean() for b in batches])
        counts = [float(b.numel()) for b in batches]  # host numbers: the sizes are known without a GPU read
        if torch.distributed.is_available() and torch.distributed.is_initialized():
            # The global mean first, then the spread around it (rsl-rl-lib's EmpiricalNormalization). Every rank's
            # storage has the same shape, so each batch counts world_size times its local size.
            world = torch.distributed.get_world_size()
            torch.distributed.all_reduce(means)
            means /= world
            spreads = torch.stack([(b - m).square().mean() for b, m in zip(batches, means)])
            torch.distributed.all_reduce(spreads)
            variances = spreads / world
            counts = [c * world for c in counts]
        else:
            variances = torch.stack([b.var(unbiased=False) for b in batches])
        for batch_mean, batch_var, batch_count in zip(means, variances, counts):
            # Chan et al.'s parallel merge: rl_games' _update_mean_var_count_from_moments
            total = self.count + batch_count
            delta = batch_mean - self.running_mean
            new_mean = self.running_mean + delta * batch_count / total
            m2 = (self.running_var * self.count + batch_var * batch_count
                  + delta.square() * self.count * batch_count / total)
            finite = torch.isfinite(batch_mean) & torch.isfinite(batch_var)
            self.running_mean.copy_(torch.where(finite, new_mean, self.running_mean))
            self.running_var.copy_(torch.where(finite, m2 / total, self.running_var))
            self.count.copy_(torch.where(finite, total, self.count))


class _RealUnitCritic:
    """The critic seen through the value statistics: its output in real units; anything else is the critic's own
    (rsl-rl-lib's ``compute_returns`` also saves and restores its hidden state)."""

    def __init__(self, critic: torch.nn.Module, normalizer: ValueNormalizer) -> None:
        self._critic, self._normalizer = critic, normalizer

    def __call__(self, *args, **kwargs) -> torch.Tensor:
        return self._normalizer.denormalize(self._critic(*args, **kwargs))

    def __getattr__(self, name: str):
        return getattr(self._critic, name)
