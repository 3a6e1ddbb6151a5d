"""Export a trained policy for deployment: ONNX and TorchScript, observation normaliser included, with the metadata a
robot runtime needs (docs/deploy.md).

``out_dir`` receives:
  * ``policy.onnx``   input 'obs' (and one per image group, e.g. 'camera': 0-255 pixels), output 'actions', any
                      batch size; the metadata in ``metadata_props``
                      (one entry per top-level key, values JSON-encoded). A recurrent policy also takes its state
                      ('h_in', and 'c_in' for an LSTM: layers x batch x units) and returns the next ('h_out',
                      'c_out'); the metadata's "recurrent" entry describes them
  * ``policy.pt``     TorchScript; the metadata as the extra file ``metadata.json``
  * ``policy.json``   the same metadata, for people and scripts
  * ``model.mjb``     the task's compiled MuJoCo model (binary, same MuJoCo version), for sim-to-sim checks
"""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path
from typing import Any

import torch

from isaacgymenvs_mw._version import __version__
from isaacgymenvs_mw.learning.reporting import package_versions
from isaacgymenvs_mw.learning.training_run import TrainingRun
from isaacgymenvs_mw.utils.files import save_files_whole

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


def export_policy(runner: TrainingRun, out_dir: Path, task=None) -> tuple[Path, Path]:
    """Write ``policy.onnx`` and ``policy.pt`` (and, given the task, their metadata and ``model.mjb``).

    Both map raw observations, as the task returns them (history stacked), to the deterministic (mean) action. Every
    file is made in memory first and the set is then written as one unit (``save_files_whole``): a full disk is one
    line naming the folder, and the files already in ``out_dir`` stay as they were, with nothing partial beside them.
    """
    out_dir = Path(out_dir)
    save_files_whole(out_dir, policy_files(runner, task))
    return out_dir / "policy.onnx", out_dir / "policy.pt"


def policy_files(runner: TrainingRun, task=None) -> dict[str, bytes]:
    """The exported files by name, as bytes: no library writes to the disk itself, so none can abort on a full one."""
    model, jit = runner.export_modules()  # the learner's policy, normaliser included, on the CPU
    # An image policy (learning/models.py) has one more input per image group, named after it ("camera"); a
    # recurrent one its state, whose batch is its second axis.
    inputs = list(getattr(model, "input_names", ["obs"]))
    outputs = list(getattr(model, "output_names", ["actions"]))
    recurrent = bool(getattr(model, "is_recurrent", False))
    axes = {name: {1 if recurrent and name not in ("obs", "actions") else 0: "batch"} for name in [*inputs, *outputs]}
    onnx_buffer = io.BytesIO()
    with torch.no_grad(), warnings.catch_warnings():
        # torch warns about any LSTM exported at batch 1 unless its state is an input, which it is here
        warnings.filterwarnings("ignore", message="Exporting a model to ONNX with a batch_size other than 1")
        torch.onnx.export(
            model, model.get_dummy_inputs(), onnx_buffer, input_names=inputs, output_names=outputs,
            dynamic_axes=axes, opset_version=18, dynamo=False,
        )
    metadata = policy_metadata(task) if task is not None else None
    if metadata is not None and recurrent:
        metadata["recurrent"] = {"type": model.rnn_type, "state_inputs": inputs[1:], "state_outputs": outputs[1:],
                                 "state_shape": [model.num_layers, "batch", model.hidden_size],
                                 "episode_start": "zeros"}
    text = json.dumps(metadata, indent=2) if metadata is not None else None
    jit_buffer = io.BytesIO()
    torch.jit.save(jit, jit_buffer, _extra_files={METADATA_FILE: text} if text is not None else None)
    files = {"policy.onnx": _with_onnx_metadata(onnx_buffer.getvalue(), metadata), "policy.pt": jit_buffer.getvalue()}
    if task is not None:
        files["policy.json"] = (text + "\n").encode()
        files["model.mjb"] = task.sim.model_bytes()
    return files


def _with_onnx_metadata(model: bytes, metadata: dict[str, Any] | None) -> bytes:
    if metadata is None:
        return model
    import onnx  # installed with torch's ONNX exporter (onnxscript)

    proto = onnx.load_from_string(model)
    del proto.metadata_props[:]
    for key, value in metadata.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, json.dumps(value)
    return proto.SerializeToString()


def read_metadata(path: Path) -> dict[str, Any]:
    """The metadata of an exported ``policy.onnx`` (from its metadata_props) or ``policy.pt`` (its extra file)."""
    path = Path(path)
    if path.suffix == ".onnx":
        import onnx

        return {p.key: json.loads(p.value) for p in onnx.load(str(path)).metadata_props}
    extra = {METADATA_FILE: ""}
    torch.jit.load(str(path), map_location="cpu", _extra_files=extra)
    return json.loads(extra[METADATA_FILE])
