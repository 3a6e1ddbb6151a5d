"""Lookups on the compiled model: indices of bodies, geoms, sites and mocap bodies by name, joint limits and PD
gains. ``Lookups`` is a part of ``Simulator`` (sim/simulator.py), which sets ``mj_model``, ``device``,
``body_names``, ``dof_names``, ``fused_bodies`` and the id cache ``_body_id_cache``.
"""

from __future__ import annotations

from typing import Sequence

import mujoco
import torch


class Lookups:
    """Model indices and constants by name."""

    def joint_pd_gains(self) -> dict[str, tuple[float, float]]:
        """{joint: (stiffness, damping)} of the joints driven by position actuators (MuJoCo's kp and kv)."""
        m, out = self.mj_model, {}
        for a in range(m.nu):
            is_joint = int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT)
            # A position actuator: force = kp * ctrl - kp * q - kv * qdot (gain kp, bias (0, -kp, -kv)).
            is_position = float(m.actuator_gainprm[a, 0]) != 0.0 and float(m.actuator_biasprm[a, 1]) != 0.0
            if is_joint and is_position:
                name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.actuator_trnid[a, 0]))
                out[name] = (float(m.actuator_gainprm[a, 0]), -float(m.actuator_biasprm[a, 2]))
        return out

    def geom_id(self, name: str) -> int:
        gid = mujoco.mj_name2id(self.mj_model, mujoco.mjtObj.mjOBJ_GEOM, name)
        if gid < 0:
            raise KeyError(f"no geom named '{name}'")
        return gid

    def joint_limits(self, names: list[str] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(lower, upper): the model's range of each named joint (default: ``dof_names``, the columns of
        ``dof_pos``), float32 on the device; m or rad."""
        m = self.mj_model
        ranges = m.jnt_range[[m.joint(name).id for name in (self.dof_names if names is None else names)]]
        limits = torch.tensor(ranges, dtype=torch.float32, device=self.device)
        return limits[:, 0], limits[:, 1]

    def body_ids(self, bodies: Sequence[str | int] | torch.Tensor | None = None) -> torch.Tensor:
        """Body indices on the device from names or indices (None: every body, the world body 0 included).

        Lists are resolved once and cached, so calling this inside a step costs no host-to-device copy after the
        first time; a tensor is taken as it is (its range is not checked: that would sync).
        """
        if isinstance(bodies, torch.Tensor):
            return bodies.to(self.device, torch.long)
        key = ("all",) if bodies is None else tuple(bodies)
        ids = self._body_id_cache.get(key)
        if ids is None:
            if bodies is None:
                rows = list(range(len(self.body_names)))
            else:
                rows = [self._body_index(b) for b in bodies]
            ids = self._body_id_cache[key] = torch.tensor(rows, dtype=torch.long, device=self.device)
        return ids

    def _body_index(self, body: str | int) -> int:
        if isinstance(body, str):
            if body not in self.body_names:
                raise ValueError(f"bodies: {self._missing_body(body)}; valid: {self.body_names}")
            return self.body_names.index(body)
        if not 0 <= int(body) < len(self.body_names):
            raise ValueError(f"bodies: index {body} is out of range; valid: 0..{len(self.body_names) - 1}")
        return int(body)

    def _missing_body(self, name: str) -> str:
        """Why there is no body ``name``: the asset names none, or collapseFixedJoints merged it into a parent."""
        into = self.fused_bodies.get(name)
        if into is None:
            return f"no body named {name!r}"
        return (f"body {name!r} was merged into {into!r} by task.env.asset.collapseFixedJoints=True (a fixed joint "
                f"joins them): set it False to keep {name!r}, or name {into!r}")

    def site_id(self, name: str) -> int:
        """The model index of the site ``name`` (a column of ``site_xpos`` / ``site_xmat``)."""
        sid = mujoco.mj_name2id(self.mj_model, mujoco.mjtObj.mjOBJ_SITE, name)
        if sid < 0:
            names = [mujoco.mj_id2name(self.mj_model, mujoco.mjtObj.mjOBJ_SITE, i) for i in range(self.mj_model.nsite)]
            raise KeyError(f"no site named '{name}'; the model's sites: {names}")
        return sid

    def mocap_index(self, body: str) -> int:
        """Column of ``body`` in ``mocap_pos`` / ``mocap_quat`` (a body with ``mocap="true"`` in its MJCF)."""
        index = int(self.mj_model.body_mocapid[self.body_id(body)])
        if index < 0:
            mocap = [n for b, n in enumerate(self.body_names) if self.mj_model.body_mocapid[b] >= 0]
            raise ValueError(f"body '{body}' is not a mocap body; mocap bodies: {mocap}")
        return index

    def body_id(self, name: str) -> int:
        if name not in self.body_names:
            raise KeyError(f"{self._missing_body(name)}; bodies: {self.body_names}")
        return self.body_names.index(name)
