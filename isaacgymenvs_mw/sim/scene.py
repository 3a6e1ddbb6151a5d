"""Per-asset views of a scene: which columns of qpos / qvel / ctrl belong to which asset, as zero-copy torch views.

A scene is the main asset (unprefixed names; the Simulator's own ``dof_pos``, ``root_pos``, ...) plus the assets of
``env.assets``, each attached under its name prefix (``sim/asset_loading.py``, which records each asset's name and prefix
in the model as a custom text element). ``Simulator.asset(name)`` returns the ``AssetView`` of one of them:

* a free asset (``fixBaseLink: False``): ``root_pos`` (N, 3) world position of the root body's origin,
  ``root_quat`` (N, 4) orientation (w, x, y, z), ``root_lin_vel`` (N, 3) linear velocity of the origin in the world
  frame, ``root_ang_vel`` (N, 3) angular velocity in the root body's own frame (MuJoCo's free joint: qvel[3:6]);
* an articulated asset: ``dof_pos`` / ``dof_vel`` (N, its hinge and slide joints, in model order) and ``ctrl``
  (N, its own actuators), with the names in ``dof_names`` / ``actuator_names``.

All are basic slices of the Simulator's views, so reading them costs nothing and writing them in place writes the
state (``Simulator.write_state(mask, ..., asset=name)`` writes the masked worlds only and refreshes the poses).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import torch

_FREE = int(mujoco.mjtJoint.mjJNT_FREE)

# Custom text elements that record, in the compiled model, each scene asset's name (after this) and prefix (its
# text): the Simulator, and a saved .mjb, know the scene's parts without the request.
SCENE_TEXT_PREFIX = "scene_asset:"


@dataclass
class JointLayout:
    """Where one asset's joints sit in qpos / qvel: a free root joint (or none) then hinge/slide columns."""

    free_qpos: int | None  # qpos address of the free joint (7 columns), None without one
    free_qvel: int | None  # qvel address of the free joint (6 columns)
    dof_qpos: slice  # hinge/slide columns of qpos
    dof_qvel: slice  # hinge/slide columns of qvel
    dof_names: list[str] = field(default_factory=list)


def joint_layout(m: mujoco.MjModel, joints: list[int], what: str) -> JointLayout:
    """The layout of ``joints`` (model joint ids, one asset's, in model order). An asset's joints are contiguous in
    qpos (MuJoCo lays bodies out depth-first, one asset's subtree after another); a free joint may only come first."""
    free_q = free_v = None
    rest = joints
    if joints and int(m.jnt_type[joints[0]]) == _FREE:
        free_q, free_v = int(m.jnt_qposadr[joints[0]]), int(m.jnt_dofadr[joints[0]])
        rest = joints[1:]
    if any(int(m.jnt_type[j]) == _FREE for j in rest):
        raise ValueError(f"{what}: a free joint that is not the root's first joint")
    qadr = [int(m.jnt_qposadr[j]) for j in rest]
    vadr = [int(m.jnt_dofadr[j]) for j in rest]
    if qadr and qadr != list(range(qadr[0], qadr[0] + len(qadr))):
        raise ValueError(f"{what}: its joints are not contiguous in qpos ({qadr})")
    q0 = qadr[0] if qadr else (free_q + 7 if free_q is not None else 0)
    v0 = vadr[0] if vadr else (free_v + 6 if free_v is not None else 0)
    return JointLayout(free_q, free_v, slice(q0, q0 + len(qadr)), slice(v0, v0 + len(vadr)),
                       [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in rest])


class AssetView:
    """One scene asset's slice of the batched state (see the module docstring for frames and shapes)."""

    def __init__(self, name: str, prefix: str, m: mujoco.MjModel, qpos: torch.Tensor, qvel: torch.Tensor,
                 ctrl: torch.Tensor) -> None:
        self.name = name
        self.prefix = prefix
        ids = [j for j in range(m.njnt) if _name(m, mujoco.mjtObj.mjOBJ_JOINT, j).startswith(prefix)]
        self.layout = joint_layout(m, ids, f"env.assets.{name}")
        self.body_names = [n for n in (_name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(m.nbody))
                           if n.startswith(prefix)]
        self.dof_names = self.layout.dof_names
        self.floating_base = self.layout.free_qpos is not None
        self.dof_pos = qpos[:, self.layout.dof_qpos]
        self.dof_vel = qvel[:, self.layout.dof_qvel]
        acts = [a for a in range(m.nu) if _name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a).startswith(prefix)]
        self.actuator_names = [_name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in acts]
        # Attached after the main asset's actuators, in env.assets order: one contiguous block per asset.
        first = acts[0] if acts else m.nu
        if acts != list(range(first, first + len(acts))):
            raise ValueError(f"env.assets.{name}: its actuators are not contiguous in ctrl ({acts})")
        self.actuator_columns = slice(first, first + len(acts))
        self.ctrl = ctrl[:, self.actuator_columns]
        if self.floating_base:
            q, v = self.layout.free_qpos, self.layout.free_qvel
            self.root_pos = qpos[:, q:q + 3]
            self.root_quat = qpos[:, q + 3:q + 7]  # (w, x, y, z)
            self.root_lin_vel = qvel[:, v:v + 3]  # world frame
            self.root_ang_vel = qvel[:, v + 3:v + 6]  # root body frame (MuJoCo free-joint convention)

    @property
    def num_dof(self) -> int:
        return len(self.dof_names)

    def __repr__(self) -> str:
        kind = "free" if self.floating_base else "fixed"
        return f"AssetView({self.name!r}, prefix={self.prefix!r}, {kind}, dofs={self.dof_names})"


def scene_prefixes(m: mujoco.MjModel, text_prefix: str) -> dict[str, str]:
    """{asset name: name prefix} recorded in the model by the builder (custom text elements), in env.assets order."""
    out = {}
    for t in range(m.ntext):
        name = _name(m, mujoco.mjtObj.mjOBJ_TEXT, t)
        if name.startswith(text_prefix):
            adr, size = int(m.text_adr[t]), int(m.text_size[t])
            out[name[len(text_prefix):]] = bytes(m.text_data[adr:adr + size]).rstrip(b"\0").decode()
    return out


def main_joints(m: mujoco.MjModel, prefixes: list[str]) -> list[int]:
    """Joint ids of the main asset: those whose names carry none of the scene assets' prefixes."""
    return [j for j in range(m.njnt)
            if not any(_name(m, mujoco.mjtObj.mjOBJ_JOINT, j).startswith(p) for p in prefixes)]


def main_ends(m: mujoco.MjModel, main: list[int]) -> tuple[int, int]:
    """(qpos, qvel) column where the main asset's state ends: the scene assets' joints follow it (their bodies are
    attached after the main asset's, and MuJoCo numbers joints depth-first); nq, nv without scene assets."""
    rest = sorted(set(range(m.njnt)) - set(main))
    if not rest:
        return int(m.nq), int(m.nv)
    if main and max(main) > rest[0]:
        raise ValueError("env.asset: the main asset's joints do not all come before the scene assets' in qpos")
    return int(m.jnt_qposadr[rest[0]]), int(m.jnt_dofadr[rest[0]])


def _name(m: mujoco.MjModel, kind: mujoco.mjtObj, i: int) -> str:
    return mujoco.mj_id2name(m, kind, i) or ""
