"""Joint-space mass matrix and a site's Jacobian per world, as torch tensors: what operational-space control needs.

MuJoCo Warp computes both inside every physics step (the composite-rigid-body mass matrix ``M``, stored as MuJoCo's
compressed rows ``M_rowadr`` / ``M_colind``, and the joint anchors and axes ``xanchor`` / ``xaxis``), for the state
the step started from, the same state as the body and site poses. ``SiteDynamics`` reads them where they lie:
plain torch on zero-copy views, so that a task's step keeps being one CUDA graph (no Warp launch inside it).
"""

from __future__ import annotations

from typing import Sequence

import mujoco
import numpy as np
import torch


class SiteDynamics:
    """The mass matrix over ``dofs`` and the Jacobian of site ``site`` with respect to them, in every world.

    Args:
        sim: the Simulator.
        site: the site's model index (``sim.site_id(name)``).
        dofs: the degrees of freedom (qvel columns) to keep, in this order; hinge or slide joints.
    """

    def __init__(self, sim, site: int, dofs: Sequence[int]) -> None:
        m: mujoco.MjModel = sim.mj_model
        dev = sim.device
        self.dofs = [int(d) for d in dofs]
        self.site = int(site)
        col = {d: i for i, d in enumerate(self.dofs)}
        # Compressed rows of the lower triangle -> positions in the dense (k, k) matrix of the kept dofs.
        src, rows, cols = [], [], []
        for r in range(m.nv):
            for k in range(int(m.M_rowadr[r]), int(m.M_rowadr[r] + m.M_rownnz[r])):
                c = int(m.M_colind[k])
                if r in col and c in col:
                    src.append(k)
                    rows.append(col[r])
                    cols.append(col[c])
        self._src = torch.tensor(src, dtype=torch.long, device=dev)
        k = len(self.dofs)
        lower = torch.tensor(rows, dtype=torch.long) * k + torch.tensor(cols, dtype=torch.long)
        upper = torch.tensor(cols, dtype=torch.long) * k + torch.tensor(rows, dtype=torch.long)
        self._lower, self._upper = lower.to(dev), upper.to(dev)
        self._M = sim.torch_view(sim.data.M)  # (N, nC)
        self._xanchor = sim.torch_view(sim.data.xanchor)  # (N, njnt, 3)
        self._xaxis = sim.torch_view(sim.data.xaxis)
        self._site_xpos = sim.site_xpos

        joints = [int(m.dof_jntid[d]) for d in self.dofs]
        kinds = [int(m.jnt_type[j]) for j in joints]
        hinge, slide = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
        if any(t not in (hinge, slide) for t in kinds):
            raise ValueError("SiteDynamics: only hinge and slide joints are supported")
        # A dof moves the site when its joint's body is the site's body or one of its ancestors.
        chain, b = set(), int(m.site_bodyid[self.site])
        while b > 0:
            chain.add(b)
            b = int(m.body_parentid[b])
        moves = np.array([int(m.jnt_bodyid[j]) in chain for j in joints], dtype=np.float32)
        self._joints = torch.tensor(joints, dtype=torch.long, device=dev)
        self._moves = torch.tensor(moves, device=dev).view(1, -1, 1)
        self._hinge = torch.tensor([t == hinge for t in kinds], device=dev).view(1, -1, 1)
        self._k = k

    def mass_matrix(self) -> torch.Tensor:
        """(N, k, k) joint-space inertia over the kept dofs (armature included), symmetric."""
        values = self._M[:, self._src]
        dense = torch.zeros((values.shape[0], self._k * self._k), dtype=values.dtype, device=values.device)
        dense[:, self._upper] = values
        dense[:, self._lower] = values
        return dense.view(-1, self._k, self._k)

    def jacobian(self) -> torch.Tensor:
        """(N, 6, k) site Jacobian in the world frame: rows 0-2 map joint velocities to the site's linear velocity,
        rows 3-5 to its angular velocity (a hinge: axis x (site - anchor) and axis; a slide: axis and 0)."""
        axis = self._xaxis[:, self._joints]  # (N, k, 3)
        lever = self._site_xpos[:, self.site].unsqueeze(1) - self._xanchor[:, self._joints]
        linear = torch.where(self._hinge, torch.linalg.cross(axis, lever, dim=-1), axis)
        angular = torch.where(self._hinge, axis, torch.zeros_like(axis))
        return (torch.cat((linear, angular), dim=-1) * self._moves).transpose(1, 2)
