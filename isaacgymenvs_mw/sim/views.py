"""The simulator's torch views of the batched MuJoCo Warp state (zero-copy, the same tensor objects for the
simulator's life), the main asset's dof and root slices, and IsaacGym-style state tensors computed from them.

``TensorViews`` is a part of ``Simulator`` (sim/simulator.py): ``_bind_views`` runs once in its constructor, after
``model`` and ``data`` exist.
"""

from __future__ import annotations

import mujoco
import torch
import warp as wp

from isaacgymenvs_mw.sim.scene import SCENE_TEXT_PREFIX, AssetView, main_ends, main_joints, scene_prefixes
from isaacgymenvs_mw.utils.rotations import quat_rotate


# The views of the state a sensor may read (sim/sensors.py, SensorContext): all worlds' state, and the main asset's.
_STATE_VIEWS = ("qpos", "qvel", "ctrl", "qacc", "qfrc_actuator", "actuator_force", "xpos", "xquat", "xipos", "xmat",
                "site_xpos", "site_xmat", "mocap_pos", "mocap_quat", "cvel", "subtree_com", "sensordata",
                "xfrc_applied", "dof_pos", "dof_vel")
_ROOT_VIEWS = ("root_pos", "root_quat", "root_lin_vel", "root_ang_vel")


class TensorViews:
    """Torch views of the worlds' state, by MuJoCo name and by IsaacGym's layout."""

    def _bind_views(self) -> None:
        d, m = self.data, self.mj_model
        self.qpos = self.torch_view(d.qpos)
        self.qvel = self.torch_view(d.qvel)
        self.ctrl = self.torch_view(d.ctrl)
        self.qacc = self.torch_view(d.qacc)
        self.qfrc_actuator = self.torch_view(d.qfrc_actuator)
        self.actuator_force = self.torch_view(d.actuator_force)  # per actuator, after its force range
        self.xpos = self.torch_view(d.xpos)
        self.xquat = self.torch_view(d.xquat)
        self.xipos = self.torch_view(d.xipos)  # centres of mass, world frame
        self.xmat = self.torch_view(d.xmat)  # (N, nbody, 3, 3) body orientations: columns are the body axes, world
        self.site_xpos = self.torch_view(d.site_xpos)  # (N, nsite, 3) site positions, world frame
        self.site_xmat = self.torch_view(d.site_xmat)  # (N, nsite, 3, 3) site orientations
        # (N, nmocap, 3) / (N, nmocap, 4) poses of the mocap bodies (world frame, (w, x, y, z)): bodies a task moves
        # by writing them (a goal marker), not the physics; the next step's kinematics reads them.
        self.mocap_pos = self.torch_view(d.mocap_pos)
        self.mocap_quat = self.torch_view(d.mocap_quat)
        # Body velocities as MuJoCo keeps them: (angular, linear) in world axes, about the subtree centre of mass of
        # the body's root (see body_lin_vel).
        self.cvel = self.torch_view(d.cvel)
        self.subtree_com = self.torch_view(d.subtree_com)
        self._body_rootid = torch.tensor(m.body_rootid, device=self.device, dtype=torch.long)
        self.sensordata = self.torch_view(d.sensordata)
        self.xfrc_applied = self.torch_view(d.xfrc_applied)
        self.overflow = self.torch_view(d.overflow)
        self._qpos0 = self.torch_view(self.model.qpos0)
        # Equality-constraint rows of the last step's constraint set (MuJoCo Warp keeps them per world, computed at
        # the start of the step from its state): read by equality_violation, only in models that have any.
        self._efc = None
        if m.neq:
            efc_type = self.torch_view(d.efc.type)
            self._efc = (efc_type, self.torch_view(d.efc.id), self.torch_view(d.efc.pos),
                         self.torch_view(d.nefc), torch.arange(efc_type.shape[1], device=self.device))
        # What one physics step hands to the next; everything else (poses, contacts, sensors) is recomputed.
        self._carried_state = {
            "qpos": self.qpos, "qvel": self.qvel, "ctrl": self.ctrl, "act": self.torch_view(d.act),
            "qacc_warmstart": self.torch_view(d.qacc_warmstart), "time": self.torch_view(d.time),
            "xfrc_applied": self.xfrc_applied, "qfrc_applied": self.torch_view(d.qfrc_applied),
        }
        # A reset zeroes all carried state but the positions (set to qpos0), and the sensors and overflow bits.
        self._zeroed_on_reset = [view for name, view in self._carried_state.items() if name != "qpos"]
        self._zeroed_on_reset += [self.sensordata, self.overflow]

        # The main asset (env.asset) owns the unprefixed names and the first qpos columns; the Simulator's own
        # dof and root views are its. Each env.assets entry has an AssetView (self.asset(name)).
        prefixes = scene_prefixes(m, SCENE_TEXT_PREFIX)
        self.assets = {name: AssetView(name, prefix, m, self.qpos, self.qvel, self.ctrl)
                       for name, prefix in prefixes.items()}
        main = main_joints(m, list(prefixes.values()))
        self.floating_base = bool(main) and int(m.jnt_type[main[0]]) == int(mujoco.mjtJoint.mjJNT_FREE)
        q0, v0 = (7, 6) if self.floating_base else (0, 0)
        q1, v1 = main_ends(m, main)
        self.dof_pos = self.qpos[:, q0:q1]
        self.dof_vel = self.qvel[:, v0:v1]
        if self.floating_base:
            self.root_pos = self.qpos[:, 0:3]
            self.root_quat = self.qpos[:, 3:7]  # (w, x, y, z)
            self.root_lin_vel = self.qvel[:, 0:3]  # world frame
            self.root_ang_vel = self.qvel[:, 3:6]  # body frame (MuJoCo free-joint convention)

        self.dof_names = [  # the main asset's hinge and slide joints: the columns of dof_pos
            mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
            for j in main
            if int(m.jnt_type[j]) in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
        ]
        self.body_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(m.nbody)]
        # ctrl[:, i] is the command of actuator i: the asset's own actuators in file order, then one per joint the
        # YAML drives, in joint order. actuator_joints[i] is the joint it drives (None: tendon, site, ... transmission).
        self.actuator_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or f"actuator{a}"
                               for a in range(m.nu)]
        self.actuator_joints = [
            mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.actuator_trnid[a, 0]))
            if int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT) else None
            for a in range(m.nu)
        ]

    def state_views(self) -> dict[str, torch.Tensor]:
        """The views of the worlds' state by attribute name (what a sensor may read: ``SensorContext.state``)."""
        names = [*_STATE_VIEWS, *(_ROOT_VIEWS if self.floating_base else ())]
        return {name: getattr(self, name) for name in names}

    @property
    def num_dof(self) -> int:
        return self.dof_pos.shape[1]

    def asset(self, name: str) -> AssetView:
        """The views of scene asset ``name`` (an ``env.assets`` key): root pose and velocity of a free one, dof
        and actuator columns of an articulated one (sim/scene.py)."""
        if name not in self.assets:
            raise KeyError(f"no scene asset named {name!r}; env.assets of this model: {list(self.assets)}")
        return self.assets[name]

    @property
    def num_actuators(self) -> int:
        """Columns of ``ctrl`` (MuJoCo's nu)."""
        return int(self.mj_model.nu)

    def torch_view(self, array: wp.array) -> torch.Tensor:
        """The torch tensor of one of the simulator's Warp arrays, the same object at every call. torch.compile
        knows two tensors share memory only by their storage, and ``wp.to_torch`` makes a new storage per call: a
        compiled step that wrote through one view and read through another could order the two wrongly."""
        kept = self._torch_views.get(id(array))
        if kept is None:  # the array is kept beside its view: its id names no other array while the entry exists
            kept = self._torch_views[id(array)] = (array, wp.to_torch(array))
        return kept[1]

    def model_field(self, name: str) -> torch.Tensor:
        """Torch view of a Model array (per-world fields have num_worlds rows); "opt.gravity" for gravity."""
        if name.startswith("opt."):
            return self.torch_view(getattr(self.model.opt, name[len("opt."):]))
        return self.torch_view(getattr(self.model, name))

    def body_lin_vel(self, body_ids: torch.Tensor | slice, com: bool = False) -> torch.Tensor:
        """(N, len(body_ids), 3) world-frame linear velocity of each body's origin (MuJoCo's mj_objectVelocity,
        world axes), or of its centre of mass with ``com``, from the last physics step's forward pass."""
        roots = self._body_rootid[body_ids]
        vel = self.cvel[:, body_ids]
        point = (self.xipos if com else self.xpos)[:, body_ids]
        return vel[..., 3:] + torch.cross(vel[..., :3], point - self.subtree_com[:, roots], dim=-1)

    def body_states(self, body_ids: torch.Tensor | None = None, com: bool = False) -> torch.Tensor:
        """IsaacGym's rigid body state tensor: (N, nbody or len(body_ids), 13), all in the world frame.

        Columns: position of the body frame's origin (0:3), orientation quaternion **(w, x, y, z)**, MuJoCo's order
        (3:7; IsaacGym's is x, y, z, w), linear velocity of the body origin (7:10; with ``com`` of the centre of
        mass, which is what PhysX reports), angular velocity (10:13). Body indices are MuJoCo's (0 is the world
        body; ``body_names``). A new tensor, computed on the device from ``xpos``, ``xquat``, ``cvel``: the values
        of the last forward pass, which after ``simulate()`` describe the start of its last physics step (call
        ``forward()`` first for the current ``qpos``/``qvel``).
        """
        ids = slice(None) if body_ids is None else body_ids
        return torch.cat((self.xpos[:, ids], self.xquat[:, ids], self.body_lin_vel(ids, com=com),
                          self.cvel[:, ids, :3]), dim=-1)

    def root_ang_vel_world(self) -> torch.Tensor:
        """(N, 3) floating base angular velocity in the world frame (``root_ang_vel`` is in the body frame), from
        the current ``qpos``/``qvel``."""
        self._require_floating_base("root_ang_vel_world")
        return quat_rotate(self.root_quat, self.root_ang_vel)

    def root_states(self) -> torch.Tensor:
        """IsaacGym's root state layout, (N, 13): position, quaternion **(w, x, y, z)**, linear and angular velocity,
        all in the world frame, from the current ``qpos``/``qvel``; a new tensor (write with ``write_state``)."""
        self._require_floating_base("root_states")
        return torch.cat((self.root_pos, self.root_quat, self.root_lin_vel, self.root_ang_vel_world()), dim=-1)

    def _require_floating_base(self, what: str) -> None:
        if not self.floating_base:
            raise ValueError(f"{what} needs a floating base, but the model's root is fixed (env.asset.fixBaseLink)")
