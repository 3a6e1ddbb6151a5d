"""The package's layering rule (DESIGN.md): only ``isaacgymenvs_mw/sim/`` imports MuJoCo (``mujoco``, ``mujoco_warp``).

Besides keeping the simulator behind one layer, the rule matters at run time: ``isaacgymenvs_mw.sim`` chooses
MuJoCo's headless OpenGL backend (MUJOCO_GL) before MuJoCo is first imported, and MuJoCo reads it only then. A task
module that imported ``mujoco`` itself, ahead of the sim layer, left MuJoCo on GLFW, and ``capture_video=True``
failed on every machine without a display.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "isaacgymenvs_mw"
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


def test_the_task_map_imports_mujoco_only_after_the_gl_backend_is_chosen():
    # A fresh interpreter without a display: when mujoco is first imported (through the task map, as train.py
    # does), the sim layer must already have run its backend choice.
    probe = (
        "import sys\n"
        "class Watch:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'mujoco' and 'seen' not in globals():\n"
        "            globals()['seen'] = 'isaacgymenvs_mw.sim' in sys.modules\n"
        "        return None\n"
        "sys.meta_path.insert(0, Watch())\n"
        "import isaacgymenvs_mw.tasks\n"
        "print(seen)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "MUJOCO_GL")}
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "True"
