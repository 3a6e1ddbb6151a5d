"""Per-world model parameters: what a randomised quantity writes, and the constants derived from it.

MuJoCo Warp reads a batched Model field as ``field[world % field.shape[0]]``, so a field given ``num_worlds`` rows
(``Simulator(per_world_fields=...)``) holds one value per world. Changing masses, inertias, centres of mass or
armature makes two derived constants stale that the step reads (``constraint.py``: contact and joint-limit
regularisation): ``body_invweight0`` and ``dof_invweight0``. ``mujoco_warp.set_const`` recomputes them with about
``nv + 6 nbody`` dense solves launched from Python, which a torch-captured step cannot hold and which would cost a
physics step each time; ``InertiaConstants`` computes the same two fields in batched torch from the per-world
masses, inertias, CoM offsets and armature at qpos0 (the other outputs of set_const, ``body_subtreemass`` and
``actuator_acc0``, are not read by the step).
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

_OBJECTS = {"bodies": mujoco.mjtObj.mjOBJ_BODY, "geoms": mujoco.mjtObj.mjOBJ_GEOM,
            "joints": mujoco.mjtObj.mjOBJ_JOINT, "actuators": mujoco.mjtObj.mjOBJ_ACTUATOR}


def model_names(m: mujoco.MjModel, kind: str, for_geoms: bool = False) -> tuple[list[str], list[int]]:
    """(names, ids) of the model's bodies / geoms / joints / actuators that randomisation may select.

    Bodies leave out the world body unless geoms are selected by body (the ground belongs to the world);
    joints are the hinge and slide joints (the floating base's free joint has no properties to randomise);
    an unnamed element is named "".
    """
    count = {"bodies": m.nbody, "geoms": m.ngeom, "joints": m.njnt, "actuators": m.nu}[kind]
    ids = list(range(count))
    if kind == "bodies" and not for_geoms:
        ids = ids[1:]
    if kind == "joints":
        movable = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
        ids = [j for j in ids if int(m.jnt_type[j]) in movable]
    return [mujoco.mj_id2name(m, _OBJECTS[kind], i) or "" for i in ids], ids


class InertiaConstants:
    """``body_invweight0`` / ``dof_invweight0`` of every world from its masses, inertias, CoM offsets and armature.

    The formulas are MuJoCo's ``mj_setConst`` (and ``mujoco_warp.set_const``): at qpos0, with M the joint-space
    inertia, ``dof_invweight0 = diag(M^-1)`` (averaged over the translational and the rotational dofs of a free
    joint, over the three of a ball joint) and, with J the 6 x nv Jacobian at a body's centre of mass,
    ``body_invweight0 = (mean of diag(J M^-1 J^T)[:3], mean of [3:])``; zero for the world and for bodies welded
    to it. Kinematics at qpos0 does not depend on the randomised quantities, so the dof axes and body frames are
    computed once on the host (MuJoCo C); only M and the Jacobians at the per-world centres of mass are per world.
    """

    def __init__(self, m: mujoco.MjModel, device: torch.device) -> None:
        d = mujoco.MjData(m)
        d.qpos[:] = m.qpos0
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        f64 = dict(device=device, dtype=torch.float64)
        nb, nv = m.nbody, m.nv
        # cdof is the dof's motion about the subtree centre of mass of its tree root: a point p moves with
        # cdof_lin + cdof_ang x (p - subtree_com[root]); the velocity of a physical point does not depend on it.
        ang = d.cdof[:, :3].copy()
        root_com = d.subtree_com[m.body_rootid[m.dof_bodyid]]
        lin = d.cdof[:, 3:] - np.cross(ang, root_com)
        chain = np.zeros((nb, nv))
        for b in range(1, nb):
            body = b
            while body > 0 and m.body_dofnum[body] == 0:
                body = m.body_parentid[body]
            dof = m.body_dofadr[body] + m.body_dofnum[body] - 1 if body > 0 else -1
            while dof >= 0:
                chain[b, dof] = 1.0
                dof = m.dof_parentid[dof]
        inertia_frame = np.zeros((nb, 9))
        for b in range(nb):
            mujoco.mju_quat2Mat(inertia_frame[b], m.body_iquat[b])
        self.ang = torch.tensor(ang, **f64)
        self.lin = torch.tensor(lin, **f64)
        self.chain = torch.tensor(chain, **f64)
        self.xpos = torch.tensor(d.xpos, **f64)
        self.xmat = torch.tensor(d.xmat.reshape(nb, 3, 3), **f64)
        self.ximat_rot = self.xmat @ torch.tensor(inertia_frame.reshape(nb, 3, 3), **f64)
        self.moving = torch.tensor((m.body_weldid != 0) & (np.arange(nb) > 0), device=device)
        # dof_invweight0 averages the diagonal over a free joint's 3 + 3 and a ball joint's 3 dofs.
        average = np.eye(nv)
        for j in range(m.njnt):
            adr, kind = m.jnt_dofadr[j], int(m.jnt_type[j])
            groups = {int(mujoco.mjtJoint.mjJNT_FREE): [(0, 3), (3, 6)], int(mujoco.mjtJoint.mjJNT_BALL): [(0, 3)]}
            for lo, hi in groups.get(kind, []):
                average[adr + lo:adr + hi, adr + lo:adr + hi] = 1.0 / 3.0
        self.average = torch.tensor(average, **f64)

    def compute(self, mass: torch.Tensor, ipos: torch.Tensor, inertia: torch.Tensor,
                armature: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-world inputs (W, nbody), (W, nbody, 3), (W, nbody, 3), (W, nv) -> (W, nbody, 2), (W, nv)."""
        mass, ipos, inertia, armature = (x.to(torch.float64) for x in (mass, ipos, inertia, armature))
        com = self.xpos + torch.einsum("bij,wbj->wbi", self.xmat, ipos)                          # (W, nb, 3)
        offset = com.unsqueeze(2) - torch.zeros_like(self.lin)                                     # (W, nb, nv, 3)
        jac_lin = (self.lin + torch.linalg.cross(self.ang.expand_as(offset), offset)) * self.chain.unsqueeze(-1)
        jac_ang = self.ang * self.chain.unsqueeze(-1)                                               # (nb, nv, 3)
        inertia_world = torch.einsum("bij,wbj,bkj->wbik", self.ximat_rot, inertia, self.ximat_rot)  # (W, nb, 3, 3)
        mass_matrix = (torch.einsum("wb,wbia,wbja->wij", mass, jac_lin, jac_lin)
                       + torch.einsum("bia,wbac,bjc->wij", jac_ang, inertia_world, jac_ang)
                       + torch.diag_embed(armature))
        # M = L L^T, so x^T M^-1 x = |L^-1 x|^2. cholesky_ex and the triangular solve check no error flags: no host
        # sync, so a captured step can hold them.
        factor, _ = torch.linalg.cholesky_ex(mass_matrix)
        eye = torch.eye(factor.shape[-1], dtype=factor.dtype, device=factor.device).expand_as(factor)
        inv_factor = torch.linalg.solve_triangular(factor, eye, upper=False)                       # (W, nv, nv)
        dof_invweight0 = torch.square(inv_factor).sum(dim=1) @ self.average
        trans = torch.square(torch.einsum("wij,wbja->wbai", inv_factor, jac_lin)).sum(dim=(2, 3)) / 3.0
        rot = torch.square(torch.einsum("wij,bja->wbai", inv_factor, jac_ang)).sum(dim=(2, 3)) / 3.0
        # MuJoCo's fallback for a body that cannot translate or cannot rotate: use the other component.
        tiny = mujoco.mjMINVAL
        trans, rot = (torch.where((trans < tiny) & (rot > tiny), rot, trans),
                      torch.where((rot < tiny) & (trans > tiny), trans, rot))
        body_invweight0 = torch.stack((trans, rot), dim=-1) * self.moving.view(1, -1, 1)
        return body_invweight0.to(torch.float32), dof_invweight0.to(torch.float32)
