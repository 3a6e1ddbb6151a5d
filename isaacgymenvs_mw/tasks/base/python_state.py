"""Python state a task changes in its step hooks, caught in the first steps on any device.

On CUDA the step's torch work is captured as CUDA graphs after a few eager steps (``step_execution.py``); a replay
runs none of the hooks' Python. A task attribute holding a Python number that the hooks change (``self._n += 1`` in
``pre_physics_step``, the counter of many IsaacGymEnvs schedules and periodic events) therefore stops changing there,
while on the CPU, where tasks are developed, it goes on: the same code does something else on a GPU, silently. So in
the eager steps before a capture would happen, on every device, the task's attributes that hold Python numbers (or
lists, tuples or dicts of them) are compared before and after each step's hooks, and those that change are named once,
with the fix. The first step is left out: state set once there (a lazily made flag) does not freeze anything.
"""

from __future__ import annotations

import numbers
import warnings


class PythonStateWarning(RuntimeWarning):
    """A task's step changes Python numbers, which a captured step would freeze."""


def _is_numbers(value: object) -> bool:
    if isinstance(value, numbers.Number):
        return True
    if isinstance(value, (list, tuple)):
        return all(isinstance(v, numbers.Number) for v in value)
    if isinstance(value, dict):
        return all(isinstance(v, numbers.Number) for v in value.values())
    return False


class PythonStateWatch:
    """Compares ``task``'s Python-number attributes around the hooks of its first ``steps`` env steps, and warns once
    (``PythonStateWarning``) naming those that changed in a step after the first. ``name``: the task's class name."""

    def __init__(self, task: object, name: str, steps: int) -> None:
        self.task, self.name, self.steps = task, name, steps
        self.changed: list[str] = []  # attribute names, in the order first seen changing

    def watching(self, step: int) -> bool:
        return step < self.steps

    def snapshot(self) -> dict[str, str]:
        # repr: a copy of lists and dicts as they are now, and NaN equal to NaN
        return {name: repr(value) for name, value in vars(self.task).items() if _is_numbers(value)}

    def compare(self, before: dict[str, str], step: int) -> None:
        """After the hooks of env step ``step`` (0-based): note what changed since ``before``; at the last watched
        step, warn about all of it."""
        if step > 0:
            after = self.snapshot()
            self.changed += [name for name, value in before.items()
                             if name in after and after[name] != value and name not in self.changed]
        if step == self.steps - 1 and self.changed:
            names = ", ".join(f"self.{name} ({type(getattr(self.task, name)).__name__})" for name in self.changed)
            warnings.warn(
                f"{self.name} keeps Python state in its step: {names} changed from step to step in its hooks. On a "
                f"GPU the step is captured as CUDA graphs after its first {self.steps} steps and replayed without "
                "running Python, so these stop changing there (on the CPU they go on). Keep such state in a tensor on "
                "self.device and update it in place (e.g. self._n = torch.zeros((), dtype=torch.long, "
                "device=self.device) in __init__, self._n += 1 in the hook), or run with +task.sim.captureStep=False "
                "(slower)", PythonStateWarning, stacklevel=2)
