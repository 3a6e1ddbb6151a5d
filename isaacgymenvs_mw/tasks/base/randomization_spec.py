"""The vocabulary of ``task.randomization_params`` (tasks/base/randomization.py): its sections and keys, the
quantities each group may randomise and where they live in the model, IsaacGymEnvs' keys refused with why, and the
parser of one distribution (``Spec``). No model and no device here: what a YAML may say, checked as it says it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch

from isaacgymenvs_mw.sim.randomization import MODEL_PROPERTIES, ModelProperty
from isaacgymenvs_mw.utils.errors import ConfigError

DISTRIBUTIONS = ("uniform", "gaussian", "loguniform")
OPERATIONS = ("additive", "scaling")
SCHEDULES = ("linear", "constant")
APPLY = ("startup", "reset", "interval")
SECTIONS = ("frequency", "observations", "actions", "sim_params", "actor_params", "push")
NOISE_KEYS = ("range", "distribution", "operation", "schedule", "schedule_steps")
DRAW_KEYS = NOISE_KEYS + ("apply", "setup_only", "interval_s", "interval_steps")
# The actor that ``actor_params.<actor>`` names for the main asset (env.asset); scene assets go by their env.assets name.
MAIN_ACTOR = "asset"
# IsaacGymEnvs keys with no MuJoCo counterpart: refused in one line saying why (docs/porting.md has the same rows).
REFUSED = {
    "color": "MuJoCo Warp renders no per-env colours for randomisation; remove it",
    "scale": "MuJoCo Warp shares one geometry (meshes, collision bounds) between worlds, so an actor cannot be "
             "resized per env; remove it, or build differently sized assets as separate env.assets",
    "restitution": "MuJoCo's contacts are soft constraints without a restitution coefficient; remove it",
    "compliance": "MuJoCo's contact softness is solref / solimp (env.contact and the MJCF), not randomised here",
    "velocity": "MuJoCo has no joint velocity limit to randomise; remove it",
    "effort": "randomise the drives' force with actuator_properties.gain (or torque_limit with "
              "env.control.torqueSpeed)",
}
# Smallest value a quantity that must stay positive is given (MuJoCo Warp turns a zero friction into NaN).
POSITIVE_FLOOR = 1e-3


@dataclass(frozen=True)
class Quantity:
    """What an ``actor_params`` / ``sim_params`` key randomises: a model property (sim/randomization.py) and how."""

    prop: ModelProperty
    axes: int = 0                    # 3: one draw per axis (x, y, z); 0: one per selected element
    broadcast: int = 0               # 3: one draw per element applied to its three columns (inertia)
    minimum: float | None = None     # None: any value; 0: >= 0; POSITIVE_FLOOR: > 0

    @property
    def selects(self) -> str | None:
        """The kind of element it is selected among: bodies, geoms, joints, actuators, or None (one per world)."""
        return self.prop.elements


def _quantity(prop: str, **how: Any) -> Quantity:
    return Quantity(MODEL_PROPERTIES[prop], **how)


QUANTITIES: dict[str, dict[str, Quantity]] = {
    "rigid_body_properties": {
        "mass": _quantity("bodies.mass", minimum=POSITIVE_FLOOR),
        "com": _quantity("bodies.com", axes=3),
        "inertia": _quantity("bodies.inertia", broadcast=3, minimum=POSITIVE_FLOOR),
    },
    "rigid_shape_properties": {
        "friction": _quantity("geoms.friction", minimum=POSITIVE_FLOOR),
        "torsion_friction": _quantity("geoms.torsional_friction", minimum=0.0),
        "rolling_friction": _quantity("geoms.rolling_friction", minimum=0.0),
    },
    "dof_properties": {
        "damping": _quantity("joints.damping", minimum=0.0),
        "armature": _quantity("joints.armature", minimum=0.0),
        "friction": _quantity("joints.friction", minimum=0.0),
        "lower": _quantity("joints.lower"),
        "upper": _quantity("joints.upper"),
    },
    "actuator_properties": {
        "stiffness": _quantity("actuators.stiffness", minimum=0.0),
        "damping": _quantity("actuators.damping", minimum=0.0),
        "gain": _quantity("actuators.gain"),
        "bias": _quantity("actuators.bias"),
        "saturation_torque": _quantity("actuators.saturation_torque", minimum=0.0),
        "torque_limit": _quantity("actuators.torque_limit", minimum=0.0),
        "velocity_limit": _quantity("actuators.velocity_limit", minimum=POSITIVE_FLOOR),
    },
}
SIM_QUANTITIES = {"gravity": _quantity("world.gravity", axes=3)}
SELECTORS = ("bodies", "geoms", "joints", "actuators")


@dataclass
class Spec:
    """A validated distribution: how to draw, how to combine with the nominal value, when."""

    key: str
    distribution: str
    operation: str
    lo: float
    hi: float
    schedule: str | None = None
    schedule_steps: int = 0
    apply: str = "reset"
    interval: int = 0
    buckets: int = 0  # num_buckets: draws take one of this many values drawn once at startup (0: every draw new)

    def identity(self) -> float:
        return 0.0 if self.operation == "additive" else 1.0


@dataclass
class Param:
    """One randomised quantity bound to the model: its spec, what it writes and the nominal values."""

    spec: Spec
    quantity: Quantity
    index: torch.Tensor                           # selected element ids (bodies, geoms, dofs, actuators)
    nominal: torch.Tensor                         # (1, k[, 3]) nominal values of the first field written
    views: list[tuple[torch.Tensor, float]] = field(default_factory=list)  # (field view (W, ...), sign)
    # Column of the draw each selected element takes (None: one draw each); a terrain's ground parts share one.
    draw_of: torch.Tensor | None = None
    bucket_values: torch.Tensor | None = None  # the num_buckets values draws pick from


def _parse_spec(raw: Any, key: str, allowed: tuple[str, ...], operations: tuple[str, ...] = OPERATIONS,
                default_apply: str = "reset") -> Spec:
    if not isinstance(raw, dict):
        raise ConfigError(f"{key}: expected a mapping with keys {list(allowed)}, got {raw!r}")
    unknown = sorted(set(raw) - set(allowed))
    if unknown:
        raise ConfigError(f"{key}: unknown key(s) {unknown}; valid keys: {list(allowed)}")
    if "range" not in raw:
        raise ConfigError(f"{key}.range is required: [low, high] (uniform, loguniform) or [mean, std] (gaussian)")
    try:
        lo, hi = (float(v) for v in raw["range"])
    except (TypeError, ValueError):
        raise ConfigError(f"{key}.range={raw['range']!r} is invalid: give two numbers") from None
    distribution = str(raw.get("distribution", "uniform"))
    if distribution not in DISTRIBUTIONS:
        raise ConfigError(f"{key}.distribution={distribution!r} is invalid: give one of {list(DISTRIBUTIONS)}")
    operation = str(raw.get("operation", operations[0]))
    if operation not in operations:
        raise ConfigError(f"{key}.operation={operation!r} is invalid: give one of {list(operations)}")
    if distribution == "gaussian" and hi < 0:
        raise ConfigError(f"{key}.range={[lo, hi]}: a gaussian's range is [mean, std]; std must be >= 0")
    if distribution != "gaussian" and lo > hi:
        raise ConfigError(f"{key}.range={[lo, hi]}: low > high")
    if distribution == "loguniform" and lo <= 0:
        raise ConfigError(f"{key}.range={[lo, hi]}: a loguniform range must be > 0")
    schedule = raw.get("schedule")
    steps = 0
    if schedule is not None:
        if schedule not in SCHEDULES:
            raise ConfigError(f"{key}.schedule={schedule!r} is invalid: give one of {list(SCHEDULES)} (or leave out)")
        steps = int(raw.get("schedule_steps", 0))
        if steps < 1:
            raise ConfigError(f"{key}.schedule_steps must be a whole number >= 1 when {key}.schedule is set")
    elif "schedule_steps" in raw:
        raise ConfigError(f"{key}.schedule_steps is set but {key}.schedule is not (linear or constant)")
    apply = str(raw.get("apply", default_apply))
    if raw.get("setup_only", False):  # IsaacGymEnvs' name for a draw made once, when the task is built
        if raw.get("apply", "startup") != "startup":
            raise ConfigError(f"{key}.setup_only=True and {key}.apply={apply!r} disagree: give one of them")
        apply = "startup"
    if apply not in APPLY:
        raise ConfigError(f"{key}.apply={apply!r} is invalid: give one of {list(APPLY)}")
    return Spec(key, distribution, operation, lo, hi, schedule, steps, apply)


def _interval_steps(raw: dict, key: str, control_dt: float) -> int:
    given = [k for k in ("interval_s", "interval_steps") if k in raw]
    if len(given) != 1:
        raise ConfigError(f"{key}: an interval draw needs exactly one of interval_s (seconds) or interval_steps")
    if given[0] == "interval_s":
        steps = round(float(raw["interval_s"]) / control_dt)
    else:
        steps = int(raw["interval_steps"])
    if steps < 1:
        raise ConfigError(f"{key}.{given[0]}={raw[given[0]]} is less than one policy step ({control_dt} s)")
    return steps
