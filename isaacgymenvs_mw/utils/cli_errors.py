"""train.py's bad-input report: one line on stderr and exit status 2 instead of a traceback and Hydra's hint.

A new user reads a 20-line traceback as a crash even when its last line says exactly what to change. Bad input is
our ``ConfigError`` (raised wherever a value is checked) or an error Hydra / OmegaConf raise while composing the
command line (an unknown task, a typo in a key, override syntax, a missing interpolation). Anything else is a bug
and keeps Hydra's usual report. ``verbose=True`` on the command line or HYDRA_FULL_ERROR=1 keeps the traceback.
"""

from __future__ import annotations

import os
import re
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from isaacgymenvs_mw.utils.errors import ConfigError, one_line
from isaacgymenvs_mw.utils.files import DISK_ERROR_STATUS, DiskWriteError, unnamed_disk_error

INPUT_ERROR_STATUS = 2  # as argparse and most Unix tools: the command line was wrong, nothing ran

_VERBOSE = re.compile(r"\+*verbose=(true|1|yes)", re.IGNORECASE)


def traceback_wanted(argv: list[str] | None = None) -> bool:
    """The user asked for the whole story: verbose=True among the overrides, or Hydra's own HYDRA_FULL_ERROR=1."""
    argv = sys.argv[1:] if argv is None else argv
    return os.environ.get("HYDRA_FULL_ERROR") == "1" or any(_VERBOSE.fullmatch(arg) for arg in argv)


def input_error_message(err: BaseException) -> str | None:
    """``err`` told as one line when it is bad input, else None (a bug, which keeps its traceback)."""
    from hydra.errors import ConfigCompositionException, MissingConfigException, OverrideParseException
    from omegaconf.errors import OmegaConfBaseException

    if isinstance(err, ConfigError):
        return one_line(str(err))
    syntax = _yaml_syntax_error(err)
    if syntax is not None:
        return syntax
    if isinstance(err, MissingConfigException):
        found = re.search(r"Could not find '([^']+)'", str(err))
        missing = found.group(1) if found else str(err.missing_cfg_file)
        group, _, name = missing.rpartition("/")
        if group and err.options:
            return (f"{group}={name}: no {group}/{name}.yaml in the config search path; "
                    f"available: {', '.join(err.options)}")
        return one_line(str(err).split("Config search path:")[0])
    if isinstance(err, OverrideParseException):
        return f"{err.override}: not a valid override ({one_line(str(err))})"
    if isinstance(err, ConfigCompositionException):
        unknown = re.match(r"Could not override '([^']+)'", str(err))
        if unknown and "not in struct" in str(err.__cause__):
            key = unknown.group(1)
            return (f"{key}: no such key (a typo? run-level keys are in cfg/config.yaml, task keys start with "
                    f"task., training keys with train.; to add a new key write +{key}=...)")
        return one_line(f"{err}\n{err.__cause__ or ''}")
    if isinstance(err, OmegaConfBaseException):
        message = str(err).split("\n")[0]
        key = getattr(err, "full_key", None) or next(iter(re.findall(r"full_key: (\S+)", str(err))), None)
        return f"{key}: {message}" if key else one_line(str(err))
    return None


def _yaml_syntax_error(err: BaseException) -> str | None:
    """A YAML file Hydra could not parse (PyYAML's ScannerError, ParserError, ...: raised bare, or as the cause of
    Hydra's error) told as the file, line and column, and what PyYAML expected; None for any other error.

    A file of a config group (``task/Broken.yaml``) is named by the override that chose it too (``task=Broken``)."""
    import yaml

    while err is not None and not isinstance(err, yaml.MarkedYAMLError):
        err = err.__cause__ or err.__context__
    if err is None:
        return None
    mark = err.problem_mark or err.context_mark
    if mark is None:
        return f"not valid YAML: {one_line(str(err))}"
    path = Path(mark.name)
    chose = f"{path.parent.name}={path.stem}: " if path.parent.name in ("task", "train") else ""
    where = ""
    if err.context and err.context_mark is not None and err.context_mark is not mark:
        where = f" ({err.context} at line {err.context_mark.line + 1}, column {err.context_mark.column + 1})"
    problem = err.problem or err.context or "a syntax error"
    return (f"{chose}{mark.name}, line {mark.line + 1}, column {mark.column + 1}: not valid YAML: "
            f"{problem}{where}")


@contextmanager
def exit_on_input_error(command: str = "train") -> Iterator[None]:
    """Bad input raised inside becomes one line on stderr and exit status 2, a disk that refused a write one line
    and exit status 74 (``DISK_ERROR_STATUS``); anything else passes on untouched. The line starts with
    ``[<command>] error:``. train.py's job body runs inside it (Hydra would otherwise print "Error executing job"
    before the report)."""
    try:
        yield
    except DiskWriteError as err:  # the command was right, the disk was not: its own status (utils/files.py)
        if traceback_wanted():
            raise
        print(f"[{command}] error: {err}", file=sys.stderr, flush=True)
        sys.exit(DISK_ERROR_STATUS)
    except Exception as err:
        disk = unnamed_disk_error(err)
        if disk is not None and not traceback_wanted():
            print(f"[{command}] error: {disk}", file=sys.stderr, flush=True)
            sys.exit(DISK_ERROR_STATUS)
        message = input_error_message(err)
        if message is None or traceback_wanted():
            raise
        print(f"[{command}] error: {message}", file=sys.stderr, flush=True)
        sys.exit(INPUT_ERROR_STATUS)


@contextmanager
def report_input_errors() -> Iterator[None]:
    """While inside, Hydra's reporting (``run_and_report``, which wraps composing the config) tells bad input as
    one line too; everything else goes on to Hydra's own report."""
    import hydra._internal.utils as hydra_utils

    original = hydra_utils.run_and_report

    def run_and_report(func: Callable):
        def guarded():
            with exit_on_input_error():
                return func()

        return original(guarded)

    hydra_utils.run_and_report = run_and_report
    try:
        yield
    finally:
        hydra_utils.run_and_report = original
