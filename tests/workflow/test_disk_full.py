"""A disk that fills during a run: every run output is written whole or not at all, the run ends with one line that
names the folder and its free space (exit status 74, EX_IOERR), and nothing points at a broken checkpoint.

The full disk is a writer that writes part of its file and then raises OSError(ENOSPC), as a write on a full
filesystem does; what must remain is checked on the folder itself and by loading the checkpoints with torch.
"""

from __future__ import annotations

import errno
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from conftest import CPU_ARGS, REPO_ROOT
from isaacgymenvs_mw.learning.checkpoints import latest_checkpoint
from isaacgymenvs_mw.utils.files import DISK_ERROR_STATUS, DiskWriteError, atomic_save

NO_SPACE = os.strerror(errno.ENOSPC)  # "No space left on device"


def fills_after(n_bytes: int):
    """A writer that writes ``n_bytes`` to its file and then fails as a full disk does."""
    def writer(path: str) -> None:
        with open(path, "wb") as f:
            f.write(b"P" * n_bytes)
        raise OSError(errno.ENOSPC, NO_SPACE)
    return writer


def test_a_full_disk_leaves_no_partial_file_and_keeps_the_earlier_one(tmp_path):
    target = tmp_path / "summary.json"
    target.write_text("the earlier summary\n")
    with pytest.raises(DiskWriteError) as err:
        atomic_save(target, fills_after(4096))
    assert sorted(os.listdir(tmp_path)) == ["summary.json"]  # no hidden partial file either
    assert target.read_text() == "the earlier summary\n"
    message = str(err.value)
    assert "\n" not in message
    assert re.fullmatch(rf"cannot write summary\.json in {re.escape(str(tmp_path))} \({NO_SPACE}; "
                        r"[\d.]+ (GiB|MiB|KiB) free\): free space there or give another runs_dir", message), message
    assert err.value.errno == errno.ENOSPC


def test_torch_save_failing_inside_its_zip_writer_is_a_disk_error(tmp_path):
    # torch.save reports a full disk from its C++ zip writer as a RuntimeError, not an OSError.
    def writer(path: str) -> None:
        Path(path).write_bytes(b"PK\x03\x04")
        raise RuntimeError(f"[enforce fail at inline_container.cc:626] . unexpected pos 64 vs 0: {NO_SPACE}")

    with pytest.raises(DiskWriteError, match=rf"cannot write model_7\.pt in .*\({NO_SPACE};"):
        atomic_save(tmp_path / "model_7.pt", writer)
    assert os.listdir(tmp_path) == []


def test_other_errors_pass_through_and_leave_nothing(tmp_path):
    def writer(path: str) -> None:
        Path(path).write_bytes(b"half")
        raise ValueError("not a disk problem")

    with pytest.raises(ValueError, match="not a disk problem"):
        atomic_save(tmp_path / "model_1.pt", writer)
    assert os.listdir(tmp_path) == []


def test_the_latest_checkpoint_is_never_a_broken_file(tmp_path):
    torch.save({"iter": 2}, tmp_path / "model_2.pt")
    (tmp_path / "model_3.pt").write_bytes(torch.load.__doc__.encode()[:50])  # cut short
    (tmp_path / "model_3_interrupted.pt").write_bytes(b"")  # left empty
    assert latest_checkpoint(tmp_path.glob("model_*.pt")) == tmp_path / "model_2.pt"


# The run: torch.save fails partway on the second checkpoint, as on a disk that fills during training.
FULL_DISK_RUN = """
import errno, os, runpy, sys, torch
real_save, calls = torch.save, []
def save(obj, f, *args, **kwargs):
    calls.append(f)
    if len(calls) == 2:
        with open(f, "wb") as out:
            out.write(b"PK" + bytes(1000))
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    return real_save(obj, f, *args, **kwargs)
torch.save = save
sys.argv = ["train.py", *sys.argv[1:]]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


def test_a_run_on_a_disk_that_fills_ends_with_one_line_and_a_whole_checkpoint(tmp_path):
    runs = tmp_path / "runs"
    cmd = [sys.executable, "-c", FULL_DISK_RUN, "task=Cartpole", "num_envs=4", "max_iterations=3",
           "train.runner.num_steps_per_env=8", "train.runner.save_interval=1", *CPU_ARGS, f"runs_dir={runs}"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(cmd, cwd=REPO_ROOT, capture_output=True, text=True, timeout=300, env=env)
    out = proc.stdout + proc.stderr
    assert proc.returncode == DISK_ERROR_STATUS == 74, out[-3000:]
    assert "Traceback" not in out, out[-3000:]
    (run_dir,) = (runs / "Cartpole").iterdir()
    errors = [line for line in proc.stderr.splitlines() if line.startswith("[train] error: ")]
    assert len(errors) == 1 and errors[0].startswith(
        f"[train] error: cannot write model_2.pt in {run_dir} ({NO_SPACE}; "), proc.stderr[-3000:]
    # model_1.pt is whole, and nothing half-written, empty or private is beside it
    names = sorted(p.name for p in run_dir.iterdir() if not p.name.startswith("events.out.tfevents"))
    assert names == ["config.yaml", "model_1.pt", "model_best.pt"], names
    assert torch.load(run_dir / "model_1.pt", weights_only=False)["iter"] == 1
    assert latest_checkpoint(run_dir.glob("model_*.pt")) == run_dir / "model_1.pt"


@pytest.mark.parametrize("raised, names", [
    (OSError(errno.ENOSPC, NO_SPACE, "/data/runs/sweeps/Ant_1/sweep.json"), "cannot write sweep.json in "
                                                                             "/data/runs/sweeps/Ant_1 "),
    (OSError(errno.EDQUOT, os.strerror(errno.EDQUOT), "/data/runs/Ant/2026-11-29"), "cannot write 2026-11-29 in "
                                                                                    "/data/runs/Ant "),
    (RuntimeError(f"unexpected pos 64 vs 0: {NO_SPACE}"), f"a write failed ({NO_SPACE}): "),
])
def test_a_disk_error_from_a_write_nothing_guards_is_one_line_and_exit_74(raised, names, capsys, monkeypatch):
    from isaacgymenvs_mw.utils.cli_errors import exit_on_input_error

    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    with pytest.raises(SystemExit) as stop:
        with exit_on_input_error("sweep"):
            raise raised
    assert stop.value.code == DISK_ERROR_STATUS
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"[sweep] error: {names}"), line
    assert "runs_dir" in line


def test_an_error_that_is_not_the_disk_is_left_alone(capsys):
    from isaacgymenvs_mw.utils.cli_errors import exit_on_input_error

    with pytest.raises(OSError, match="Permission denied"):
        with exit_on_input_error("train"):
            raise OSError(errno.EACCES, "Permission denied", "/root/x")
