"""A user's module that registers a task on import (used through the `task_module=` run key in the tests)."""


from isaacgymenvs_mw.tasks import register_task
from isaacgymenvs_mw.tasks.cartpole import Cartpole


@register_task("ModuleCartpoleForTests")
class ModuleCartpole(Cartpole):
    """Cartpole whose observations are scaled by 2 (so the tests can tell it built this class)."""

    def compute_observations(self) -> None:
        super().compute_observations()
        self.obs_buf.mul_(2.0)
