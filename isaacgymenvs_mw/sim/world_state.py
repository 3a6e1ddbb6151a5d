"""The worlds' state as the simulator saves, loads, writes and resets it: the state one physics step carries to the
next, masked writes of it, resets to the initial state, and the reset of worlds that blew up.

``WorldState`` is a part of ``Simulator`` (sim/simulator.py), which binds the views it reads (``qpos``, ``qvel``,
``_carried_state``, ``_zeroed_on_reset``, ``_efc``: sim/views.py). All of it is device torch work with no host sync,
so it may run inside a captured step.
"""

from __future__ import annotations

import torch

from isaacgymenvs_mw.sim.divergence import DIVERGED_SPEED, EQUALITY_DIVERGED, EQUALITY_ROW


class WorldState:
    """Save, load, write and reset the worlds' state."""

    def reset_worlds(self, mask: torch.Tensor) -> None:
        """Return the masked worlds to the model's initial state (qpos0, zero velocity, no controls or forces).

        The state that carries from one step to the next is reset with torch ops (like ``mujoco_warp.reset_data``,
        whose other fields, contacts and mass matrix, are recomputed by the next step anyway), so that a task's
        whole post-physics step is plain torch work that a CUDA graph can hold. Overflow bits of those worlds are
        folded into the run's record first: a reset clears them.
        """
        self._overflow_seen |= self.overflow
        rows = mask.view(-1, 1)
        self.qpos.copy_(torch.where(rows, self._qpos0, self.qpos))
        for view in self._zeroed_on_reset:
            view.masked_fill_(mask.view((-1,) + (1,) * (view.dim() - 1)), 0)
        if self.body_forces is not None:
            self.body_forces.clear(mask)

    def save_state(self) -> dict[str, torch.Tensor]:
        """A copy of every world's carried state (positions, velocities, controls, forces, solver warm start)."""
        return {name: view.clone() for name, view in self._carried_state.items()}

    def load_state(self, state: dict[str, torch.Tensor]) -> None:
        """Put back a ``save_state`` copy in place; the next physics step continues from it."""
        for name, view in self._carried_state.items():
            view.copy_(state[name])

    def _snapshot(self) -> dict[str, torch.Tensor]:
        state = self.save_state()
        if self.body_forces is not None:
            state["body_forces"] = self.body_forces.wrench.clone()
        return state

    def _restore(self, state: dict[str, torch.Tensor]) -> None:
        self.load_state(state)
        if "body_forces" in state:
            self.body_forces.wrench.copy_(state["body_forces"])

    def equality_violation(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Each world's largest equality-constraint residual (|efc_pos| of any equality row, m or rad) in the last
        physics step, and the equality constraint it belongs to: two (num_worlds,) tensors; None when the model has
        no equality constraints. Device work only (no host sync)."""
        if self._efc is None:
            return None
        efc_type, efc_id, efc_pos, nefc, column = self._efc
        # Rows past a world's count hold what an earlier step left there.
        rows = (efc_type == EQUALITY_ROW) & (column < nefc.view(-1, 1))
        residual = torch.where(rows, efc_pos.abs(), torch.zeros_like(efc_pos))
        worst = residual.argmax(dim=1, keepdim=True)
        return residual.gather(1, worst).squeeze(1), efc_id.gather(1, worst).squeeze(1)

    def reset_nonfinite(self) -> torch.Tensor:
        """Reset worlds whose qpos or qvel holds NaN/inf, whose qvel exceeds ``DIVERGED_SPEED`` (a world on its
        way to NaN), or whose equality constraints are violated by more than ``EQUALITY_DIVERGED`` (see
        ``reset_worlds``); returns their mask."""
        bad = ~(torch.isfinite(self.qpos).all(dim=1) & (self.qvel.abs() <= DIVERGED_SPEED).all(dim=1))
        violation = self.equality_violation()
        if violation is not None:
            bad |= violation[0] > EQUALITY_DIVERGED
        self.reset_worlds(bad)
        return bad

    def write_state(
        self,
        mask: torch.Tensor,
        dof_pos: torch.Tensor | None = None,
        dof_vel: torch.Tensor | None = None,
        root_pos: torch.Tensor | None = None,
        root_quat: torch.Tensor | None = None,
        root_lin_vel: torch.Tensor | None = None,
        root_ang_vel: torch.Tensor | None = None,
        refresh: bool = True,
        asset: str | None = None,
    ) -> None:
        """Write state for the masked worlds only, then (``refresh``) recompute body poses from it.

        Each value is a full (num_worlds, ...) tensor; rows outside the mask are ignored. Selecting by mask keeps
        this free of host syncs. Root velocities: linear in the world frame, angular in the body frame.
        A caller that reads only qpos/qvel until the next physics step may skip the refresh.
        ``asset``: the name of an ``env.assets`` entry whose state this is (``self.asset(name)``); None: the main
        asset's (``env.asset``).
        """
        rows = mask.view(-1, 1)
        views = self if asset is None else self.asset(asset)
        pairs = [(views.dof_pos, dof_pos), (views.dof_vel, dof_vel)]
        if views.floating_base:
            pairs += [(views.root_pos, root_pos), (views.root_quat, root_quat),
                      (views.root_lin_vel, root_lin_vel), (views.root_ang_vel, root_ang_vel)]
        elif any(v is not None for v in (root_pos, root_quat, root_lin_vel, root_ang_vel)):
            key = "env.asset.fixBaseLink" if asset is None else f"env.assets.{asset}.fixBaseLink"
            raise ValueError(f"root state written to a fixed-base asset ({key} is True)")
        for view, value in pairs:
            if value is not None:
                view.copy_(torch.where(rows, value, view))
        if refresh:
            self.refresh_kinematics()
