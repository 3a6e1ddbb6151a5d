"""apply_body_forces on a CUDA device (captured graphs) against the same calls on Warp's CPU device.

    python benchmarks/diagnostics/forces_on_device.py [--device cuda:0]

The CPU path is checked against MuJoCo C by tests/sim/test_body_forces.py; this runs the same sequence of env steps
on both devices and prints the largest qpos difference after each, as JSON. It covers what the CPU cannot: the
graph variants (physics, +forces, +pose), the first call of each graph (an eager run that is undone, then the
capture), one-step forces dropped by the captured step, and persistent forces until cleared.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import mujoco
import numpy as np
import torch

from isaacgymenvs_mw.sim import Simulator

# The model tests/sim/test_body_forces.py checks against MuJoCo C.
XML = (Path(__file__).resolve().parents[2] / "tests" / "assets" / "free_box_and_hinge.xml").read_text()
N, SUBSTEPS = 64, 3


def episode(device: str) -> list[np.ndarray]:
    """qpos after each env step of: a plain step, a one-step body-frame force at a point, a plain step, a
    world-frame force made persistent for two steps, a step after clearing it."""
    model = mujoco.MjModel.from_xml_string(XML)
    sim = Simulator(model, N, device, substeps=SUBSTEPS)
    gen = torch.Generator().manual_seed(0)
    sim.qvel.copy_(torch.randn(N, model.nv, generator=gen).to(device))
    forces = (torch.randn(N, 2, 3, generator=gen) * 5).to(device)
    torques = torch.randn(N, 2, 3, generator=gen).to(device)
    points = (torch.randn(N, 2, 3, generator=gen) * 0.1).to(device)
    out = []

    def record() -> None:
        out.append(sim.qpos.detach().cpu().numpy().copy())

    sim.simulate(); record()
    sim.apply_body_forces(forces, torques, bodies=["box", "arm"], positions=points, frame="body")
    sim.simulate(); record()
    sim.simulate(); record()
    sim.apply_body_forces(forces, None, bodies=["box", "arm"], frame="world", persist=True)
    sim.simulate(); record()
    sim.simulate(); record()
    sim.clear_body_forces()
    sim.simulate(); record()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda:0")
    args = parser.parse_args()
    on_device, on_cpu = episode(args.device), episode("cpu")
    steps = ["plain", "one-step body force at a point", "plain (force dropped)", "persistent world force",
             "persistent world force", "cleared"]
    diffs = [float(np.abs(a - b).max()) for a, b in zip(on_device, on_cpu)]
    print(json.dumps({"device": args.device, "worlds": N, "max_abs_qpos_diff_per_step": dict(zip(steps, diffs)),
                      "ok": max(diffs) < 1e-4}))


if __name__ == "__main__":
    main()
