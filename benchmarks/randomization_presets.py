"""Randomisation settings the GPU checks and the overhead benchmark apply on top of a task's YAML.

``apply(cfg, name)`` replaces ``task.task`` of a composed config:
  off:      task.randomize False (the nominal model, no noise, no pushes)
  shipped:  the task YAML as it is
  full:     every quantity the layer knows, drawn at every reset (masses, CoM, inertia -> the inertia constants
            recomputed in the step), gravity, friction, joint damping and armature, drive gains, a 0-2 step action
            delay, action and observation noise, pushes; plus a DC-motor torque-speed limit (Go1's URDF limits:
            23.7 N m, 30.1 rad/s)
  fixed:    like full but every draw a single value (range [a, a]) and no noise or pushes: two tasks built from it
            compute the same thing whatever their random streams (check_step_graph.py compares graph vs eager)
"""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf, open_dict


def _full(fixed: bool) -> dict:
    def spec(lo: float, hi: float, op: str) -> dict:
        return {"range": [hi, hi] if fixed else [lo, hi], "operation": op, "distribution": "uniform"}

    params = {
        "sim_params": {"gravity": spec(-0.2, 0.2, "additive")},
        "actor_params": {
            "rigid_body_properties": {"mass": {"bodies": ".*", **spec(0.8, 1.2, "scaling")},
                                      "com": {"bodies": ".*", **spec(-0.02, 0.02, "additive")},
                                      "inertia": {"bodies": ".*", **spec(0.8, 1.2, "scaling")}},
            "rigid_shape_properties": {"friction": {"geoms": "ground", **spec(0.5, 1.25, "scaling")}},
            "dof_properties": {"damping": spec(0.0, 0.05, "additive"), "armature": spec(0.8, 1.2, "scaling")},
            "actuator_properties": {"stiffness": spec(0.9, 1.1, "scaling"), "damping": spec(0.9, 1.1, "scaling"),
                                    "torque_limit": spec(0.9, 1.0, "scaling")},
        },
        "actions": {"delay": {"range": [1, 1] if fixed else [0, 2]}},
    }
    if not fixed:
        params["actions"].update({"range": [0.0, 0.02], "distribution": "gaussian", "operation": "additive"})
        params["observations"] = {"terms": {"base_lin_vel": 0.1, "base_ang_vel": 0.2, "projected_gravity": 0.05,
                                            "dof_pos": 0.01, "dof_vel": 1.5},
                                  "range": [0.0, 0.01], "distribution": "gaussian", "operation": "additive"}
        params["push"] = {"interval_s": 15.0, "range": [-1.0, 1.0], "operation": "set"}
    return params


TORQUE_SPEED = {"saturationTorque": {".*": 23.7}, "torqueLimit": {".*": 23.7}, "velocityLimit": {".*": 30.1}}
PRESETS = ("off", "shipped", "full", "fixed")


def apply(cfg: DictConfig, name: str) -> DictConfig:
    if name not in PRESETS:
        raise SystemExit(f"unknown randomisation preset {name!r}; give one of {PRESETS}")
    with open_dict(cfg):
        if name == "off":
            cfg.task.task = OmegaConf.create({"randomize": False})
        elif name in ("full", "fixed"):
            cfg.task.task = OmegaConf.create({"randomize": True, "randomization_params": _full(name == "fixed")})
            cfg.task.env.control.torqueSpeed = OmegaConf.create(TORQUE_SPEED)
    return cfg
