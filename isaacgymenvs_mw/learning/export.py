"""Export a trained policy for deployment: ONNX and TorchScript, observation normaliser included, with the metadata a
robot runtime needs (docs/deploy.md).

``out_dir`` receives:
  * ``policy.onnx``   input 'obs' (and one per image group, e.g. 'camera': 0-255 pixels), output 'actions', any
                      batch size; the metadata in ``metadata_props``
                      (one entry per top-level key, values JSON-encoded)
  * ``policy.pt``     TorchScript; the metadata as the extra file ``metadata.json``
  * ``policy.json``   the same metadata, for people and scripts
  * ``model.mjb``     the task's compiled MuJoCo model (binary, same MuJoCo version), for sim-to-sim checks
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import torch
from rsl_rl.runners import OnPolicyRunner

from isaacgymenvs_mw._version import __version__
from isaacgymenvs_mw.learning.reporting import package_versions
from isaacgymenvs_mw.utils.files import disk_errors_named

METADATA_FILE = "metadata.json"  # name of the TorchScript extra file


def policy_metadata(task) -> dict[str, Any]:
    """The task's deployment description (``VecTask.deployment_info``) plus the versions that produced it."""
    info = dict(task.deployment_info())
    actuators = task.action_actuators()
    if actuators is not None:
        # The names give a plain task's actions a meaning on the robot; legged tasks' joint_names say the same in
        # joint terms.
        info.setdefault("actuator_names", actuators)
        info.setdefault("actuator_joints", list(task.sim.actuator_joints))  # the joint each drives (None: not a joint)
    info["versions"] = {"isaacgymenvs_mw": __version__, **package_versions()}
    info["files"] = {"onnx": "policy.onnx", "torchscript": "policy.pt", "mujoco_model": "model.mjb"}
    return info


def export_policy(runner: OnPolicyRunner, out_dir: Path, task=None) -> tuple[Path, Path]:
    """Write ``policy.onnx`` and ``policy.pt`` (and, given the task, their metadata and ``model.mjb``).

    Both map raw observations, as the task returns them (history stacked), to the deterministic (mean) action. The
    files are written in a private folder beside ``out_dir`` and then moved in, so a file in ``out_dir`` is always
    whole, also while another process exports into it.
    """
    out_dir = Path(out_dir)
    with disk_errors_named(out_dir / "policy.onnx"):  # a full disk: one line naming the folder, no traceback
        out_dir.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
        try:
            _write_policy_files(runner, staging, task)
            for written in sorted(staging.iterdir()):
                os.replace(written, out_dir / written.name)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
    return out_dir / "policy.onnx", out_dir / "policy.pt"


def _write_policy_files(runner: OnPolicyRunner, out_dir: Path, task) -> None:
    onnx_path, jit_path = out_dir / "policy.onnx", out_dir / "policy.pt"
    policy_module = getattr(runner, "policy_module", None)  # a runner of another learner (rl_games) gives its own
    if policy_module is not None:
        model = policy_module().to("cpu").eval()  # a copy: the runner's own stays where it is
    else:
        model = runner.alg.get_policy().as_onnx(verbose=False).to("cpu").eval()
    # An image policy (learning/models.py) has one more input per image group, named after it ("camera").
    inputs = list(getattr(model, "input_names", ["obs"]))
    with torch.no_grad():
        torch.onnx.export(
            model, model.get_dummy_inputs(), str(onnx_path), input_names=inputs, output_names=["actions"],
            dynamic_axes={name: {0: "batch"} for name in [*inputs, "actions"]}, opset_version=18, dynamo=False,
        )
    if policy_module is not None:
        with torch.no_grad():
            torch.jit.trace(model, model.get_dummy_inputs()).save(str(jit_path))
    else:
        runner.export_policy_to_jit(str(out_dir), filename=jit_path.name)
    if task is not None:
        metadata = policy_metadata(task)
        text = json.dumps(metadata, indent=2)
        (out_dir / "policy.json").write_text(text + "\n")
        _add_onnx_metadata(onnx_path, metadata)
        jit = torch.jit.load(str(jit_path), map_location="cpu")
        torch.jit.save(jit, str(jit_path), _extra_files={METADATA_FILE: text})
        task.sim.save_model(str(out_dir / "model.mjb"))


def _add_onnx_metadata(path: Path, metadata: dict[str, Any]) -> None:
    import onnx  # installed with torch's ONNX exporter (onnxscript)

    proto = onnx.load(str(path))
    del proto.metadata_props[:]
    for key, value in metadata.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, json.dumps(value)
    onnx.save(proto, str(path))


def read_metadata(path: Path) -> dict[str, Any]:
    """The metadata of an exported ``policy.onnx`` (from its metadata_props) or ``policy.pt`` (its extra file)."""
    path = Path(path)
    if path.suffix == ".onnx":
        import onnx

        return {p.key: json.loads(p.value) for p in onnx.load(str(path)).metadata_props}
    extra = {METADATA_FILE: ""}
    torch.jit.load(str(path), map_location="cpu", _extra_files=extra)
    return json.loads(extra[METADATA_FILE])
