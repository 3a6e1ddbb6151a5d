"""Bad input ends ``python train.py`` with one line on stderr, exit status 2, no traceback, and the key as typed.

The table of inputs and messages lives in docs/errors.md; every row there is run here (so the documentation cannot
drift from what the program says), and the same checks hold for each: the whole message equals the row's, after
``{tmp}`` is replaced by this test's folder of prepared files (a truncated checkpoint, an empty task YAML, ...).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import torch
from conftest import CPU_ARGS, REPO_ROOT

DOC = REPO_ROOT / "docs" / "errors.md"
ROW = re.compile(r"^\| `(?P<args>[^`]+)` \| `(?P<message>.+)` \|$")


def doc_rows() -> list[tuple[str, str]]:
    rows = [(m["args"], m["message"]) for m in map(ROW.match, DOC.read_text().splitlines()) if m]
    assert len(rows) >= 20, f"docs/errors.md lists {len(rows)} bad inputs"
    return rows


def prepare(tmp: Path) -> None:
    """The files the rows name: task YAMLs that are empty, lack name: or are not YAML; checkpoints that are not."""
    (tmp / "cfg" / "task").mkdir(parents=True)
    (tmp / "cfg" / "train").mkdir()
    (tmp / "cfg" / "task" / "Empty.yaml").write_text("")
    (tmp / "cfg" / "task" / "Unnamed.yaml").write_text("env:\n  numEnvs: 4\n")
    # YAML syntax errors: an unclosed list (PyYAML's ParserError), a tab indenting a line (its ScannerError)
    (tmp / "cfg" / "task" / "Broken.yaml").write_text("name: Cartpole\nenv:\n  numEnvs: 4\n  resetDist: [1.0, 2.0\n"
                                                      "  maxEffort: 400.0\n")
    (tmp / "cfg" / "task" / "Tabbed.yaml").write_text("name: Cartpole\nenv:\n\tnumEnvs: 4\n")
    for name in ("Empty", "Unnamed", "Broken", "Tabbed"):
        (tmp / "cfg" / "train" / f"{name}PPO.yaml").write_text((REPO_ROOT / "cfg/train/CartpolePPO.yaml").read_text())
    torch.save({"actor_state_dict": {}, "iter": 1}, tmp / "whole.pt")
    (tmp / "truncated.pt").write_bytes((tmp / "whole.pt").read_bytes()[:100])
    torch.save({"notes": "not a policy"}, tmp / "notes.pt")
    # Cartpole's 4 observations and 1 action, but hidden layers of 64 where CartpolePPO.yaml builds 32
    wide = {"mlp.0.weight": torch.zeros(64, 4), "mlp.0.bias": torch.zeros(64), "mlp.2.weight": torch.zeros(64, 64),
            "mlp.2.bias": torch.zeros(64), "mlp.4.weight": torch.zeros(1, 64), "mlp.4.bias": torch.zeros(1)}
    torch.save({"actor_state_dict": wide, "critic_state_dict": {}, "iter": 0}, tmp / "wide.pt")
    # what test mode exports for Cartpole, as far as examples/deploy_mujoco.py reads it (policy.json)
    (tmp / "cartpole_export").mkdir()
    (tmp / "cartpole_export" / "policy.json").write_text(json.dumps({"task": "Cartpole", "control_dt": 0.0166,
                                                                     "num_actions": 1}))
    (tmp / "run").mkdir()  # a run directory given as the checkpoint: the message names its latest whole model_*.pt
    for name in ("model_9.pt", "model_10.pt", "model_2.pt"):
        (tmp / "run" / name).write_bytes((tmp / "whole.pt").read_bytes())
    (tmp / "run" / "model_11.pt").write_bytes(b"")  # what a full disk left before writes were atomic: never named
    (tmp / "run" / "model_12_interrupted.pt").write_bytes((tmp / "whole.pt").read_bytes()[:100])


# Rows of another command (a script, or `-m module`): its error prefix and the key its rows name.
SCRIPTS = {"examples/deploy_mujoco.py": ("[deploy] error: ", "export_dir"),
           "-m isaacgymenvs_mw.warmup": ("[warmup] error: ", "task")}


def command_of(args: str) -> str:
    """The command a row runs: a script's path, ``-m <module>``, or train.py's overrides (then not in SCRIPTS)."""
    argv = args.split()
    return " ".join(argv[:2]) if argv[0] == "-m" else argv[0]


def run_row(args: str, tmp: Path) -> subprocess.CompletedProcess:
    argv = args.replace("{tmp}", str(tmp)).split()
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
    if argv[0] == "-m":  # this checkout's package, from the test's folder
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO_ROOT), env.get("PYTHONPATH")]))
        return subprocess.run([sys.executable, *argv], cwd=tmp, capture_output=True, text=True, timeout=300, env=env)
    if argv[0] in SCRIPTS:
        return subprocess.run([sys.executable, str(REPO_ROOT / argv[0]), *argv[1:]], cwd=tmp, capture_output=True,
                              text=True, timeout=300, env=env)
    flags = argv[:2] if argv[0].startswith("--") else []  # e.g. --config-dir DIR: before the overrides
    # CPU_ARGS first: a row may name its own device, and Hydra takes the last value of a key.
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), *flags, *CPU_ARGS, "max_iterations=1", f"runs_dir={tmp}/runs",
           *argv[len(flags):]]
    env.pop("HYDRA_FULL_ERROR", None)
    return subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, timeout=300, env=env)


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory) -> tuple[Path, dict[str, subprocess.CompletedProcess]]:
    tmp = tmp_path_factory.mktemp("bad_input")
    prepare(tmp)
    rows = doc_rows()
    with ThreadPoolExecutor(max_workers=2) as pool:  # each run is mostly Python start-up; CI has 2 cores
        results = list(pool.map(lambda row: run_row(row[0], tmp), rows))
    return tmp, {args: proc for (args, _), proc in zip(rows, results)}


@pytest.mark.parametrize("args, message", doc_rows(), ids=[args for args, _ in doc_rows()])
def test_bad_input_is_one_line_naming_the_key(outcomes, args, message):
    tmp, procs = outcomes
    proc = procs[args]
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out[-3000:]
    assert "Traceback" not in out and "HYDRA_FULL_ERROR" not in out and "Error executing job" not in out, out
    prefix, key = SCRIPTS.get(command_of(args), ("[train] error: ", None))
    errors = [line for line in proc.stderr.splitlines() if line.startswith(prefix)]
    # {...}: what depends on the machine (its free memory), anything on one line
    expected = re.escape(prefix + message.replace("{tmp}", str(tmp))).replace(re.escape("{...}"), ".+?")
    assert len(errors) == 1 and re.fullmatch(expected, errors[0]), proc.stderr[-3000:]
    key = key or re.match(r"[+\-]*([^=\s]+)", args.split()[-1]).group(1)  # the row's last override names its key
    assert key in errors[0], (key, errors[0])


def test_torchrun_on_a_machine_without_gpus_is_one_line(tmp_path):
    # torchrun starts train.py with WORLD_SIZE (and RANK, LOCAL_RANK) set; rsl-rl-lib's runner then trains across
    # processes, on GPUs only.
    env = {**os.environ, "WORLD_SIZE": "2", "RANK": "0", "LOCAL_RANK": "0", "OMP_NUM_THREADS": "1"}
    assert not torch.cuda.is_available()  # the situation this test is about: a CPU-only machine
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), *CPU_ARGS, "max_iterations=1", f"runs_dir={tmp_path}/runs"]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert proc.stderr.splitlines()[-1] == (
        "[train] error: torchrun (WORLD_SIZE=2) needs one CUDA GPU per process, but torch sees none on this machine: "
        "train in one process (python train.py, without torchrun and multi_gpu=True), e.g. on the CPU")


@pytest.mark.parametrize("args", ["num_envs=0", "train.algorithm.gamma=2", "test=True checkpoint=missing.pt"])
def test_a_bad_run_or_train_value_is_told_before_the_learning_stack_is_imported(tmp_path, args):
    # python -X importtime lists every module the process imported, on stderr: none of torch, rsl_rl or the simulator
    cmd = [sys.executable, "-X", "importtime", str(REPO_ROOT / "train.py"), *CPU_ARGS, *args.split()]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr[-3000:]
    imported = {line.rsplit("|", 1)[1].strip() for line in proc.stderr.splitlines() if line.startswith("import time:")}
    assert {"hydra", "omegaconf"} <= imported  # the listing is complete: train.py's own imports are in it
    assert not {"torch", "rsl_rl", "warp", "mujoco_warp"} & imported, sorted(imported)
    assert proc.stderr.splitlines()[-1].startswith("[train] error: ")


def test_verbose_keeps_the_traceback(tmp_path):
    proc = run_row("num_envs=0 verbose=True", tmp_path)
    assert proc.returncode != 0 and "Traceback" in proc.stderr and "num_envs=0 is invalid" in proc.stderr


def test_task_keys_are_respelled_for_the_command_line():
    from isaacgymenvs_mw.utils.errors import ConfigError, under_task

    # A task names keys from its own section, where task. is the randomisation subsection (task.task.* outside).
    err = under_task(ConfigError("sim.dt must be > 0; see env.terrain.type and task.randomization_params.x, "
                                 "not cfg/sim.yaml, my-env.x or mujoco.sim.x"))
    assert str(err) == ("task.sim.dt must be > 0; see task.env.terrain.type and task.task.randomization_params.x, "
                        "not cfg/sim.yaml, my-env.x or mujoco.sim.x")
    assert isinstance(err, ConfigError)
    # A key the task already spelled as typed keeps its one task. prefix.
    typed = "task.env.x=1 and task.sim.dt=0 and task.task.randomization_params.y"
    assert str(under_task(ConfigError(typed))) == typed
