"""The run-time log of worlds that blow up: which joint ran away (or which equality constraint broke) in the worlds
``Simulator.reset_nonfinite`` resets, warned about by a periodic host check. The build-time probe that predicts such
blow-ups is sim/stability.py, beside the model builder."""

from __future__ import annotations

import math
import warnings
from typing import TYPE_CHECKING

import mujoco
import numpy as np
import torch

from isaacgymenvs_mw.sim.divergence import DIVERGED_SPEED, EQUALITY_DIVERGED, object_name

if TYPE_CHECKING:  # the log reads a simulator it is handed; the simulator does not import this module
    from isaacgymenvs_mw.sim.simulator import Simulator

# What usually makes a world blow up, with the keys that change it (the blow-up warning's second half).
BLOWUP_CAUSES = (
    "Likely causes: PD drive gains too stiff for the timestep (env.control.stiffness / damping; a build-time "
    "'PD drive ... numerically unstable' warning names such a drive), sim.dt too large (lower it; raising "
    "env.controlFrequencyInv keeps the policy rate), wrong asset inertias (tiny or zero masses and inertias in the "
    "URDF <inertial> / MJCF; env.asset.armature adds rotor inertia to a joint), or drives fighting a closed chain "
    "(a build-time 'PD drive ... will blow' or 'This model will blow' warning); docs/config.md, 'Drive stability'."
)


class BlowupLog:
    """Which joint ran away in the worlds ``Simulator.reset_nonfinite`` resets, reported by a periodic host check.

    ``reset_nonfinite`` runs inside the step (device work only, capturable): it keeps each reset world's joint speeds
    (and, in a model with equality constraints, its largest constraint residual) from just before the reset. ``poll``
    runs where the host already syncs (VecTask's periodic overflow check) and warns with the first blown-up world's
    fastest joint (a NaN/inf speed counts as the fastest), or the equality constraint it broke at finite speeds.
    """

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self.speed = torch.zeros_like(sim.qvel)  # |qvel| of each world at its last blow-up
        self.seen = torch.zeros(sim.num_worlds, dtype=torch.bool, device=sim.device)  # blown up since the last poll
        # Largest equality residual of each world at its last blow-up, and which constraint it was.
        self.violation = torch.zeros(sim.num_worlds, dtype=sim.qvel.dtype, device=sim.device)
        self.equality = torch.zeros(sim.num_worlds, dtype=torch.long, device=sim.device)
        model = sim.mj_model
        self._equality_names = [object_name(model, mujoco.mjtObj.mjOBJ_EQUALITY, i, "equality")
                                for i in range(model.neq)]
        self._dof_labels = []  # how the warning names each dof
        for dof in range(model.nv):
            joint = int(model.dof_jntid[dof])
            label = f"'{mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint) or f'joint{joint}'}'"
            if int(model.jnt_type[joint]) == int(mujoco.mjtJoint.mjJNT_FREE):
                part = dof - int(model.jnt_dofadr[joint])
                label += f" (floating base, {'linear' if part < 3 else 'angular'} velocity {'xyz'[part % 3]})"
            self._dof_labels.append(label)

    def reset_nonfinite(self) -> torch.Tensor:
        """``sim.reset_nonfinite()``, keeping the reset worlds' joint speeds first; returns the reset mask."""
        speed = self.sim.qvel.abs()  # a copy: the reset zeroes qvel
        violation = self.sim.equality_violation()  # the reset leaves the constraint rows as they are
        bad = self.sim.reset_nonfinite()
        self.speed.copy_(torch.where(bad.view(-1, 1), torch.nan_to_num(speed, nan=math.inf), self.speed))
        if violation is not None:
            self.violation.copy_(torch.where(bad, violation[0].to(self.violation.dtype), self.violation))
            self.equality.copy_(torch.where(bad, violation[1].long(), self.equality))
        self.seen |= bad
        return bad

    def poll(self, interval: int | None = None) -> str | None:
        """Host-side check (syncs): warn when worlds blew up since the last poll, naming the first one's fastest joint
        or broken equality constraint; returns the message (None: none blew up). ``interval``: env steps since the
        last poll, for the text."""
        seen = self.seen.cpu().numpy().copy()  # a copy: on the CPU device numpy() shares memory with the zeroed flags
        if not seen.any():
            return None
        world = int(np.argmax(seen))
        speeds = self.speed[world].cpu().numpy().copy()
        dof = int(np.argmax(speeds))
        violation, equality = float(self.violation[world]), int(self.equality[world])
        self.seen.zero_()
        since = f"in the last {interval} env steps" if interval else "since the last check"
        nonfinite = int(np.isinf(speeds).sum())
        speed = (f"|velocity| {speeds[dof]:.3g}" if not nonfinite else
                 "velocity NaN/inf" + (f", as were {nonfinite - 1} other dof(s)" if nonfinite > 1 else ""))
        criteria = f"NaN/inf state, or a joint speed above {DIVERGED_SPEED:.0e}"
        if self._equality_names:
            criteria = (f"NaN/inf state, a joint speed above {DIVERGED_SPEED:.0e}, or an equality constraint "
                        f"violated by more than {EQUALITY_DIVERGED}")
        if not nonfinite and speeds[dof] <= DIVERGED_SPEED and violation > EQUALITY_DIVERGED:
            first = (f"First diverging: equality constraint '{self._equality_names[equality]}' in world {world} "
                     f"(violated by {violation:.3g}, fastest joint {self._dof_labels[dof]} at {speed}, when it "
                     "was reset)")
        else:
            first = f"First diverging joint: {self._dof_labels[dof]} in world {world} ({speed} when it was reset)"
        message = (
            f"{int(seen.sum())} world(s) blew up {since} ({criteria}) and were reset to the initial pose. {first}. "
            f"{BLOWUP_CAUSES}"
        )
        warnings.warn(message, RuntimeWarning, stacklevel=3)
        return message
