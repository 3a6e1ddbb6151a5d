"""What of a user's ``--config-dir`` folder Hydra searches (before the project's ``cfg/``).

A user brings either a project of their own (``task/MyTask.yaml``, ``train/MyTaskPPO.yaml``) or IsaacGymEnvs' whole
``cfg`` folder, to run its rl_games train YAMLs unchanged. Searched as it is, IsaacGymEnvs' folder would replace the
project's ``config.yaml`` (its run keys lack ``runs_dir`` and the rest) and the project's task YAMLs with PhysX ones
(``sim.physx``, IsaacGym's asset files). So Hydra searches a view of the folder instead: everything in it but its
``config.yaml`` (the run keys are always ``cfg/config.yaml``'s; give yours on the command line) and but the
IsaacGymEnvs task YAMLs of tasks the project has its own MuJoCo YAML for; one line says what was left out.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
from pathlib import Path

import yaml

_VIEWS: dict[str, str] = {}  # user folder -> its view, made once per process


def is_isaacgym_task_yaml(path: Path) -> bool:
    """True for an IsaacGymEnvs task YAML: one with a ``sim.physx`` section (IsaacGym's solver settings)."""
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError, UnicodeDecodeError):
        return False
    sim = data.get("sim") if isinstance(data, dict) else None
    return isinstance(sim, dict) and "physx" in sim


def user_config_view(folder: str, cfg_dir: Path) -> str:
    """The folder Hydra searches for the user's ``folder``: links to its entries, less its ``config.yaml`` and the
    IsaacGymEnvs task YAMLs that ``cfg_dir/task`` has a YAML of the same name for."""
    if folder in _VIEWS:
        return _VIEWS[folder]
    source = Path(folder)
    view = Path(tempfile.mkdtemp(prefix="isaacgymenvs_mw.config_dir."))
    atexit.register(shutil.rmtree, view, ignore_errors=True)
    left_out: list[str] = []
    for entry in sorted(source.iterdir()):
        if entry.name == "config.yaml":
            left_out.append("config.yaml (the run keys are cfg/config.yaml's)")
        elif entry.name == "task" and entry.is_dir():
            (view / "task").mkdir()
            ours = []
            for task_file in sorted(entry.iterdir()):
                if (task_file.suffix == ".yaml" and (cfg_dir / "task" / task_file.name).is_file()
                        and is_isaacgym_task_yaml(task_file)):
                    ours.append(task_file.stem)
                else:
                    os.symlink(task_file, view / "task" / task_file.name)
            if ours:
                left_out.append(f"the IsaacGymEnvs (PhysX) task YAMLs of {', '.join(ours)}, for which this project's "
                                "cfg/task/<Name>.yaml (the same keys, on MuJoCo) is used")
        else:
            os.symlink(entry, view / entry.name)
    if left_out:
        print(f"[config] --config-dir {folder}: not read: {'; '.join(left_out)}", flush=True)
    _VIEWS[folder] = str(view)
    return str(view)
