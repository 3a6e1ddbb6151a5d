"""Per-world model parameters: what a randomised quantity writes, and the constants derived from it.

MuJoCo Warp reads a batched Model field as ``field[world % field.shape[0]]``, so a field given ``num_worlds`` rows
(``Simulator(per_world_fields=...)``) holds one value per world. Changing masses, inertias, centres of mass or
armature makes two derived constants stale that the step reads (``constraint.py``: contact and joint-limit
regularisation): ``body_invweight0`` and ``dof_invweight0``. ``mujoco_warp.set_const`` recomputes them with about
``nv + 6 nbody`` dense solves launched from Python, which a torch-captured step cannot hold and which would cost a
physics step each time; ``InertiaConstants`` computes the same two fields in batched torch from the per-world
masses, inertias, CoM offsets and armature at qpos0 (the other outputs of set_const, ``body_subtreemass`` and
``actuator_acc0``, are not read by the step).

The randomisation layer (tasks/base/randomization.py) asks for a property by meaning (``"geoms.friction"``,
``"bodies.mass"``); ``MODEL_PROPERTIES`` says which Model field entries carry it here, with MuJoCo's columns and signs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from isaacgymenvs_mw.sim.names import name_matches
from isaacgymenvs_mw.sim.simulator import Simulator
from isaacgymenvs_mw.utils.errors import ConfigError

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


@dataclass(frozen=True)
class FieldWrite:
    """One Model field entry a property is written to: value * sign goes to ``field[..., column]``."""

    field: str
    column: int | None = None
    sign: float = 1.0

    def __str__(self) -> str:
        return self.field if self.column is None else f"{self.field}[{self.column}]"


@dataclass(frozen=True)
class ModelProperty:
    """A physical property of the model's bodies / geoms / joints / actuators (or of the world: ``elements`` None)."""

    elements: str | None
    writes: tuple[FieldWrite, ...]
    torque_speed: bool = False  # a parameter of the drives' torque-speed limit (sim.torque_speed), not a Model field
    per_joint: bool = False  # a joints property held per joint (jnt_*), not per dof (dof_*)

    @property
    def changes_inertia(self) -> bool:
        """Whether writing it makes ``body_invweight0`` / ``dof_invweight0`` stale (``InertiaConstants``)."""
        return any(w.field in INERTIA_INPUTS for w in self.writes)


# The Model fields InertiaConstants reads: writing any of them makes the derived constants stale.
INERTIA_INPUTS = ("body_mass", "body_ipos", "body_inertia", "dof_armature")

MODEL_PROPERTIES: dict[str, ModelProperty] = {
    "bodies.mass": ModelProperty("bodies", (FieldWrite("body_mass"),)),
    "bodies.com": ModelProperty("bodies", (FieldWrite("body_ipos"),)),
    "bodies.inertia": ModelProperty("bodies", (FieldWrite("body_inertia"),)),
    # Column 0 is the sliding friction; 1 and 2 are torsional and rolling.
    "geoms.friction": ModelProperty("geoms", (FieldWrite("geom_friction", 0),)),
    "geoms.torsional_friction": ModelProperty("geoms", (FieldWrite("geom_friction", 1),)),
    "geoms.rolling_friction": ModelProperty("geoms", (FieldWrite("geom_friction", 2),)),
    "joints.damping": ModelProperty("joints", (FieldWrite("dof_damping"),)),
    "joints.friction": ModelProperty("joints", (FieldWrite("dof_frictionloss"),)),
    # A joint's range (MuJoCo's limit constraint; only a limited joint has one).
    "joints.lower": ModelProperty("joints", (FieldWrite("jnt_range", 0),), per_joint=True),
    "joints.upper": ModelProperty("joints", (FieldWrite("jnt_range", 1),), per_joint=True),
    "joints.armature": ModelProperty("joints", (FieldWrite("dof_armature"),)),
    # An actuator's force is gainprm[0] * ctrl + biasprm[0] + biasprm[1] * q + biasprm[2] * qdot; for a position
    # servo kp = gainprm[0] = -biasprm[1] and kd = -biasprm[2].
    "actuators.stiffness": ModelProperty("actuators", (FieldWrite("actuator_gainprm", 0),
                                                       FieldWrite("actuator_biasprm", 1, -1.0))),
    "actuators.damping": ModelProperty("actuators", (FieldWrite("actuator_biasprm", 2, -1.0),)),
    "actuators.gain": ModelProperty("actuators", (FieldWrite("actuator_gainprm", 0),)),
    "actuators.bias": ModelProperty("actuators", (FieldWrite("actuator_biasprm", 0),)),
    "actuators.saturation_torque": ModelProperty("actuators", (FieldWrite("saturation"),), torque_speed=True),
    "actuators.torque_limit": ModelProperty("actuators", (FieldWrite("limit"),), torque_speed=True),
    "actuators.velocity_limit": ModelProperty("actuators", (FieldWrite("speed"),), torque_speed=True),
    "world.gravity": ModelProperty(None, (FieldWrite("opt.gravity"),)),
}


def per_world_fields(properties: Sequence[ModelProperty]) -> tuple[str, ...]:
    """Model fields the simulator must batch per world to hold one value of each property per world."""
    fields = [w.field for p in properties if not p.torque_speed for w in p.writes]
    if any(p.changes_inertia for p in properties):
        fields += ["body_invweight0", "dof_invweight0"]
    return tuple(dict.fromkeys(fields))


def element_ids(m: mujoco.MjModel, prop: ModelProperty, selector: str | None, patterns: list[str] | None,
                key: str, device: torch.device) -> torch.Tensor:
    """Indices into the property's field of the elements that ``patterns`` select by name (None: all of them).

    ``selector`` is the kind the patterns name (None: the property's own); geoms may also be selected by their
    body's name. Joints select their dofs. A property of the world has the one index 0.
    """
    if prop.elements is None:
        return torch.zeros(1, dtype=torch.long, device=device)
    kind = selector or prop.elements
    names, ids = model_names(m, kind, for_geoms=prop.elements == "geoms")
    if patterns is None:
        chosen = list(range(len(names)))
    else:
        chosen = []
        for pattern in patterns:
            chosen += [i for i in name_matches(pattern, names, f"{key}.{kind}", kind) if i not in chosen]
    element = [ids[i] for i in chosen]
    if kind == "bodies" and prop.elements == "geoms":
        element = [g for g in range(m.ngeom) if int(m.geom_bodyid[g]) in element]
    elif kind == "joints" and not prop.per_joint:
        element = [int(m.jnt_dofadr[j]) for j in element]
    return torch.tensor(sorted(set(element)), dtype=torch.long, device=device)


def actor_elements(m: mujoco.MjModel, prop: ModelProperty, index: torch.Tensor, prefix: str | None,
                   prefixes: Sequence[str]) -> torch.Tensor:
    """The entries of ``index`` (as ``element_ids`` returns them) that belong to one actor of the scene: a scene
    asset's (names starting with its ``prefix``) or, with ``prefix`` None, the main asset's (none of ``prefixes``).
    Bodies, geoms and joints belong to the actor of their body; actuators go by their own name."""
    def owned(name: str) -> bool:
        return name.startswith(prefix) if prefix is not None else not any(name.startswith(p) for p in prefixes)

    if prop.elements == "actuators":
        names = [mujoco.mj_id2name(m, _OBJECTS["actuators"], int(i)) or "" for i in index.tolist()]
        return index[torch.tensor([owned(n) for n in names], dtype=torch.bool, device=index.device)]
    body_of = {"bodies": lambda i: i, "geoms": lambda i: int(m.geom_bodyid[i]),
               "joints": (lambda i: int(m.jnt_bodyid[i])) if prop.per_joint else (lambda i: int(m.dof_bodyid[i]))}
    keep = [b > 0 and owned(mujoco.mj_id2name(m, _OBJECTS["bodies"], b) or "")
            for b in (body_of[prop.elements](int(i)) for i in index.tolist())]
    return index[torch.tensor(keep, dtype=torch.bool, device=index.device)]


def write_view(sim: Simulator, write: FieldWrite, torque_speed: bool, key: str) -> torch.Tensor:
    """The per-world view (num_worlds, n[, 3]) that ``write`` goes to; gravity is one element of three axes."""
    if torque_speed:
        if sim.torque_speed is None:
            raise ConfigError(f"{key}: the drives have no torque-speed limit; set env.control.torqueSpeed")
        return getattr(sim.torque_speed, write.field)
    full = sim.model_field(write.field)
    if full.shape[0] != sim.num_worlds:
        raise RuntimeError(f"{key}: Model field {write.field} is not batched per world")
    if write.field == "opt.gravity":
        return full.unsqueeze(1)
    return full if write.column is None else full[..., write.column]


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

    def update(self, sim: Simulator, mask: torch.Tensor) -> None:
        """Recompute the two constants of the worlds in ``mask`` from their current per-world fields."""
        fields = [sim.model_field(n) for n in INERTIA_INPUTS]
        body, dof = self.compute(*(f.expand(sim.num_worlds, *f.shape[1:]) for f in fields))
        for name, value in (("body_invweight0", body), ("dof_invweight0", dof)):
            view = sim.model_field(name)
            view.copy_(torch.where(mask.view((-1,) + (1,) * (value.dim() - 1)), value, view))
