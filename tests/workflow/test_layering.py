"""The package's layering rule (DESIGN.md): only ``isaacgymenvs_mw/sim/`` imports MuJoCo (``mujoco``, ``mujoco_warp``).

And what importing the package must not do: load an OpenGL library. OSMesa's LLVM, loaded when the package chose
MUJOCO_GL=osmesa at import, crashed (exit 139) the tests and ``make()`` followed by ``import rsl_rl`` with a CUDA build
of torch on a CPU-only machine (Triton's LLVM clashed with it). GL is now chosen only when a video recorder starts.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "isaacgymenvs_mw"
SIMULATOR_MODULES = {"mujoco", "mujoco_warp"}


def imported_modules(path: Path) -> set[str]:
    """Top-level names of every module a source file imports, at any depth (functions included)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_only_the_sim_layer_imports_mujoco():
    offenders = {str(path.relative_to(PACKAGE.parent)): sorted(imported_modules(path) & SIMULATOR_MODULES)
                 for path in PACKAGE.rglob("*.py") if "sim" not in path.relative_to(PACKAGE).parts[:1]}
    assert {path: names for path, names in offenders.items() if names} == {}


def test_the_documented_api_loads_no_opengl_library(tmp_path):
    # A fresh interpreter without a display and without MUJOCO_GL, as on a headless CPU machine: the README's make()
    # example, a few steps and the learner's import. No GL library may be mapped into the process afterwards, and
    # MUJOCO_GL is left unset (MuJoCo's default context class is only a name until a renderer is made).
    probe = (
        "import os, sys, ctypes.util\n"
        "real = ctypes.util.find_library  # as where OSMesa is installed (the README's set-up installs it)\n"
        "ctypes.util.find_library = lambda name: 'libOSMesa.so.8' if name == 'OSMesa' else real(name)\n"
        "import isaacgymenvs_mw\n"
        "import torch\n"
        "env = isaacgymenvs_mw.make('Cartpole', num_envs=2, sim_device='cpu', rl_device='cpu', headless=True)\n"
        "env.reset()\n"
        "for _ in range(3):\n"
        "    env.step(torch.zeros(2, env.num_actions))\n"
        "import rsl_rl.runners\n"
        "import isaacgymenvs_mw.learning.launch\n"
        "maps = open('/proc/self/maps').read()\n"
        "gl = sorted({line.split()[-1] for line in maps.splitlines()\n"
        "             if any(name in line for name in ('libOSMesa', 'libEGL', 'libGL.', 'libGLX', 'libLLVM'))})\n"
        "print('GL', gl, 'OpenGL' in sys.modules, os.environ.get('MUJOCO_GL'))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL",
                                                             "PYOPENGL_PLATFORM")}
    env.update(OMP_NUM_THREADS="1", PYTHONPATH=str(PACKAGE.parent))
    out = subprocess.run([sys.executable, "-c", probe], env=env, cwd=tmp_path, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().splitlines()[-1] == "GL [] False None", out.stdout
