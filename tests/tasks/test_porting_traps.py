"""What an IsaacGymEnvs port meets (issue 59): a task's own errors, an empty critic state, Python state in the hooks,
joint velocity limits, a GL backend that is not installed."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import pytest
from conftest import CPU_ARGS, REPO_ROOT, TESTS_DIR

import _porting_tasks  # noqa: F401  (registers the tasks below)
from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError


def porting_cfg(name: str, *overrides: str, num_envs: int = 4):
    return compose_config(["task=Cartpole", f"task.name={name}", f"num_envs={num_envs}", *CPU_ARGS, *overrides])


def train_py(tmp_path, *args: str, pythonpath: tuple = ()) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join(map(str, [*pythonpath, TESTS_DIR]))}
    env.pop("HYDRA_FULL_ERROR", None)
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), *CPU_ARGS, "num_envs=4", "max_iterations=1",
           f"runs_dir={tmp_path}/runs", "task=Cartpole", "task_module=_porting_tasks", *args]
    return subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)


# ------------------------------------------------------------------ errors raised by a task
def test_a_tasks_value_error_is_one_line_with_status_2_and_the_key_as_typed(tmp_path):
    proc = train_py(tmp_path, "task.name=CartpoleBadValueForTests", "task.env.maxEffort=2000")
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "Traceback" not in proc.stdout + proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("[train] error: ")]
    assert len(errors) == 1, proc.stderr[-3000:]
    assert errors[0].startswith("[train] error: task.env.maxEffort=2000 is invalid: give at most 1000 N (raised at "
                                "_porting_tasks.py:"), errors


def test_a_tasks_config_error_keeps_a_key_already_spelled_as_typed():
    with pytest.raises(ConfigError) as caught:
        build_task(porting_cfg("CartpoleConfigErrorForTests", "task.env.resetDist=-1"))
    assert str(caught.value) == "task.env.resetDist=-1 is invalid: give a distance >= 0 (m)"
    # A plain ValueError of the task's own code is told the same way, the key under task.
    with pytest.raises(ConfigError, match=r"^task\.env\.maxEffort=1500 is invalid: give at most 1000 N \(raised at "
                                          r"_porting_tasks\.py:\d+\)$"):
        build_task(porting_cfg("CartpoleBadValueForTests", "task.env.maxEffort=1500"))


def test_a_value_error_raised_by_a_library_inside_the_constructor_stays_a_bug():
    import json

    with pytest.raises(json.JSONDecodeError) as caught:
        build_task(porting_cfg("CartpoleBugForTests"))
    assert not isinstance(caught.value, ConfigError)


# ------------------------------------------------------------------ state_terms() == []
def test_an_empty_state_term_list_means_no_critic_state_and_trains(tmp_path):
    from isaacgymenvs_mw.learning.launch import run

    task = build_task(porting_cfg("CartpoleNoStateForTests"))
    obs = task.reset()
    assert task.num_states == 0 and "states" not in obs and task.observations.state_layout is None
    task.step(task.zero_actions())
    summary = run(porting_cfg("CartpoleNoStateForTests", "max_iterations=2", f"runs_dir={tmp_path}/runs",
                              num_envs=8))
    assert summary["iterations"] == 2


# ------------------------------------------------------------------ Python state in the step hooks
def test_a_python_counter_in_the_hooks_is_named_once_with_the_fix():
    import torch

    from isaacgymenvs_mw.tasks.base.python_state import PythonStateWarning

    task = build_task(porting_cfg("CartpolePythonCounterForTests"))
    task.reset()
    with pytest.warns(PythonStateWarning) as caught:
        for _ in range(6):
            task.step(task.zero_actions())
    assert len(caught) == 1
    message = str(caught[0].message)
    assert "self._n (int)" in message and "push_every" not in message  # a constant number is not named
    assert "in a tensor" in message and "captureStep=False" in message
    assert task._n == 6  # eager on the CPU: it kept counting
    with warnings.catch_warnings():  # once: later steps say nothing more
        warnings.simplefilter("error", PythonStateWarning)
        task.step(torch.zeros((task.num_envs, 1)))


def test_with_the_step_never_captured_the_counter_is_not_reported():
    from isaacgymenvs_mw.tasks.base.python_state import PythonStateWarning

    task = build_task(porting_cfg("CartpolePythonCounterForTests", "+task.sim.captureStep=False"))
    task.reset()
    with warnings.catch_warnings():
        warnings.simplefilter("error", PythonStateWarning)
        for _ in range(5):
            task.step(task.zero_actions())


# ------------------------------------------------------------------ MUJOCO_GL naming a backend that cannot load
# Loaded by Python at start-up (sitecustomize on PYTHONPATH): the dynamic loader finds no libOSMesa, as on a machine
# without the package, whether or not this one has it.
NO_OSMESA = """
import ctypes
_load = ctypes.CDLL.__init__
def _without_osmesa(self, name, *args, **kwargs):
    if name and "OSMesa" in str(name):
        raise OSError(f"{name}: cannot open shared object file: No such file or directory")
    _load(self, name, *args, **kwargs)
ctypes.CDLL.__init__ = _without_osmesa
"""


@pytest.mark.parametrize("backend, says", [
    ("osmesa", "MUJOCO_GL=osmesa needs libOSMesa, for CPU rendering (Debian/Ubuntu: apt-get install libosmesa6). Or "
               "unset MUJOCO_GL"),
    ("nope", "MUJOCO_GL='nope' is not a backend MuJoCo knows: give one of ['osmesa', 'egl', "),
])
def test_a_mujoco_gl_backend_that_cannot_load_is_one_line_saying_what_to_install(tmp_path, monkeypatch, backend,
                                                                                  says):
    shim = tmp_path / "no_osmesa"
    shim.mkdir()
    (shim / "sitecustomize.py").write_text(NO_OSMESA)
    monkeypatch.setenv("MUJOCO_GL", backend)
    monkeypatch.delenv("PYOPENGL_PLATFORM", raising=False)
    proc = train_py(tmp_path, pythonpath=[shim])
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out[-3000:]
    assert "Traceback" not in out
    errors = [line for line in proc.stderr.splitlines() if line.startswith("[train] error: ")]
    assert len(errors) == 1 and errors[0].startswith(
        f"[train] error: mujoco cannot be imported with MUJOCO_GL={backend!r} ("), out[-3000:]
    assert says in errors[0]


def test_mujoco_import_error_names_each_backends_library():
    from isaacgymenvs_mw.sim.gl import mujoco_import_error

    err = mujoco_import_error("egl", OSError("libEGL.so.1: cannot open shared object file"))
    assert isinstance(err, ConfigError) and "\n" not in str(err)
    assert "(OSError: libEGL.so.1: cannot open shared object file): MUJOCO_GL=egl needs libEGL" in str(err)
    assert "apt-get install libegl1" in str(err)


# ------------------------------------------------------------------ joint velocity limit (env.control.velocityClamp)
def pushed_cart_speeds(overrides: list[str], steps: int = 80):
    """Cart and pole speeds after each of ``steps`` env steps of the largest push (action +1: 400 N on the cart)."""
    import torch

    task = build_task(porting_cfg("Cartpole", *overrides))
    task.reset()
    push = torch.ones((task.num_envs, 1))
    cart, pole = [], []
    for _ in range(steps):
        obs = task.step(push)[0]["obs"]
        cart.append(task.sim.dof_vel[:, task.cart_dof].clone())
        pole.append(task.sim.dof_vel[:, task.pole_dof].clone())
        assert torch.equal(obs[:, 1], cart[-1].clamp(-5.0, 5.0))  # what the policy sees (clipObservations 5)
    return torch.stack(cart), torch.stack(pole), task


def test_the_velocity_clamp_holds_a_joint_under_the_largest_push():
    free, free_pole, _ = pushed_cart_speeds([])
    assert float(free.abs().max()) > 3.0  # without the clamp 400 N drives the cart well past 0.5 m/s
    cart, pole, task = pushed_cart_speeds(["+task.env.control.velocityClamp={slider_to_cart:0.5}"])
    assert float(cart.abs().max()) <= 0.5
    assert float((cart == 0.5).float().mean()) > 0.5  # it runs at the limit, not below it by chance
    assert float(pole.abs().max()) > 0.5  # the pole's joint, not named, is left alone
    assert task.dof_velocity_clamp.tolist() == [0.5, float("inf")]


def test_one_velocity_clamp_for_every_joint_and_bad_values():
    cart, pole, _ = pushed_cart_speeds(["+task.env.control.velocityClamp=0.25"], steps=40)
    assert float(cart.abs().max()) <= 0.25 and float(pole.abs().max()) <= 0.25  # 0.25: exact in float32
    with pytest.raises(ConfigError, match=r"^task\.env\.control\.velocityClamp=-1 is invalid: give a number >= 0"):
        build_task(porting_cfg("Cartpole", "+task.env.control.velocityClamp=-1"))
    with pytest.raises(ConfigError, match=r"task\.env\.control\.velocityClamp: 'wheel' matches no joint"):
        build_task(porting_cfg("Cartpole", "+task.env.control.velocityClamp={wheel:1.0}"))
