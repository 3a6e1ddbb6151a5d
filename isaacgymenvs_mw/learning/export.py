"""Export a trained policy for deployment: ONNX and TorchScript, observation normaliser included."""

from __future__ import annotations

from pathlib import Path

import torch
from rsl_rl.runners import OnPolicyRunner


def export_policy(runner: OnPolicyRunner, out_dir: Path) -> tuple[Path, Path]:
    """Write ``policy.onnx`` (any batch size, input 'obs', output 'actions') and ``policy.pt`` (TorchScript).

    Both map raw observations, as the task returns them, to the deterministic (mean) action.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    onnx_path, jit_path = out_dir / "policy.onnx", out_dir / "policy.pt"
    model = runner.alg.get_policy().as_onnx(verbose=False).to("cpu").eval()
    with torch.no_grad():
        torch.onnx.export(
            model, model.get_dummy_inputs(), str(onnx_path), input_names=["obs"], output_names=["actions"],
            dynamic_axes={"obs": {0: "batch"}, "actions": {0: "batch"}}, opset_version=18, dynamo=False,
        )
    runner.export_policy_to_jit(str(out_dir), filename=jit_path.name)
    return onnx_path, jit_path
