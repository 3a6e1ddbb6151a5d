"""The task YAML's ``sim`` section in MuJoCo terms (``SolverOptions``), checked and written into a model's options
(sim/builder.py)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from isaacgymenvs_mw.utils.errors import ConfigError

_INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
}
_SOLVERS = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}
_CONES = {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC}


@dataclass
class SolverOptions:
    """The task YAML ``sim`` section, in MuJoCo terms."""

    dt: float = 0.005
    gravity: Sequence[float] = (0.0, 0.0, -9.81)
    integrator: str = "implicitfast"
    solver: str = "newton"
    cone: str = "pyramidal"
    iterations: int = 10
    ls_iterations: int = 20
    ccd_iterations: int | None = None  # None: MuJoCo's default (35); GJK and EPA iterations of convex collisions
    ccd_tolerance: float | None = None  # None: MuJoCo's default (1e-6)
    impratio: float = 1.0
    enable_contacts: bool = True


def apply_options(spec: mujoco.MjSpec, o: SolverOptions) -> None:
    """Write ``o`` into the spec's options; a value MuJoCo has no counterpart for is an error naming its key."""
    for key, table in (("integrator", _INTEGRATORS), ("solver", _SOLVERS), ("cone", _CONES)):
        if getattr(o, key) not in table:
            raise ConfigError(f"sim.{key}: '{getattr(o, key)}' is not one of {sorted(table)}")
    if o.dt <= 0:
        raise ConfigError(f"sim.dt must be > 0, got {o.dt}")
    spec.option.timestep = float(o.dt)
    spec.option.gravity = np.asarray(o.gravity, dtype=float)
    spec.option.integrator = _INTEGRATORS[o.integrator]
    spec.option.solver = _SOLVERS[o.solver]
    spec.option.cone = _CONES[o.cone]
    spec.option.iterations = int(o.iterations)
    spec.option.ls_iterations = int(o.ls_iterations)
    if o.ccd_iterations is not None:
        if o.ccd_iterations < 1:
            raise ConfigError(f"sim.ccd_iterations must be >= 1, got {o.ccd_iterations}")
        spec.option.ccd_iterations = int(o.ccd_iterations)
    if o.ccd_tolerance is not None:
        if o.ccd_tolerance <= 0:
            raise ConfigError(f"sim.ccd_tolerance must be > 0, got {o.ccd_tolerance}")
        spec.option.ccd_tolerance = float(o.ccd_tolerance)
    spec.option.impratio = float(o.impratio)
    if not o.enable_contacts:
        spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT

