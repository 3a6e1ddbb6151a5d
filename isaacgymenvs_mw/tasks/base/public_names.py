"""VecTask's public names, made so that a task's own attribute of the same name never breaks on an upgrade.

A ported task keeps attributes of its own under names the framework may later add to VecTask: IsaacGymEnvs'
Trifinger keeps a device counter of env steps, IsaacGymEnvs' ``Env`` sets ``self.num_obs`` and ``self.obs_space``.
A read-only ``property`` of the same name on VecTask turns such an assignment into ``AttributeError: property ... has
no setter``. So VecTask's names come in three kinds:

* a fact VecTask shows (``env_steps``, ``num_obs``, ``obs_space``, ...) is a ``TaskOverridable``: a task that assigns
  the name gets its own attribute, which every later read returns, and one warning line names the attribute and what
  VecTask's means. The framework's own code reads these facts from their homes (the episode, the observations, the
  randomisation layer), so it keeps working; clients of the task (rl_games, a learner) see the task's value, as they
  would in IsaacGymEnvs, where these names are plain attributes;
* a buffer (``obs_buf``, ``rew_buf``, ``progress_buf``, ...) takes an assignment into the framework's tensor
  (``EpisodeBuffer``, ``ObservationBuffer``), so ``self.obs_buf = torch.cat(...)`` fills the buffer the step returns;
* an object VecTask runs on (``FRAMEWORK_OBJECTS``: ``episode``, ``observations``, ...) cannot be replaced by the
  task: after the task's constructor returns, ``check_framework_objects`` names the attribute in one line and says
  to rename the task's.
"""

from __future__ import annotations

import warnings
from typing import Any, Callable

import torch

from isaacgymenvs_mw.utils.errors import ConfigError


class TaskOverridable:
    """A read-only fact of VecTask (a ``property`` in all but one thing): a task's own assignment of the name wins.

    Used as a decorator, like ``property``: ``@TaskOverridable`` over a getter whose docstring's first sentence says
    what VecTask's value means (the warning quotes it)."""

    def __init__(self, fget: Callable[[Any], Any]) -> None:
        self.fget = fget
        self.__doc__ = fget.__doc__
        self.name = fget.__name__

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, task: Any, owner: type | None = None) -> Any:
        if task is None:
            return self
        own = task.__dict__.get(self.name, _ABSENT)
        return self.fget(task) if own is _ABSENT else own

    def __set__(self, task: Any, value: Any) -> None:
        if self.name not in task.__dict__:
            warnings.warn(f"{type(task).__name__} sets its own `{self.name}`, which the task's code and the task's "
                          f"clients now read; VecTask's `{self.name}` ({self.meaning()}) goes on for the framework "
                          "(rename the task's attribute to silence this)", stacklevel=2)
        task.__dict__[self.name] = value

    def meaning(self) -> str:
        """The first sentence of the getter's docstring: what VecTask's value is."""
        doc = " ".join((self.__doc__ or "").split())
        return doc.split(". ")[0].rstrip(".") or f"VecTask.{self.name}"

    def framework_value(self, task: Any) -> Any:
        """VecTask's own value, whatever the task assigned."""
        return self.fget(task)


_ABSENT = object()


class ObservationBuffer:
    """``obs_buf`` / ``states_buf``: the observations' tensor; an assignment copies into it (shape checked), as
    ``EpisodeBuffer`` does for the episode's buffers: the step returns that tensor, not a rebound name."""

    def __init__(self, doc: str) -> None:
        self.__doc__ = doc

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, task: Any, owner: type | None = None) -> Any:
        return self if task is None else getattr(task.observations, self.name)

    def __set__(self, task: Any, value: torch.Tensor) -> None:
        buffer = getattr(task.observations, self.name)
        if value is buffer:
            return
        if not isinstance(value, torch.Tensor) or value.shape != buffer.shape:
            shape = tuple(value.shape) if isinstance(value, torch.Tensor) else type(value).__name__
            raise ConfigError(f"{type(task).__name__}: self.{self.name} = a {shape} value, but the buffer is "
                              f"{tuple(buffer.shape)} (num_envs, env.numObservations / numStates): write the task's "
                              f"values into it (self.{self.name}[:] = ...) at its size")
        buffer.copy_(value)


# The objects VecTask's step runs on, by attribute: a task that binds one of these names to something else would
# silently take the framework's machinery away, so construction stops with one line instead.
FRAMEWORK_OBJECTS = {
    "episode": "the episodes' buffers and clock (tasks/base/episode.py)",
    "observations": "the observation buffers, layouts and history (tasks/base/observation_composer.py)",
    "randomizer": "the randomisation layer (tasks/base/randomization.py)",
    "execution": "how the step runs: eager, compiled or captured (tasks/base/step_execution.py)",
    "metrics": "the task's declared metrics (tasks/base/metrics.py; record with self.metrics.record)",
    "display": "the viewer (tasks/base/display.py)",
    "extras": "the step's extras dict (IsaacGymEnvs' `extras`: a task may replace it with a dict of its own)",
}


def check_framework_objects(task: Any, expected: dict[str, type]) -> None:
    """After the task's constructor: each of ``FRAMEWORK_OBJECTS`` must still be VecTask's (of its ``expected``
    type); one line names the one a task replaced."""
    for name, kind in expected.items():
        value = task.__dict__.get(name)
        if value is None:
            raise ConfigError(f"{type(task).__name__} has no self.{name} ({FRAMEWORK_OBJECTS[name]}): a task that "
                              "overrides allocate_buffers() calls super().allocate_buffers() first")
        if not isinstance(value, kind):
            raise ConfigError(f"{type(task).__name__} sets self.{name} = {type(value).__name__}, but VecTask uses "
                              f"self.{name} for {FRAMEWORK_OBJECTS[name]}: rename the task's attribute "
                              f"(docs/porting.md lists the framework's names)")


def overridable_names(cls: type) -> dict[str, TaskOverridable]:
    """Every ``TaskOverridable`` name of a task class, by name (docs and tests list them)."""
    found: dict[str, TaskOverridable] = {}
    for klass in reversed(cls.__mro__):
        found.update({k: v for k, v in vars(klass).items() if isinstance(v, TaskOverridable)})
    return found
