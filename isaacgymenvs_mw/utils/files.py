"""Run outputs written whole or not at all, and a full disk told as one line.

A checkpoint, summary or export cut short by a full disk is worse than none: resuming from it fails, and a folder's
latest checkpoint would point at it. ``atomic_save`` writes into a hidden file in the same folder and renames it
over the target only once it is complete (a rename within one filesystem is atomic), and removes the hidden file
when writing fails. A write that fails for lack of space (or quota, or a read-only or failing disk) becomes a
``DiskWriteError`` whose message names the folder and its free space; train.py prints it as one line and exits with
``DISK_ERROR_STATUS``.
"""

from __future__ import annotations

import errno
import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

# sysexits.h's EX_IOERR ("an error occurred while doing I/O on some file"): the command was right, the disk was not,
# so it is not the bad-input status 2.
DISK_ERROR_STATUS = 74

# Errors that say the disk, not the program, is at fault: no space, no quota left, read-only, failing hardware.
_DISK_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EIO, errno.EFBIG}


class DiskWriteError(OSError):
    """A run output could not be written because of the disk; the message is the whole story, on one line."""

    def __str__(self) -> str:
        return str(self.strerror)  # OSError's own adds "[Errno 28]" in front


def _free_space(folder: Path) -> str:
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return "unknown free space"
    for unit, size in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if free >= size:
            return f"{free / size:.1f} {unit} free"
    return f"{free} bytes free"


def disk_error(path: str | os.PathLike, code: int) -> DiskWriteError:
    """A failed write of ``path`` (errno ``code``) told as one line naming the folder and its free space."""
    folder = Path(path).parent
    return DiskWriteError(code, f"cannot write {Path(path).name} in {folder} ({os.strerror(code)}; "
                                f"{_free_space(folder)}): free space there or give another runs_dir")


def disk_errno(err: BaseException | None) -> int | None:
    """The errno when ``err`` (or an error it was raised from: torch.save wraps them) is the disk's fault, else
    None."""
    while err is not None:
        if isinstance(err, OSError) and err.errno in _DISK_ERRNOS:
            return err.errno
        if isinstance(err, RuntimeError) and "No space left on device" in str(err):  # torch's zip writer
            return errno.ENOSPC
        err = err.__cause__ or err.__context__
    return None


def unnamed_disk_error(err: BaseException) -> DiskWriteError | None:
    """A disk error raised by a write no ``disk_errors_named`` guards (a library's own file, a folder being made),
    told as one line naming the file when the error knows it; None when ``err`` is not the disk's fault."""
    code = disk_errno(err)
    if code is None:
        return None
    filename = getattr(err, "filename", None)
    if filename:
        return disk_error(filename, code)
    return DiskWriteError(code, f"a write failed ({os.strerror(code)}): free space where the run writes "
                                f"(runs_dir) or give another runs_dir")


@contextmanager
def disk_errors_named(path: str | os.PathLike) -> Iterator[None]:
    """Inside, an error raised by the disk while writing ``path`` becomes a one-line ``DiskWriteError``."""
    try:
        yield
    except DiskWriteError:
        raise
    except Exception as err:
        code = disk_errno(err)
        if code is None:
            raise
        raise disk_error(path, code) from err


def _write_bytes(path: Path, data: bytes) -> None:
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())  # a full disk can first show at the flush to the device


def save_files_whole(folder: str | os.PathLike, contents: dict[str, bytes]) -> None:
    """Write a set of files (name -> bytes) into ``folder`` as one unit: every file is written to a hidden name
    first and only then are all renamed in; on failure none of them is changed (earlier files stay as they were),
    no hidden file is left, and a disk error becomes a ``DiskWriteError`` naming the file it stopped at."""
    folder = Path(folder)
    written: list[tuple[Path, Path]] = []
    name = next(iter(contents), "")
    try:
        with disk_errors_named(folder / name):
            folder.mkdir(parents=True, exist_ok=True)
        for name, data in contents.items():
            target = folder / name
            partial = folder / f".{name}.{os.getpid()}.partial"
            written.append((partial, target))
            with disk_errors_named(target):
                _write_bytes(partial, data)
        for partial, target in written:
            os.replace(partial, target)  # renames take no space: once here, the set completes
    except BaseException:
        for partial, _ in written:
            partial.unlink(missing_ok=True)
        raise


def atomic_save(path: str | os.PathLike, writer: Callable[[str], object]) -> None:
    """Call ``writer(partial_path)`` to write the whole file, then rename it to ``path``; on failure nothing is left
    at either name (an earlier file at ``path`` stays as it was) and a disk error becomes a ``DiskWriteError``."""
    path = Path(path)
    partial = path.with_name(f".{path.name}.{os.getpid()}.partial")  # hidden, and matches no model_*.pt
    with disk_errors_named(path):
        try:
            writer(str(partial))
            os.replace(partial, path)
        except BaseException:
            partial.unlink(missing_ok=True)
            raise
