"""Run toward a target far along +x: IsaacGymEnvs' Ant and Humanoid, on MJCF robots that bring their own motors.

The robot starts upright at the origin; a target sits ``env.target`` away (1000 m along x by default), so the
episode is about running as fast as possible in that direction without falling. The reward is IsaacGymEnvs':
progress (the drop in the horizontal distance to the target over the step, divided by the policy dt: the speed
toward the target in m/s) + staying alive + being upright + heading toward the target, minus action, energy and
joints-at-limit costs; the step on which the torso drops below ``terminationHeight`` earns ``deathCost`` instead
and ends the episode.

The policy's action i is the command of the MJCF's actuator i (a motor: joint torque = gear × action ×
``powerScale``); every movable joint must be driven by exactly one of them. The foot forces come from contact
sensors that the MJCF declares (force and torque, net over each foot's contacts: 6 values per foot).

Where this differs from IsaacGymEnvs, on purpose:
  * hooks run reward -> reset -> observe (IsaacGymEnvs: reset -> observe -> reward), so the reward of a step is
    computed from the state that step produced, and the first observation of a new episode is its reset state;
  * yaw, roll and the angle to the target are wrapped to (-π, π] (IsaacGymEnvs' Ant leaves yaw and roll in [0, 2π),
    a jump of 2π when the torso turns through the x axis), and the angle to the target is measured in the ground
    plane (IsaacGymEnvs computes it from the x and z offsets, which makes it minus the yaw);
  * the joints-at-limit count of the Ant uses |scaled position| (IsaacGymEnvs counts only the upper limit);
  * the joint forces observed by the Humanoid are the actuator torques (MuJoCo ``qfrc_actuator``).
"""

from __future__ import annotations

import torch

from isaacgymenvs_mw.tasks.base.metrics import PER_STEP, Metric
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.rewards import RewardTerms, reward_methods
from isaacgymenvs_mw.tasks.base.env_keys import refuse_reward_scale
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import quat_rotate, quat_rotate_inverse, wrap_to_pi, yaw_from_quat

# env keys every locomotion task YAML sets (IsaacGymEnvs' names where it has them).
_SCALAR_KEYS = (
    "powerScale", "headingWeight", "upWeight", "aliveReward", "actionsCost", "energyCost", "jointsAtLimitCost",
    "deathCost", "terminationHeight", "dofVelocityScale", "angularVelocityScale", "contactForceScale",
    "upThreshold", "headingThreshold", "jointsAtLimitThreshold", "resetDofPosNoise",
    "resetDofVelNoise",
)
FORWARD_SPEED = Metric("forward_speed", PER_STEP)  # test mode: the torso's speed along +x (m/s), each step


class LocomotionTask(VecTask):
    """IsaacGymEnvs' locomotion tasks (Ant, Humanoid): the shared observation, reward, termination and reset."""

    # Humanoid: also observe each joint's actuator torque (IsaacGymEnvs' dof force sensors).
    observe_dof_forces = False
    # Sensor values per foot in the observation (force and torque).
    FOOT_SENSOR_DIM = 6

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        missing = [k for k in _SCALAR_KEYS + ("target", "footContactSensors") if k not in env]
        if missing:
            raise ConfigError(f"{type(self).__name__}: the task YAML's env section lacks {missing}")
        refuse_reward_scale(type(self).__name__, env)
        self.env_numbers = {key: float(env[key]) for key in _SCALAR_KEYS}
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        self._init_joints()
        self._init_foot_sensors(env["footContactSensors"])
        self._init_buffers(env)
        self.build_observation_layouts()

    # ------------------------------------------------------------------ model
    def _init_joints(self) -> None:
        """Actuator i drives one joint; limits, motor strengths and the reset pose per joint."""
        sim, name = self.sim, type(self).__name__
        if not sim.floating_base:
            raise ConfigError(f"{name}: the robot needs a floating base: set env.asset.fixBaseLink: False")
        dofs, joints = sim.dof_names, sim.actuator_joints
        not_motors = [a for a, j in zip(sim.actuator_names, joints) if j is None]
        if not_motors:
            raise ConfigError(f"{name}: actuators {not_motors} do not drive a joint; each action is one joint's motor")
        undriven = [d for d in dofs if d not in joints]
        twice = sorted({j for j in joints if joints.count(j) > 1})
        if undriven or twice:
            raise ConfigError(
                f"{name}: every joint needs exactly one motor in the asset's <actuator> section; joints without one: "
                f"{undriven}, joints with several: {twice} (actuator -> joint: "
                f"{dict(zip(sim.actuator_names, joints))})"
            )
        m, dev = sim.mj_model, self.device
        joint_ids = [m.joint(d).id for d in dofs]
        unlimited = [d for d, j in zip(dofs, joint_ids) if not m.jnt_limited[j]]
        if unlimited:
            raise ConfigError(f"{name}: joints {unlimited} have no range; the observation scales joint positions "
                             "to [-1, 1] by their limits, so give each joint a range in the MJCF")
        self.dof_lower, self.dof_upper = self.sim.joint_limits()
        # Actuator i's joint, as a column of dof_pos / dof_vel.
        self.actuated_dof = torch.tensor([dofs.index(j) for j in joints], device=dev, dtype=torch.long)
        gear = torch.tensor(m.actuator_gear[:, 0], device=dev, dtype=torch.float)
        # IsaacGymEnvs weighs the energy and joint-limit costs by each motor's share of the strongest one.
        self.motor_effort_ratio = gear / gear.abs().max()
        self.dof_effort_ratio = torch.zeros_like(self.dof_lower).scatter(0, self.actuated_dof, self.motor_effort_ratio)
        # Reset pose: zero, or the nearest limit where zero is outside the range (the Ant's feet).
        self.initial_dof_pos = torch.clamp(torch.zeros_like(self.dof_lower), self.dof_lower, self.dof_upper)

    def _init_foot_sensors(self, sensors: list[str]) -> None:
        self._foot_sensors = []  # each foot's (N, 6) force and torque sensor
        for sensor in sensors:
            view = self.sim.sensor(sensor, key="env.footContactSensors")
            if view.shape[1] != self.FOOT_SENSOR_DIM:
                raise ConfigError(f"env.footContactSensors: sensor '{sensor}' gives {view.shape[1]} values, the task "
                                 f"reads {self.FOOT_SENSOR_DIM} (force and torque: data=\"force torque\")")
            self._foot_sensors.append(view)
        self.num_feet = len(sensors)

    def _init_buffers(self, env: dict) -> None:
        n, dev = self.num_envs, self.device
        target = [float(v) for v in env["target"]]
        if len(target) != 3:
            raise ConfigError(f"env.target={target} is invalid: give [x, y, z] (m)")
        self.targets = torch.tensor(target, device=dev).repeat(n, 1)
        qpos0 = torch.tensor(self.sim.mj_model.qpos0[:7], device=dev, dtype=torch.float)
        self.start_pos, self.start_quat = qpos0[:3], qpos0[3:7]  # env.baseInitState, compiled into the model
        self.inv_start_quat = (self.start_quat * torch.tensor([1.0, -1.0, -1.0, -1.0], device=dev)).repeat(n, 1)
        self.basis_up = torch.tensor([0.0, 0.0, 1.0], device=dev).repeat(n, 1)
        self.basis_heading = torch.tensor([1.0, 0.0, 0.0], device=dev).repeat(n, 1)
        self.actions = torch.zeros(n, self.num_actions, device=dev)
        # Where each torso was at the previous step (ground plane), and its speed toward the target since then.
        self.prev_xy = self.start_pos[:2].repeat(n, 1)
        self.progress_speed = torch.zeros(n, device=dev)
        # Torso state in the frame of its start orientation, refreshed after each physics step and each reset.
        self.torso_quat = torch.zeros(n, 4, device=dev)
        self.vel_loc = torch.zeros(n, 3, device=dev)
        self.angvel_loc = torch.zeros(n, 3, device=dev)
        self.up_proj = torch.zeros(n, device=dev)
        self.heading_proj = torch.zeros(n, device=dev)
        self.yaw = torch.zeros(n, device=dev)
        self.roll = torch.zeros(n, device=dev)
        self.angle_to_target = torch.zeros(n, device=dev)
        # Every _reward_ method is a term, its weight and sign inside it (IsaacGymEnvs' constants).
        self.rewards = RewardTerms(self, dict.fromkeys(reward_methods(self), 1.0), n, dev)

    # ------------------------------------------------------------ observation
    def observation_terms(self) -> list[ObsTerm]:
        numbers, n, sim = self.env_numbers, self.num_actions, self.sim
        terms = [
            ObsTerm("torso_height", 1, compute=lambda: sim.root_pos[:, 2:3]),                         # m
            ObsTerm("lin_vel", 3, compute=lambda: self.vel_loc),                                      # torso frame, m/s
            ObsTerm("ang_vel", 3, numbers["angularVelocityScale"], compute=lambda: self.angvel_loc),        # rad/s
            ObsTerm("yaw", 1, compute=lambda: self.yaw.unsqueeze(1)),                                 # rad, (-π, π]
            ObsTerm("roll", 1, compute=lambda: self.roll.unsqueeze(1)),                               # rad, (-π, π]
            # rad: heading error in the ground plane
            ObsTerm("angle_to_target", 1, compute=lambda: self.angle_to_target.unsqueeze(1)),
            ObsTerm("up_proj", 1, compute=lambda: self.up_proj.unsqueeze(1)),            # torso z axis · world up
            ObsTerm("heading_proj", 1, compute=lambda: self.heading_proj.unsqueeze(1)),  # torso x axis · to target
            ObsTerm("dof_pos_scaled", n, compute=self.dof_pos_scaled),                   # limits -> ±1
            ObsTerm("dof_vel", n, numbers["dofVelocityScale"], compute=lambda: sim.dof_vel),   # rad/s
        ]
        if self.observe_dof_forces:
            # Actuator torque per joint (N m); a reset keeps the previous step's forces until the next physics
            # step: show none instead.
            terms.append(ObsTerm("dof_force", n, numbers["contactForceScale"],
                                 compute=lambda: sim.qfrc_actuator[:, 6:] * (self.progress_buf > 0).unsqueeze(1)))
        terms += [
            ObsTerm("foot_forces", self.FOOT_SENSOR_DIM * self.num_feet, numbers["contactForceScale"],  # N, N m
                    compute=lambda: torch.cat(self._foot_sensors, dim=1)),
            ObsTerm("actions", n, compute=lambda: self.actions),                                  # last policy output
        ]
        return terms

    def dof_pos_scaled(self) -> torch.Tensor:
        """Joint positions mapped linearly from [lower, upper] to [-1, 1] (IsaacGymEnvs' ``unscale``)."""
        return (2.0 * self.sim.dof_pos - self.dof_upper - self.dof_lower) / (self.dof_upper - self.dof_lower)

    def _refresh_torso_state(self) -> None:
        """Torso orientation, velocities and heading relative to the target, from qpos / qvel."""
        sim = self.sim
        q = _quat_mul(sim.root_quat, self.inv_start_quat)
        self.torso_quat[:] = q
        to_target = self.targets - sim.root_pos
        to_target[:, 2] = 0.0
        up = quat_rotate(q, self.basis_up)
        heading = quat_rotate(q, self.basis_heading)
        self.up_proj[:] = up[:, 2]
        self.heading_proj[:] = torch.sum(heading * torch.nn.functional.normalize(to_target, dim=-1), dim=-1)
        self.vel_loc[:] = quat_rotate_inverse(q, sim.root_lin_vel)
        # MuJoCo gives the free joint's angular velocity in the body frame; IsaacGym in the world frame.
        self.angvel_loc[:] = quat_rotate_inverse(q, quat_rotate(sim.root_quat, sim.root_ang_vel))
        w, x, y, z = q.unbind(-1)
        self.roll[:] = torch.atan2(2.0 * (w * x + y * z), w * w - x * x - y * y + z * z)
        self.yaw[:] = yaw_from_quat(q)
        walk_angle = torch.atan2(to_target[:, 1], to_target[:, 0])
        self.angle_to_target[:] = wrap_to_pi(walk_angle - self.yaw)

    # --------------------------------------------------------------- stepping
    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.actions[:] = actions
        # The motors' gear turns a command into a torque; MuJoCo clamps the command to the actuator's ctrlrange.
        self.sim.ctrl[:] = actions * self.env_numbers["powerScale"]

    def declared_metrics(self) -> list[Metric]:
        return [*super().declared_metrics(), FORWARD_SPEED]

    def refresh_state(self) -> None:
        self._refresh_torso_state()
        self.progress_speed[:] = self._speed_toward_target()
        self.prev_xy[:] = self.sim.root_pos[:, :2]
        if self.metrics.evaluating:
            # Speed of the torso along +x (world frame, m/s), before any reset replaces the state.
            self.metrics.record(FORWARD_SPEED, self.sim.root_lin_vel[:, 0].clone())

    def _speed_toward_target(self) -> torch.Tensor:
        """The drop in horizontal distance to the target over the step, / policy dt (IsaacGymEnvs' potential
        difference). Written as (p - p_prev)·(a + b) / (|a| + |b|) with a, b the offsets to the target before and
        after: |a| - |b| of two ~1000 m distances in float32 is rounded to 6e-5 m, 0.004 m/s at 60 Hz."""
        target = self.targets[:, :2]
        now, before = self.sim.root_pos[:, :2], self.prev_xy
        a, b = target - before, target - now
        drop = torch.sum((now - before) * (a + b), dim=-1) / (torch.norm(a, dim=-1) + torch.norm(b, dim=-1))
        return drop / self.control_dt

    def check_termination(self) -> torch.Tensor:
        return self.sim.root_pos[:, 2] < self.env_numbers["terminationHeight"]

    def compute_reward(self) -> None:
        # A fall replaces the step's terms by the death cost; the episode sums log what was earned before it. A
        # blown-up world earns nothing (its body states are NaN until the next physics step).
        earned = self.rewards.compute(self.terminate_buf)
        total = torch.where(self.terminate_buf, torch.full_like(self.rew_buf, self.env_numbers["deathCost"]), earned)
        self.rew_buf[:] = total

    def reset_idx(self, mask: torch.Tensor) -> None:
        n, nd, dev = self.num_envs, self.sim.num_dof, self.device
        noise_pos, noise_vel = self.env_numbers["resetDofPosNoise"], self.env_numbers["resetDofVelNoise"]
        dof_pos = self.initial_dof_pos + noise_pos * (2.0 * torch.rand(n, nd, device=dev) - 1.0)
        dof_pos = torch.clamp(dof_pos, self.dof_lower, self.dof_upper)
        dof_vel = noise_vel * (2.0 * torch.rand(n, nd, device=dev) - 1.0)
        # The torso goes back to the model's start pose (qpos0: env.baseInitState), at rest.
        self.sim.reset_worlds(mask)
        self.sim.write_state(mask, dof_pos=dof_pos, dof_vel=dof_vel, refresh=False)  # observations read qpos/qvel
        self.prev_xy.copy_(torch.where(mask.unsqueeze(1), self.start_pos[:2], self.prev_xy))
        self.actions.masked_fill_(mask.unsqueeze(1), 0.0)
        # The torso state the observation reads, for the new states: VecTask.reset observes right after this, and
        # a stale first observation (the torso state from before the reset) made the first episodes fall more.
        self._refresh_torso_state()

    # ------------------------------------------------------------ reward terms
    # Each returns its contribution to the step's reward (sign and weight included); the learner recipe scales the sum.
    def _reward_progress(self) -> torch.Tensor:
        # rewards moving toward the target: the drop in horizontal distance over the step / policy dt (m/s)
        return self.progress_speed

    def _reward_alive(self) -> torch.Tensor:
        # rewards every step the torso stays above the termination height
        return torch.full_like(self.progress_speed, self.env_numbers["aliveReward"])

    def _reward_upright(self) -> torch.Tensor:
        # rewards an upright torso: upWeight while its up axis is within acos(upThreshold) of vertical
        return (self.up_proj > self.env_numbers["upThreshold"]).float() * self.env_numbers["upWeight"]

    def _reward_heading(self) -> torch.Tensor:
        # rewards facing the target: headingWeight above headingThreshold, proportionally less below it
        w, thr = self.env_numbers["headingWeight"], self.env_numbers["headingThreshold"]
        return torch.where(self.heading_proj > thr, torch.full_like(self.heading_proj, w), w * self.heading_proj / thr)

    def _reward_action_cost(self) -> torch.Tensor:
        # penalises large commands: actionsCost × Σ a²
        return -self.env_numbers["actionsCost"] * torch.sum(self.actions ** 2, dim=-1)

    def _reward_energy_cost(self) -> torch.Tensor:
        # penalises mechanical power: energyCost × Σ |a × scaled joint velocity| × motor strength share
        vel = self.sim.dof_vel[:, self.actuated_dof] * self.env_numbers["dofVelocityScale"]
        power = torch.abs(self.actions * vel) * self.motor_effort_ratio
        return -self.env_numbers["energyCost"] * torch.sum(power, dim=-1)

    def _reward_joints_at_limit(self) -> torch.Tensor:
        # penalises joints pressed to their limits: jointsAtLimitCost per joint with |scaled position| > threshold
        at_limit = torch.abs(self.dof_pos_scaled()) > self.env_numbers["jointsAtLimitThreshold"]
        return -self.env_numbers["jointsAtLimitCost"] * torch.sum(at_limit.float(), dim=-1)


def _quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of (w, x, y, z) quaternions, batched."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack((
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ), dim=-1)

