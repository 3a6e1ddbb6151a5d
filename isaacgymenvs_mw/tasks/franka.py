"""The Franka family (FrankaCabinet, FrankaCubeStack, FrankaCubeLift and its camera variants): the Panda's joints,
servo targets and hand frames in a batch of worlds, and what the cube tasks share.

The arm is the scene's main asset (``env.asset``: ``assets/mjcf/franka_panda.xml`` or a model with the same joint,
actuator, body and site names): 7 arm joints and two coupled finger slides, 8 position servos (7 joints and the
gripper, whose command is each finger's opening in metres, 0 ... 0.04), and the ``grasp`` site between the
fingertip pads. IsaacGymEnvs' Franka tasks have 9 DOFs and 9 actions, one per finger; here the fingers are coupled
by the model, so the gripper is one action and both finger positions stay in the observation.

``ArmKinematics`` is the hand's kinematics in torch, which poses the arm for starts with a cube in the hand.
The cube tasks share the scene's dimensions, the gripper command, the arm's start-pose draw, and the reward
quantities of the approach (IsaacGymEnvs' ``dist``) and of holding and raising cube A (this project's ``grasp`` /
``lift_height`` shaping). All positions are in the robot's base frame, the world frame of these scenes
(``assets/mjcf/table.xml``).
"""

from __future__ import annotations

import numpy as np
import torch

from isaacgymenvs_mw.sim import Simulator
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
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
        self.dof_lower, self.dof_upper = sim.joint_limits()  # (9,): the dofs are `expected`, checked above
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

    def close_gripper(self, mask: torch.Tensor) -> None:
        """Command the masked worlds' gripper closed (after ``reset``: a start with a cube in the hand)."""
        self.targets[:, 7].masked_fill_(mask, CLOSED)
        self.ctrl[:, 7].masked_fill_(mask, CLOSED)

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


# ---------------------------------------------------------------- the cube tasks
CUBE_A_SIZE = 0.05  # edge length of cube A (m), assets/mjcf/cube_5cm.xml
TABLE_TOP = -0.1  # table surface height in the robot's base frame (m), assets/mjcf/table.xml
TABLE_CENTRE_XY = (0.45, 0.0)
FINGERTIP = 0.0441  # fingertip point: this far along the grasp frame's approach axis from a finger's origin (m), IGE
OPEN, CLOSED = 0.04, 0.0  # gripper commands: each finger's opening (m)
# FrankaCubeStack's "lifted" (IGE: A's centre 0.09 m above the table): a rise of 0.065 m from where A rests
STACK_LIFT_RISE = CUBE_A_SIZE + 0.04 - CUBE_A_SIZE / 2.0


def gripper_command(action: torch.Tensor) -> torch.Tensor:
    """Each finger's opening (N,) for the gripper action (N,): >= 0 opens (OPEN), < 0 closes (CLOSED), as IGE."""
    return torch.where(action >= 0.0, OPEN, CLOSED)


def joint_pos_targets_delta(actions: torch.Tensor, arm: FrankaArm, arm_step: float) -> torch.Tensor:
    """joint_pos control: the change (N, 8) of the servo targets, the 7 arm joints by ``arm_step`` x action (rad),
    the gripper straight to its commanded opening."""
    grip = gripper_command(actions[:, 7])
    return torch.cat((actions[:, :7] * arm_step, (grip - arm.targets[:, 7]).unsqueeze(1)), dim=1)


def noisy_start_pose(start: torch.Tensor, noise: float, arm: FrankaArm, n: int) -> torch.Tensor:
    """(n, 9) reset joint positions, IGE's: each arm joint ``start`` + ``noise`` x U(-1, 1), clamped to its range;
    the fingers stay at ``start``."""
    offset = torch.zeros((n, 9), device=start.device)
    offset[:, :7] = noise * (2.0 * torch.rand((n, 7), device=start.device) - 1.0)
    return torch.clamp(start + offset, arm.dof_lower, arm.dof_upper)


def fingertips(arm: FrankaArm) -> tuple[torch.Tensor, torch.Tensor]:
    """World positions (N, 3) of the left and right fingertip points (IGE's fingertip links): FINGERTIP out along
    the approach axis from each finger's pad face."""
    approach = arm.grasp_axes()[:, :, 2]
    left, right = arm.finger_pos()
    return left + FINGERTIP * approach, right + FINGERTIP * approach


def approach_term(cube: torch.Tensor, grasp: torch.Tensor, tip_left: torch.Tensor,
                  tip_right: torch.Tensor) -> torch.Tensor:
    """IsaacGymEnvs' ``dist`` quantity: 1 - tanh(10 x the mean distance of the cube's centre to the grasp point and
    the two fingertips), (N,)."""
    d = torch.linalg.norm(cube - grasp, dim=-1)
    d_left = torch.linalg.norm(cube - tip_left, dim=-1)
    d_right = torch.linalg.norm(cube - tip_right, dim=-1)
    return 1.0 - torch.tanh(10.0 * (d + d_left + d_right) / 3.0)


def grasp_terms(cube_a: torch.Tensor, grasp: torch.Tensor, finger_opening: torch.Tensor,
                table_top: float = TABLE_TOP, full_rise: float = STACK_LIFT_RISE) -> dict[str, torch.Tensor]:
    """This project's shaping quantities: ``held`` (float 0/1: A's centre within 3 cm of the grasp point and each
    finger opened less than 3 cm, i.e. closed on A's 2.5 cm half-width) and ``lift_height`` (while held, A's centre
    above its resting height as a fraction of ``full_rise`` (m; FrankaCubeStack: the 6.5 cm rise that makes it
    ``lifted``), clamped to 0 ... 1)."""
    held = ((torch.linalg.norm(cube_a - grasp, dim=-1) < 0.03) & (finger_opening < 0.03)).float()
    rise = (cube_a[:, 2] - table_top - CUBE_A_SIZE / 2.0) / full_rise
    return {"held": held, "lift_height": held * torch.clamp(rise, 0.0, 1.0)}


def privileged_terms(arm: FrankaArm, cubes: dict, observed: list[ObsTerm] = ()) -> list[ObsTerm]:
    """What an asymmetric critic reads besides the policy's observation (``env.asymmetric_observations``), 9 + 6 per
    cube + 7 values: what the simulator knows and a policy must infer: the joint speeds, each cube's velocities, the
    fingertips relative to cube A and whether A is held (the grasp the reward shapes). ``cubes``: name -> asset view,
    cube A first; a term named as one of ``observed`` (the policy's, which the critic reads too) is left out."""
    cube_a = next(iter(cubes.values()))

    def tips_to_cube() -> torch.Tensor:
        left, right = fingertips(arm)
        return torch.cat((left - cube_a.root_pos, right - cube_a.root_pos), dim=1)

    terms = [ObsTerm("dof_vel", 9, scale=0.1, compute=lambda: arm.sim.dof_vel)]          # rad/s; fingers m/s
    for name, cube in cubes.items():
        terms += [ObsTerm(f"{name}_lin_vel", 3, compute=lambda c=cube: c.root_lin_vel),  # m/s, world frame
                  ObsTerm(f"{name}_ang_vel", 3, compute=lambda c=cube: c.root_ang_vel)]  # rad/s, cube frame
    terms += [ObsTerm("fingertips_to_cube", 6, compute=tips_to_cube),                     # m, left and right tip - A
              ObsTerm("held", 1, compute=lambda: grasp_terms(cube_a.root_pos, arm.grasp_pos(),
                                                             arm.sim.dof_pos[:, 7])["held"].unsqueeze(1))]  # 0 / 1
    seen = {term.name for term in observed}
    return [term for term in terms if term.name not in seen]



# ---------------------------------------------------------------- kinematics of the hand, for starts with a cube held
class ArmKinematics:
    """The pose and Jacobian of a site on the arm as functions of the 7 arm joints, batched in torch, from the
    model's body tree: MuJoCo's forward kinematics for hinge joints (a body's frame is its parent's moved by
    ``body_pos`` / ``body_quat``, then turned about each joint's axis through its anchor by qpos - qpos0).

    Args:
        sim: the built Simulator, the Panda its main asset.
        site: the site's model index (``sim.site_id``).
    """

    def __init__(self, sim: Simulator, site: int) -> None:
        m = sim.mj_model
        f64 = {"dtype": torch.float64, "device": sim.device}
        chain, b = [], int(m.site_bodyid[site])
        while b > 0:
            chain.append(b)
            b = int(m.body_parentid[b])
        self.bodies = []  # per body of the chain, root first: position, rotation, [(column of q, anchor, axis, ref)]
        arm_qpos = [int(m.jnt_qposadr[m.joint(name).id]) for name in ARM_JOINTS]
        for body in reversed(chain):
            joints = []
            for j in np.flatnonzero(m.jnt_bodyid == body):
                if m.jnt_type[j] != 3 or int(m.jnt_qposadr[j]) not in arm_qpos:  # 3: mjJNT_HINGE
                    raise ConfigError(f"ArmKinematics: joint {m.joint(j).name!r} on the way to the site is not an "
                                      f"arm joint {list(ARM_JOINTS)}")
                adr = int(m.jnt_qposadr[j])
                joints.append((arm_qpos.index(adr), torch.tensor(m.jnt_pos[j], **f64),
                               torch.tensor(m.jnt_axis[j], **f64), float(m.qpos0[adr])))
            self.bodies.append((torch.tensor(m.body_pos[body], **f64), _quat_matrix(m.body_quat[body], f64), joints))
        self.site_pos, self.site_rot = torch.tensor(m.site_pos[site], **f64), _quat_matrix(m.site_quat[site], f64)

    def forward(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """For arm joints ``q`` (K, 7): the site's world position (K, 3), rotation (K, 3, 3; axes as columns) and
        Jacobian (K, 6, 7; rows 0-2 linear, 3-5 angular velocity per joint velocity), float64."""
        q = q.double()
        k = q.shape[0]
        pos = torch.zeros((k, 3), dtype=q.dtype, device=q.device)
        rot = torch.eye(3, dtype=q.dtype, device=q.device).expand(k, 3, 3)
        anchors, axes = [None] * 7, [None] * 7
        for body_pos, body_rot, joints in self.bodies:
            pos = pos + rot @ body_pos
            rot = rot @ body_rot
            for column, joint_pos, axis, ref in joints:
                anchors[column] = pos + rot @ joint_pos
                axes[column] = rot @ axis
                rot = rot @ _axis_angle_matrix(axis, q[:, column] - ref)
                pos = anchors[column] - rot @ joint_pos
        site = pos + rot @ self.site_pos
        anchor, axis = torch.stack(anchors, dim=2), torch.stack(axes, dim=2)  # (K, 3, 7)
        linear = torch.linalg.cross(axis, site.unsqueeze(2) - anchor, dim=1)
        return site, rot @ self.site_rot, torch.cat((linear, axis), dim=1)

    def solve(self, target_pos: torch.Tensor, target_rot: torch.Tensor, q_start: torch.Tensor, lower: torch.Tensor,
              upper: torch.Tensor, iterations: int = 200, damping: float = 1e-4) -> tuple[torch.Tensor, torch.Tensor]:
        """Damped least squares: arm joints (K, 7) within [``lower``, ``upper``] that put the site at ``target_pos``
        (K, 3) with rotation ``target_rot`` (K, 3, 3), starting from ``q_start`` (7,); and the remaining pose error
        (K,; m and rad together)."""
        q = q_start.double().expand(target_pos.shape[0], 7).clone()
        target_pos, target_rot = target_pos.double(), target_rot.double()
        eye = damping * torch.eye(6, dtype=q.dtype, device=q.device)
        for _ in range(iterations):
            error, jac = self._pose_error(q, target_pos, target_rot)
            step = jac.transpose(1, 2) @ torch.linalg.solve(jac @ jac.transpose(1, 2) + eye, error.unsqueeze(2))
            q = torch.clamp(q + step.squeeze(2), lower.double(), upper.double())
        return q, torch.linalg.norm(self._pose_error(q, target_pos, target_rot)[0], dim=1)

    def _pose_error(self, q: torch.Tensor, target_pos: torch.Tensor,
                    target_rot: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(K, 6) the position still to go and the rotation still to go (half the skew part of R_target R^T), and
        the Jacobian (K, 6, 7) at ``q``."""
        pos, rot, jac = self.forward(q)
        r = target_rot @ rot.transpose(1, 2)
        turn = 0.5 * torch.stack((r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]), dim=1)
        return torch.cat((target_pos - pos, turn), dim=1), jac


def _quat_matrix(quat: np.ndarray, f64: dict) -> torch.Tensor:
    """The rotation matrix of a (w, x, y, z) unit quaternion."""
    w, x, y, z = (float(v) for v in quat / np.linalg.norm(quat))
    return torch.tensor([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                         [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                         [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]], **f64)


def _axis_angle_matrix(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """(K, 3, 3) rotations by ``angle`` (K,) about the unit ``axis`` (3,) (Rodrigues)."""
    x, y, z = axis / torch.linalg.norm(axis)
    zero = torch.zeros((), dtype=axis.dtype, device=axis.device)
    skew = torch.stack((torch.stack((zero, -z, y)), torch.stack((z, zero, -x)), torch.stack((-y, x, zero))))
    s, c = torch.sin(angle).view(-1, 1, 1), torch.cos(angle).view(-1, 1, 1)
    return torch.eye(3, dtype=axis.dtype, device=axis.device) + s * skew + (1.0 - c) * (skew @ skew)
