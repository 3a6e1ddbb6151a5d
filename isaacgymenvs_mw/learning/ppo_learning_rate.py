"""SyncFreePPO's learning rate on the device (learning/ppo.py): the rate lives in device tensors that fused Adam reads,
and rsl-rl-lib's adaptive rule (or rl_games' per-epoch one) moves it without a host read."""

from __future__ import annotations

import torch

from isaacgymenvs_mw.utils.config import real_number
from isaacgymenvs_mw.utils.errors import ConfigError

LR_MIN, LR_MAX, LR_FACTOR = 1e-5, 1e-2, 1.5  # rsl-rl-lib's adaptive-schedule constants (bounds: the defaults)


class DeviceLearningRate:
    """Mixin of SyncFreePPO: the bounds of the adaptive rate, its device tensors, and the rule that moves them."""

    @property
    def _adaptive(self) -> bool:
        return self.desired_kl is not None and self.schedule == "adaptive"

    def _refuse_without_adaptive(self, key: str, value) -> None:
        """A setting of the adaptive rule given where the rate never moves: an error rather than silently ignored."""
        if not self._adaptive:
            raise ConfigError(
                f"{key}={value!r} has no effect: the learning rate moves only with "
                f"train.algorithm.schedule=adaptive and a train.algorithm.desired_kl (got "
                f"schedule={self.schedule!r}, desired_kl={self.desired_kl!r}); remove it or set both")

    def _check_rate_bounds(self, low, high) -> tuple[float, float]:
        key = "train.algorithm.learning_rate"
        low = real_number(low, f"{key}_min", 0.0, low_open=True)
        high = real_number(high, f"{key}_max", 0.0, low_open=True)
        if not self._adaptive:
            for name, value, default in (("min", low, LR_MIN), ("max", high, LR_MAX)):
                if value != default:
                    self._refuse_without_adaptive(f"{key}_{name}", value)
            return low, high
        if low > high:
            raise ConfigError(f"{key}_min={low!r} is invalid: give a number <= {key}_max ({high!r})")
        if not low <= self.learning_rate <= high:
            raise ConfigError(f"{key}={self.learning_rate!r} is invalid with the adaptive schedule: give a number "
                              f"within [{key}_min, {key}_max] = [{low!r}, {high!r}]")
        return low, high

    def _install_device_learning_rate(self) -> None:
        """Put the optimizer's current rate into device tensors that Adam reads at each step."""
        rate = float(self.optimizer.param_groups[0]["lr"])
        if self._adaptive:  # a checkpoint's rate from outside this run's bounds (a resume with narrower ones)
            rate = min(max(rate, self.learning_rate_min), self.learning_rate_max)
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

    def _adapt_learning_rate(self, kl_mean: torch.Tensor, rl_games_rule: bool = False) -> None:
        too_far = kl_mean > self.desired_kl * 2.0
        too_close = kl_mean < self.desired_kl / 2.0
        if not rl_games_rule:
            # rsl-rl-lib's rule leaves the rate alone on a KL of 0 (an update's first mini-batch, its policy still
            # the rollout's); rl_games' has no such condition, and its KL can be <= 0 where a std has collapsed.
            too_close = too_close & (kl_mean > 0.0)
        lowered = torch.clamp(self._lr64 / LR_FACTOR, min=self.learning_rate_min)
        raised = torch.clamp(self._lr64 * LR_FACTOR, max=self.learning_rate_max)
        self._lr64.copy_(torch.where(too_far, lowered, torch.where(too_close, raised, self._lr64)))
        self._lr.copy_(self._lr64)
