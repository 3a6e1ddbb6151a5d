"""Quadcopter: fly a four-rotor craft to the point 1 m above its origin and hover there (IsaacGymEnvs' task).

IsaacGymEnvs' ``Quadcopter`` (isaacgymenvs/tasks/quadcopter.py) with its observation, actions, reward, resets and
termination rule; the model is ``assets/mjcf/quadcopter.xml``, written from the figures IGE builds its MJCF from.

Actions (12, IGE's order): 0:8 move the position targets of the 8 rotor joints (``rotor_pitch<i>``,
``rotor_roll<i>``, in model order) at up to 8π rad/s, clamped to the joint ranges; 8:12 change the 4 rotor thrusts at
up to 200 N/s, clamped to [0, 2] N. Both are integrated over the policy step (IGE: ``x += dt * speed * action``), so
a policy holds a thrust by outputting 0.

Thrust: a force along each rotor body's own z axis, applied with ``apply_body_forces(frame="body")`` at the rotor's
centre of mass (its site ``rotor<i>_thrust``), which is IGE's ``apply_rigid_body_force_tensors(..., LOCAL_SPACE)``
on the rotor bodies, one to one. A MuJoCo site actuator would do the same, but its ``ctrl`` is the thrust itself,
while IGE's action is a rate of change of a thrust state the task keeps; with forces, the 12 actions keep IGE's
meaning and the model's actuators are only the 8 joint drives.
"""

from __future__ import annotations

import math
from typing import Callable

import torch

from isaacgymenvs_mw.tasks.base.env_keys import positive_env_number
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, OUTCOME, PER_STEP, Metric
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import quat_axis

ROTOR_BODIES = ["rotor0", "rotor1", "rotor2", "rotor3"]
TARGET = (0.0, 0.0, 1.0)            # IGE's fixed target point (m)
REACHED_DISTANCE = 0.1              # m: test mode's reached_target, the craft's centre within this of the target
MAX_THRUST = 2.0                    # N per rotor (IGE's max_thrust)
DOF_ACTION_SPEED_SCALE = 8 * math.pi  # rad/s at action 1 (IGE)
THRUST_ACTION_SPEED_SCALE = 200.0     # N/s at action 1 (IGE)
# PhysX, IGE's engine, clamps each rigid body's angular speed (PxRigidBody::setMaxAngularVelocity, 100 rad/s by
# default); MuJoCo does not, and a craft spun up by held full-thrust rotor tilts reached thousands of rad/s, where its
# rotor hinges diverged. The same cap, applied once per policy step (env.maxAngularVelocity).
MAX_ANGULAR_VELOCITY = 100.0          # rad/s
TARGET_DISTANCE = Metric("target_distance", PER_STEP)  # test mode: m from the target, each step
# The task's success, an episode that ends with the craft within REACHED_DISTANCE of the target: in training the rate
# over ended episodes (Episode/reached_target, what save_best follows), in test mode each env's first episode's.
REACHED_TARGET_RATE = Metric("reached_target", EPISODE_SUM, success=True)
REACHED_TARGET = Metric("reached_target", OUTCOME, success=True)


class Quadcopter(VecTask):
    """Observation (21): target offset / 3, root quaternion (w, x, y, z), linear velocity / 2, angular velocity / π
    (world frame), the 8 rotor joint angles. Actions (12): 8 joint target rates, 4 thrust rates."""

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        self.rotor_bodies = list(env.get("rotorBodies", ROTOR_BODIES))
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        check_rotor_bodies(self.rotor_bodies, 4, self.sim.body_names, env)
        n, dev = self.num_envs, self.device
        self.dof_lower_limits, self.dof_upper_limits = self.sim.joint_limits()
        self.dof_position_targets = torch.zeros((n, 8), device=dev)
        self.thrusts = torch.zeros((n, 4), device=dev)
        self.forces = torch.zeros((n, 4, 3), device=dev)
        self.fresh = torch.ones(n, dtype=torch.bool, device=dev)  # first step of an episode: IGE applies no action
        self.max_angular_velocity = positive_env_number(env, "maxAngularVelocity", MAX_ANGULAR_VELOCITY)
        self.target = torch.tensor(TARGET, device=dev)
        self.initial_root_pos = self.sim.root_pos[0].clone()
        self.initial_root_quat = self.sim.root_quat[0].clone()
        # Zero thrusts now: the simulator's force buffer exists before the step is compiled, so the compiled step
        # does not meet a new model at the first step and compile again.
        self.apply_body_forces(self.forces, bodies=self.rotor_bodies, frame="body")
        self.build_observation_layouts()

    def check_action_size(self) -> None:
        # 12 actions for 8 joint drives: the 4 thrusts are forces (module docstring), not actuators.
        if self.num_actions != 12 or self.sim.num_actuators != 8 or len(self.sim.dof_names) != 8:
            raise ConfigError(
                f"Quadcopter: env.numActions={self.num_actions} is invalid: give 12 (8 rotor joint targets, 4 thrusts), "
                f"with a position drive on each of the 8 rotor joints (the model has {self.sim.num_actuators} "
                f"actuators on {len(self.sim.dof_names)} joints)")

    def pre_physics_step(self, actions: torch.Tensor) -> None:
        dt = self.control_dt
        targets = self.dof_position_targets + dt * DOF_ACTION_SPEED_SCALE * actions[:, 0:8]
        targets = torch.minimum(torch.maximum(targets, self.dof_lower_limits), self.dof_upper_limits)
        thrusts = (self.thrusts + dt * THRUST_ACTION_SPEED_SCALE * actions[:, 8:12]).clamp(0.0, MAX_THRUST)
        fresh = self.fresh.view(-1, 1)
        self.dof_position_targets.copy_(torch.where(fresh, self.sim.dof_pos, targets))
        self.thrusts.copy_(torch.where(fresh, torch.zeros_like(thrusts), thrusts))
        self.fresh.zero_()
        self.forces[:, :, 2] = self.thrusts
        spin = self.sim.root_ang_vel  # a view of qvel: scaled in place, its direction kept
        speed = torch.linalg.norm(spin, dim=1, keepdim=True).clamp(min=1e-9)
        spin.mul_((self.max_angular_velocity / speed).clamp(max=1.0))
        self.sim.ctrl[:, :8] = self.dof_position_targets
        self.apply_body_forces(self.forces, bodies=self.rotor_bodies, frame="body")

    def check_termination(self) -> torch.Tensor:
        return quadcopter_failed(self.sim.root_pos, self.target)

    def declared_metrics(self) -> list[Metric]:
        return [*super().declared_metrics(), REACHED_TARGET_RATE, TARGET_DISTANCE, REACHED_TARGET]

    def compute_reward(self) -> None:
        self.rew_buf[:] = compute_quadcopter_reward(self.sim.root_pos, self.sim.root_quat,
                                                    self.sim.root_ang_vel_world(), self.target)
        if self.metrics.evaluating:  # test mode: how far from the target it flies, step by step (eval.json)
            self.metrics.record(TARGET_DISTANCE, torch.linalg.norm(self.sim.root_pos - self.target, dim=-1))

    def observation_terms(self) -> list[ObsTerm]:
        return [*flight_terms(self.sim, lambda: self.target),
                ObsTerm("dof_pos", 8, compute=lambda: self.sim.dof_pos)]                 # rad

    def reset_idx(self, mask: torch.Tensor) -> None:
        n, dev = self.num_envs, self.device
        # Whether each ending episode ended at its target. IGE's own rule only fails a craft beyond 3 m or below
        # 0.3 m, so this criterion is ours: within REACHED_DISTANCE.
        final = torch.linalg.norm(self.sim.root_pos - self.target, dim=-1)
        reached = (mask & (final < REACHED_DISTANCE)).float()
        self.metrics.record(REACHED_TARGET_RATE, reached.sum())
        if self.metrics.evaluating:  # test mode: eval.json reached_target
            self.metrics.record(REACHED_TARGET, reached)
        self.sim.reset_worlds(mask)
        pos = self.initial_root_pos.expand(n, 3).clone()
        pos[:, 0:2] += 3.0 * torch.rand((n, 2), device=dev) - 1.5          # IGE: x, y += U(-1.5, 1.5)
        pos[:, 2] += 1.7 * torch.rand(n, device=dev) - 0.2                 # IGE: z += U(-0.2, 1.5)
        dof_pos = 0.4 * torch.rand((n, 8), device=dev) - 0.2               # IGE: U(-0.2, 0.2) rad
        self.sim.write_state(mask, dof_pos=dof_pos, dof_vel=torch.zeros_like(dof_pos), root_pos=pos,
                             root_quat=self.initial_root_quat.expand(n, 4),
                             root_lin_vel=torch.zeros((n, 3), device=dev), root_ang_vel=torch.zeros((n, 3), device=dev))
        self.fresh |= mask
        self.thrusts.masked_fill_(mask.view(-1, 1), 0.0)


def quadcopter_failed(root_pos: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """IGE's rule: more than 3 m from the target, or the body below 0.3 m."""
    return (torch.linalg.norm(root_pos - target, dim=-1) > 3.0) | (root_pos[:, 2] < 0.3)


def compute_quadcopter_reward(root_pos: torch.Tensor, root_quat: torch.Tensor, root_ang_vel: torch.Tensor,
                              target: torch.Tensor) -> torch.Tensor:
    """IGE's reward p + p (u + s): p = 1 / (1 + d²) with d the distance to the target, u = 1 / (1 + (1 - z_up)²) with
    z_up the z component of the body's z axis, s = 1 / (1 + ω_z²) with ω_z the world-frame yaw rate.
    ``root_quat`` is (w, x, y, z)."""
    dist = torch.linalg.norm(root_pos - target, dim=-1)
    pos_reward = 1.0 / (1.0 + dist * dist)
    tilt = torch.abs(1.0 - quat_axis(root_quat, 2)[:, 2])
    up_reward = 1.0 / (1.0 + tilt * tilt)
    spin = torch.abs(root_ang_vel[:, 2])
    spin_reward = 1.0 / (1.0 + spin * spin)
    return pos_reward + pos_reward * (up_reward + spin_reward)


def check_rotor_bodies(bodies: list[str], count: int, body_names: list[str], env: dict) -> None:
    """``env.rotorBodies``: the ``count`` bodies of the asset that the thrusts push (a flying task's), else one line
    naming them and the model's bodies."""
    missing = [b for b in bodies if b not in body_names]
    if len(bodies) != count or missing:
        raise ConfigError(
            f"env.rotorBodies={bodies} is invalid: give the {count} rotor bodies of the asset "
            f"({env['asset']['assetFileName']}); not in the model: {missing}; its bodies: {body_names[1:]}")


def flight_terms(sim, target: Callable[[], torch.Tensor]) -> list[ObsTerm]:
    """IsaacGymEnvs' flying tasks' observation: the offset to ``target()`` / 3, the root quaternion, and the world-frame
    linear velocity / 2 and angular velocity / pi of the root body."""
    return [ObsTerm("target_offset", 3, scale=1.0 / 3.0, compute=lambda: target() - sim.root_pos),  # m
            ObsTerm("root_quat", 4, compute=lambda: sim.root_quat),                   # (w, x, y, z)
            ObsTerm("root_lin_vel", 3, scale=0.5, compute=lambda: sim.root_lin_vel),  # m/s, world frame
            ObsTerm("root_ang_vel", 3, scale=1.0 / math.pi, compute=sim.root_ang_vel_world)]  # rad/s, world
