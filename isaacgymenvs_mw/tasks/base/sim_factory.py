"""How VecTask asks the sim layer for its simulator: the model the task YAML requests, and the Simulator built from
a request (``VecTask.model_request`` / ``VecTask.make_simulator`` call these; tasks extend the request between).

Named a factory, apart from ``sim/simulator.py`` (the ``Simulator`` class itself): this is the task side's reading of
the YAML into the sim layer's arguments, and holds no simulator code of its own."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

from isaacgymenvs_mw.sim import (
    ModelRequest,
    Simulator,
    build_model,
    free_joint_damping,
    free_joint_speed_limits,
    request_from_config,
)

ASSETS_DIR = Path(__file__).resolve().parents[3] / "assets"


def yaml_model_request(cfg: Mapping) -> ModelRequest:
    """``env.asset``, ``env.assets``, ``env.control`` (torque-speed limits included), ``env.plane``,
    ``env.baseInitState``, ``env.cameras``, ``env.sensors`` and ``sim`` (``sim.request.request_from_config``);
    relative asset roots are read from the task YAML's folder (``yaml_dir``)."""
    return request_from_config(cfg["env"], cfg.get("sim", {}), cfg.get("yaml_dir"), ASSETS_DIR)


def build_simulator(cfg: Mapping, request: ModelRequest, num_envs: int, device: str, substeps: int,
                    per_world_fields: tuple[str, ...]) -> Simulator:
    """The Simulator of ``request``: ``num_envs`` worlds on ``device``, ``substeps`` physics steps per env step, the
    ``per_world_fields`` batched (the task's and the randomised quantities'), the YAML's ``sim`` sizes and options."""
    sim = cfg.get("sim", {})
    model = build_model(request)
    simulator = Simulator(
        model,
        num_worlds=num_envs,
        device=device,
        substeps=substeps,
        nconmax=sim.get("nconmax"),
        njmax=sim.get("njmax"),
        per_world_fields=tuple(dict.fromkeys(per_world_fields)),
        use_graphs=sim.get("useGraphs"),
        deterministic=bool(sim.get("deterministic", False)),  # the run-level `deterministic`, via build_task
        declared_sensors=request.all_sensors(),
        torque_speed=request.torque_speed,
        angular_speed_limits=free_joint_speed_limits(model, request.angular_speed_caps()),
        free_body_damping=free_joint_damping(model, request.free_body_damping()),
    )
    if request.collapse_fixed_joints:
        simulator.fused_bodies = fused_bodies(request, simulator.body_names)
    return simulator


def fused_bodies(request: ModelRequest, compiled: list[str]) -> dict[str, str]:
    """{body of the asset file: the body it was merged into} for the bodies that collapseFixedJoints (MuJoCo's
    fusestatic) joined to a parent through a fixed joint, so that naming one can say why it is gone."""
    spec = request.spec  # parsed once by request_from_config; a request built by hand may have none
    if spec is None:
        return {}
    kept, out = set(compiled), {}
    for body in spec.bodies:
        if body.name and body.name not in kept:
            parent = body.parent
            while parent is not None and parent.name not in kept and parent.name != "world":
                parent = parent.parent
            out[body.name] = parent.name if parent is not None else "world"
    return out
