"""Bad input from the user's configuration, told as one line: the key as typed on the command line, the value, and
what is valid. ``train.py`` prints a ``ConfigError`` without a traceback and exits with status 2."""

from __future__ import annotations

import re

# A task-section key as the task code names it (``sim.dt``, ``env.terrain.type``, ``task.randomization_params``):
# on the command line and in make()'s overrides it lives under ``task.``. Not preceded by a word character, a dot
# or a path separator, so ``task.sim.dt``, ``cfg/sim.yaml`` and ``mujoco.sim`` are left alone; nor a key a task
# already spelled as typed (``task.env.x``, ``task.sim.dt``, ``task.task.x``), which would become ``task.task.env.x``.
_TASK_KEY = re.compile(r"(?<![\w./\\-])(?!task\.(?:env|sim|task)\.)(env|sim|task)\.(?=[A-Za-z_])")


class ConfigError(ValueError):
    """A configuration value (YAML or command line) that the framework refuses; the message is the whole story.

    A ``ValueError`` so that code catching bad values the Python way keeps working."""

    __str__ = BaseException.__str__  # the message as given, also where KeyError (which quotes it) is a base


class MissingFileError(ConfigError, FileNotFoundError):
    """A file or folder the configuration names does not exist."""


class UnknownNameError(ConfigError, KeyError):
    """A name (task, body, term) the configuration gives is not one the framework knows."""


def under_task(err: ConfigError) -> ConfigError:
    """The same error with the task section's keys spelled as on the command line (``sim.dt`` -> ``task.sim.dt``)."""
    respelled = type(err)(_TASK_KEY.sub(r"task.\1.", str(err)))
    respelled.__cause__ = err.__cause__
    return respelled


def one_line(message: str) -> str:
    """A message folded onto one line: its lines joined by '; ', indentation and blank lines dropped."""
    return "; ".join(line.strip() for line in str(message).splitlines() if line.strip())
