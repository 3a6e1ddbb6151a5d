"""The Franka Panda of the manipulation tasks (FrankaCabinet, FrankaCubeStack): its joints, servo targets and hand
frames in a batch of worlds.

The arm is the scene's main asset (``env.asset``: ``assets/mjcf/franka_panda.xml`` or a model with the same joint,
actuator, body and site names): 7 arm joints and two coupled finger slides, 8 position servos (7 joints and the
gripper, whose command is each finger's opening in metres, 0 ... 0.04), and the ``grasp`` site between the
fingertip pads. IsaacGymEnvs' Franka tasks have 9 DOFs and 9 actions, one per finger; here the fingers are coupled
by the model, so the gripper is one action and both finger positions stay in the observation.
"""

from __future__ import annotations

import numpy as np
import torch

from isaacgymenvs_mw.sim import Simulator
from isaacgymenvs_mw.utils.errors import ConfigError

ARM_JOINTS = tuple(f"joint{i}" for i in range(1, 8))
FINGER_JOINTS = ("finger_joint1", "finger_joint2")
SERVOS = tuple(f"actuator{i}" for i in range(1, 8)) + ("gripper",)


class FrankaArm:
    """Joint limits, servo targets and hand frames of the Panda in every world of ``sim``.

    Args:
        sim: the built Simulator, the Panda its main asset.
        task: the task's name, for error messages.
    """

    def __init__(self, sim: Simulator, task: str) -> None:
        self.sim = sim
        dofs = list(sim.dof_names)
        expected = list(ARM_JOINTS + FINGER_JOINTS)
        if dofs != expected:
            raise ConfigError(f"{task}: env.asset must be a Franka Panda with the joints {expected} "
                              f"(assets/mjcf/franka_panda.xml); the model's are {dofs}")
        if list(sim.actuator_names[:len(SERVOS)]) != list(SERVOS):
            raise ConfigError(f"{task}: env.asset's first actuators must be {list(SERVOS)}; the model's are "
                              f"{sim.actuator_names}")
        m, dev = sim.mj_model, sim.device
        ranges = torch.tensor(np.array([m.joint(j).range for j in expected]), dtype=torch.float32, device=dev)
        self.dof_lower, self.dof_upper = ranges[:, 0], ranges[:, 1]  # (9,)
        servo = torch.tensor(np.array([m.actuator(a).ctrlrange for a in SERVOS]), dtype=torch.float32, device=dev)
        self.target_lower, self.target_upper = servo[:, 0], servo[:, 1]  # (8,): joint ranges, gripper 0 ... 0.04
        self.num_targets = len(SERVOS)
        self.ctrl = sim.ctrl[:, :self.num_targets]
        self.targets = torch.zeros((sim.num_worlds, self.num_targets), device=dev)
        self.grasp_site = sim.site_id("grasp")
        self.left_finger = sim.body_id("left_finger")
        self.right_finger = sim.body_id("right_finger")

    def start_pose(self, values: object, key: str) -> torch.Tensor:
        """The 9 joint positions ``values`` (7 arm joints, rad; 2 fingers, m) as a tensor, checked: 9 numbers, each
        inside its joint's range (a finger's opening within 0 ... 0.04 m), else a one-line error naming ``key``."""
        try:
            start = torch.tensor([float(v) for v in values], dtype=torch.float32, device=self.sim.device)
        except (TypeError, ValueError):
            start = None
        if start is None or start.shape != (9,):
            raise ConfigError(f"{key}={values!r} is invalid: give 9 joint positions (7 arm joints, 2 fingers)")
        outside = ((start < self.dof_lower) | (start > self.dof_upper)).nonzero().flatten().tolist()
        if outside:
            i = outside[0]
            raise ConfigError(f"{key}[{i}]={float(start[i]):.6g} is outside the range of joint "
                              f"{self.sim.dof_names[i]} [{float(self.dof_lower[i]):.6g}, "
                              f"{float(self.dof_upper[i]):.6g}] (a finger's opening is 0 ... 0.04 m)")
        return start

    # ------------------------------------------------------------------ commands
    def move_targets(self, delta: torch.Tensor) -> None:
        """Add ``delta`` (N, 8) to the servo targets, keep them in the servo ranges, and command them."""
        torch.clamp(self.targets + delta, self.target_lower, self.target_upper, out=self.targets)
        self.ctrl.copy_(self.targets)

    def reset(self, mask: torch.Tensor, dof_pos: torch.Tensor) -> None:
        """Put the masked worlds' arms at ``dof_pos`` (N, 9; finger 2 follows finger 1), at rest, targets there.
        Body poses follow at the next physics step (call ``sim.refresh_kinematics`` to read them before)."""
        dof_pos = torch.cat((dof_pos[:, :8], dof_pos[:, 7:8]), dim=1)  # the coupled fingers open alike
        self.sim.write_state(mask, dof_pos=dof_pos, dof_vel=torch.zeros_like(dof_pos), refresh=False)
        rows = mask.unsqueeze(1)
        self.targets.copy_(torch.where(rows, dof_pos[:, :8], self.targets))
        self.ctrl.copy_(torch.where(rows, self.targets, self.ctrl))  # the running worlds keep their commands

    # ------------------------------------------------------------------ state
    def scaled_dof_pos(self) -> torch.Tensor:
        """(N, 9) joint positions mapped from their ranges to [-1, 1] (IsaacGymEnvs' ``unscale``)."""
        return 2.0 * (self.sim.dof_pos - self.dof_lower) / (self.dof_upper - self.dof_lower) - 1.0

    def grasp_pos(self) -> torch.Tensor:
        """(N, 3) world position of the point between the fingertip pads."""
        return self.sim.site_xpos[:, self.grasp_site]

    def grasp_axes(self) -> torch.Tensor:
        """(N, 3, 3) the grasp frame's axes as columns: x, y (the fingers' opening direction: the left finger moves
        along +y) and z (the approach direction, out of the palm)."""
        return self.sim.site_xmat[:, self.grasp_site]

    def finger_pos(self) -> tuple[torch.Tensor, torch.Tensor]:
        """World positions (N, 3) of the left and right finger bodies' origins: the inner faces of the pads."""
        return self.sim.xpos[:, self.left_finger], self.sim.xpos[:, self.right_finger]
