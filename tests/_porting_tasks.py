"""Tasks that do what IsaacGymEnvs ports do (used by tests/tasks/test_porting_traps.py, also through ``task_module=``)."""

from __future__ import annotations

import json

import torch

from isaacgymenvs_mw.tasks import register_task
from isaacgymenvs_mw.tasks.cartpole import Cartpole
from isaacgymenvs_mw.utils.errors import ConfigError


@register_task("CartpoleNoStateForTests")
class CartpoleNoState(Cartpole):
    """Declares its critic state as an empty list: no critic state, as None says."""

    def state_terms(self):
        return []


@register_task("CartpolePythonCounterForTests")
class CartpolePythonCounter(Cartpole):
    """Keeps a Python step counter in pre_physics_step (IsaacGymEnvs' schedules do): frozen once the step is
    captured on a GPU."""

    def __init__(self, *args, **kwargs):
        self._n = 0
        self.push_every = 150
        super().__init__(*args, **kwargs)

    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self._n += 1
        super().pre_physics_step(actions)


@register_task("CartpoleBadValueForTests")
class CartpoleBadValue(Cartpole):
    """Refuses env.maxEffort above 1000 with a plain ValueError (as a ported task's own check would)."""

    def __init__(self, cfg, *args, **kwargs):
        if float(cfg["env"]["maxEffort"]) > 1000:
            raise ValueError(f"env.maxEffort={cfg['env']['maxEffort']} is invalid: give at most 1000 N")
        super().__init__(cfg, *args, **kwargs)


@register_task("CartpoleConfigErrorForTests")
class CartpoleConfigError(Cartpole):
    """Refuses a negative env.resetDist with ConfigError, the key written the long way (task.env.resetDist)."""

    def __init__(self, cfg, *args, **kwargs):
        if float(cfg["env"]["resetDist"]) < 0:
            raise ConfigError(f"task.env.resetDist={cfg['env']['resetDist']} is invalid: give a distance >= 0 (m)")
        super().__init__(cfg, *args, **kwargs)


@register_task("CartpoleBugForTests")
class CartpoleBug(Cartpole):
    """A bug, not bad input: a library (Python's json) raises a ValueError in its own code, called from the
    constructor."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        json.loads("{")
