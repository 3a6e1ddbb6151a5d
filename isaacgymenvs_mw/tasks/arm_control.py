"""The arm controller of the Franka tasks (FrankaCabinet, FrankaCubeLift, FrankaCubeStack): how actions drive the
arm (``env.controlType``). One class per kind, with the same methods (action size, observation, apply, reset), so a
task never asks which one it has; a task names the kinds it supports (``arm_control``).

  * ``joint_pos`` (``JointPositionControl``, default): the 7 arm servo targets move by ``actionScale x control dt x a``
    per step, clamped to the joint ranges. The gripper action opens (>= 0) or closes (< 0) the fingers, as IGE's cube
    tasks; or, with a ``gripper_speed`` (FrankaCabinet's ``fingerSpeedScale``), it moves the gripper target like a
    joint's at that fraction of the arm's speed, as IGE's FrankaCabinet;
  * ``joint_tor`` (``JointTorqueControl``): the arm joints' torques are ``a x`` their limits (87 / 12 N m),
    IsaacGymEnvs' joint_tor, by rewriting the MJCF's arm servos as motors (``env.control.driveMode``);
  * ``osc`` (``OperationalSpaceControl``): IsaacGymEnvs' operational-space control. The first 6 actions x
    ``oscCommandLimit`` are a pose error of the grasp frame (m, rad; world axes), turned into arm torques through the
    task-space inertia from the mass matrix and the grasp site's Jacobian (``sim.dynamics.SiteDynamics``), plus a
    null-space pull toward ``startDofPos``; gains ``oscKp`` and ``oscKpNull``, critically damped, as IGE.
The last action is the gripper in every mode; the torque modes open or close it.
"""

from __future__ import annotations

import math

import torch

from isaacgymenvs_mw.sim.dynamics import SiteDynamics
from isaacgymenvs_mw.tasks.base.contract import check_actuator_count
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.franka import gripper_command, joint_pos_targets_delta
from isaacgymenvs_mw.utils.config import one_of
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import wrap_to_pi

CONTROL_TYPES = ("joint_pos", "joint_tor", "osc")


class JointPositionControl:
    """Actions move the arm's servo targets; 8 actions (7 joints and the gripper); observes all 9 joint positions.

    Args:
        gripper_speed: None: the gripper action opens or closes the fingers; a number: it moves the gripper's target
            by this fraction of ``actionScale x control dt`` per step at action 1 (m).
    """

    kind = "joint_pos"

    def __init__(self, gripper_speed: float | None = None) -> None:
        self.gripper_speed = gripper_speed

    def prepare(self, env: dict) -> None:
        """Change the task YAML before the model is built (the torque modes make the servos motors)."""

    def bind(self, task) -> None:
        """Take what the control reads from the built task: its arm, simulator and numbers."""
        self.task, self.sim, self.arm = task, task.sim, task.arm
        self.torque_limit = torch.tensor(task.sim.mj_model.actuator_forcerange[:7, 1], dtype=torch.float32,
                                         device=task.device)
        scale = task.env_numbers["actionScale"]
        self.arm_step = scale * task.control_dt  # rad per step at action 1
        self.target_step = None
        if self.gripper_speed is not None:
            # every target's step per unit action (rad for the arm, m for the gripper), IGE's FrankaCabinet
            speed = torch.ones(self.arm.num_targets, device=task.device)
            speed[-1] = self.gripper_speed
            self.target_step = speed * scale * task.control_dt

    def action_count(self) -> int | None:
        """The actions this control takes, when they are not the model's actuators (None: one per actuator)."""
        return None

    def check_action_size(self, task) -> None:
        """``env.numActions`` fits this control (VecTask.check_action_size, at construction, before ``bind``)."""
        wanted = self.action_count()
        if wanted is None:
            check_actuator_count(type(task).__name__, task.num_actions, task.sim)
        elif task.num_actions != wanted:
            raise ConfigError(f"{type(task).__name__}: task.env.numActions={task.num_actions} is invalid with "
                              f"controlType={self.kind}: give {wanted} (6 pose-error components and the gripper, "
                              "IGE's)")

    def apply(self, actions: torch.Tensor) -> None:
        if self.target_step is None:
            self.arm.move_targets(joint_pos_targets_delta(actions, self.arm, self.arm_step))
        else:
            self.arm.move_targets(actions * self.target_step)

    def observation_terms(self, scaled: bool = False) -> list[ObsTerm]:
        """The arm's joints (IsaacGymEnvs' joint_tor observation): all 9 positions (rad; fingers m), or with
        ``scaled`` each mapped from its range to [-1, 1] (IGE's FrankaCabinet)."""
        if scaled:
            return [ObsTerm("dof_pos", 9, compute=self.arm.scaled_dof_pos)]
        return [ObsTerm("dof_pos", 9, compute=lambda: self.sim.dof_pos)]

    def on_reset(self, mask: torch.Tensor) -> None:
        """After the arm's reset: the servo targets already sit at the new joint positions."""


class JointTorqueControl(JointPositionControl):
    """Actions are arm torques as fractions of the joints' limits, and the gripper."""

    kind = "joint_tor"

    def prepare(self, env: dict) -> None:
        # The MJCF's arm servos become torque motors (same names and ctrl columns, force capped at 87 / 12 N m).
        control = env.setdefault("control", {})
        control["driveMode"] = {**dict(control.get("driveMode") or {}), "joint[1-7]": "effort"}

    def apply(self, actions: torch.Tensor) -> None:
        self.sim.ctrl[:, :7] = actions[:, :7] * self.torque_limit
        self.sim.ctrl[:, 7] = gripper_command(actions[:, -1])

    def on_reset(self, mask: torch.Tensor) -> None:
        # the arm's ctrl columns are torques: none in a new episode
        self.sim.ctrl[:, :7].masked_fill_(mask.unsqueeze(1), 0.0)


class OperationalSpaceControl(JointTorqueControl):
    """IsaacGymEnvs' 7 actions (a pose error of the grasp frame and the gripper) through its OSC law; observes the
    fingers only."""

    kind = "osc"

    def bind(self, task) -> None:
        super().bind(task)
        env = task.cfg["env"]
        limit = [float(v) for v in env.get("oscCommandLimit", ())]
        if len(limit) != 6 or min(limit) <= 0:
            raise ConfigError(f"env.oscCommandLimit={env.get('oscCommandLimit')!r} is invalid: give 6 numbers > 0 "
                              "(the largest commanded pose error along x, y, z (m) and about them (rad))")
        self.command_limit = torch.tensor(limit, device=task.device)
        self.kp, self.kp_null = float(env["oscKp"]), float(env["oscKpNull"])
        self.dynamics = SiteDynamics(task.sim, task.arm.grasp_site, range(7))

    def action_count(self) -> int | None:
        return 7

    def apply(self, actions: torch.Tensor) -> None:
        # the torques for this step's pose error, held over the step's physics substeps (as IGE)
        q, qd = self.sim.dof_pos[:, :7], self.sim.dof_vel[:, :7]
        torques = osc_torques(actions[:, :6] * self.command_limit, q, qd, self.task.start_dof_pos[:7],
                              self.dynamics.mass_matrix(), self.dynamics.jacobian(), self.kp, self.kp_null)
        # A singular pose can make the unchecked inverses NaN: that world gets no arm torque for this step (a NaN
        # command would reach the learner through the next state; rare, about once in a thousand iterations).
        torques = torch.nan_to_num(torques, nan=0.0)
        self.sim.ctrl[:, :7] = torch.clamp(torques, -self.torque_limit, self.torque_limit)
        self.sim.ctrl[:, 7] = gripper_command(actions[:, -1])

    def observation_terms(self, scaled: bool = False) -> list[ObsTerm]:
        # IGE's osc observation: the fingers only (m)
        return [ObsTerm("finger_pos", 2, compute=lambda: self.sim.dof_pos[:, 7:9])]


CONTROLS = {c.kind: c for c in (JointPositionControl, JointTorqueControl, OperationalSpaceControl)}


def arm_control(env: dict, task: str, kinds: tuple[str, ...] = CONTROL_TYPES,
                gripper_speed: float | None = None) -> JointPositionControl:
    """The control ``env.controlType`` names (default joint_pos), one of the ``kinds`` that ``task`` supports,
    prepared on the task YAML; ``gripper_speed`` configures joint_pos's gripper (JointPositionControl)."""
    value = env.get("controlType", "joint_pos")
    if len(kinds) == 1 and value != kinds[0]:
        raise ConfigError(f"env.controlType={value!r} is invalid: {task} supports only {kinds[0]!r}")
    kind = one_of(value, "env.controlType", kinds)
    if gripper_speed is not None and kind != "joint_pos":
        raise ConfigError(f"env.controlType={kind!r} is invalid: {task} moves its gripper target as a joint, "
                          "which only 'joint_pos' does")
    control = CONTROLS[kind](gripper_speed)
    control.prepare(env)
    return control


def osc_torques(pose_error: torch.Tensor, q: torch.Tensor, qd: torch.Tensor, q_rest: torch.Tensor,
                mass: torch.Tensor, jacobian: torch.Tensor, kp: float, kp_null: float) -> torch.Tensor:
    """IsaacGymEnvs' operational-space control law: arm torques (N, k) that pull the end effector by ``pose_error``
    (N, 6) with stiffness ``kp`` and critical damping, plus a null-space pull toward ``q_rest``.

    tau = J^T Lambda (kp e - kd J qd) + (I - J^T Jbar^T) M (kp_null (q_rest - q) - kd_null qd), Lambda = (J M^-1
    J^T)^-1, Jbar^T = Lambda J M^-1, kd = 2 sqrt(kp). Inverses without error checks (``inv_ex``): a check would wait
    on the GPU; a singular arm pose gives large, clamped torques for that step, not a stall.
    """
    kd, kd_null = 2.0 * math.sqrt(kp), 2.0 * math.sqrt(kp_null)
    mass_inv = torch.linalg.inv_ex(mass)[0]
    jt = jacobian.transpose(1, 2)
    task_inertia = torch.linalg.inv_ex(jacobian @ mass_inv @ jt)[0]  # (N, 6, 6)
    eef_vel = (jacobian @ qd.unsqueeze(-1)).squeeze(-1)
    force = (kp * pose_error - kd * eef_vel).unsqueeze(-1)
    torque = jt @ (task_inertia @ force)
    # The pull toward the rest pose (wrapped to (-pi, pi]), in the null space of the task: it does not move the hand.
    rest = kp_null * wrap_to_pi(q_rest - q) - kd_null * qd
    jbar_t = task_inertia @ jacobian @ mass_inv  # (N, 6, k)
    eye = torch.eye(q.shape[1], device=q.device, dtype=q.dtype).expand_as(mass)
    torque = torque + (eye - jt @ jbar_t) @ (mass @ rest.unsqueeze(-1))
    return torque.squeeze(-1)
