"""Velocity-tracking locomotion on flat ground or generated rough terrain, shared by every legged robot (Anymal,
Go1, ...).

The robot gets a command (forward and sideways velocity, yaw rate), sampled from YAML ranges and resampled on
a timer, and must follow it; with ``env.commands.heading`` the yaw rate steers towards a sampled heading instead.
Joint position targets go to MuJoCo position actuators (PD) at the policy rate.
Rewards are legged_gym's: one ``_reward_<name>`` method per term, weighted by ``rewards.scales.<name>`` times the
policy dt; a zero scale removes the term. Everything a user would tune lives in the task YAML.

The ground is a component (tasks/terrain_curriculum.py): flat, or with ``env.terrain.type: heightfield`` a generated
grid of sub-terrains with legged_gym's curriculum and a height scan; the task reads both through the same methods.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from isaacgymenvs_mw.sim import ModelRequest, ground_geoms, match_body_names, match_joint_numbers, match_joint_values
from isaacgymenvs_mw.tasks.base.metrics import PER_STEP, Metric
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.rewards import RewardTerms
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.tasks.terrain_curriculum import ground_from_config
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import quat_rotate_inverse, wrap_to_pi, yaw_from_quat

# Test mode: |command - base velocity| in the horizontal plane (m/s), each step.
LIN_VEL_TRACKING_ERROR = Metric("lin_vel_tracking_error", PER_STEP)


class LeggedTask(VecTask):
    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        self.ground = ground_from_config(env.get("terrain"))  # before the model is built: a terrain is part of it
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        self._init_joint_settings(env)
        self._init_bodies(env["asset"])
        self._init_buffers(env)
        self._init_rewards(env)
        self.ground.bind(self)
        self.build_observation_layouts()

    # ----------------------------------------------------------------- model
    def model_request(self) -> ModelRequest:
        request = super().model_request()
        env = self.cfg["env"]
        asset = env["asset"]
        bodies = request.body_names()  # from the request's parsed asset: no second parse
        sensed = list(request.contact_bodies)  # env.asset.contactBodies, then the bodies the rewards read
        for key in ("footBodies", "terminateContactBodies", "penalizeContactBodies"):
            for body in match_body_names(asset.get(key, []), bodies, f"env.asset.{key}"):
                if body not in sensed:
                    sensed.append(body)
        request.contact_bodies = sensed
        self._sensed_bodies = sensed  # the rows of the contact_forces sensor
        self.ground.add_to(request)
        return request

    def _init_joint_settings(self, env: dict) -> None:
        names = self.sim.dof_names
        if len(names) != self.num_actions:
            raise ConfigError(f"env.numActions={self.num_actions} but the asset has {len(names)} joints: {names}")
        angles = match_joint_numbers(env["defaultJointAngles"], names, "env.defaultJointAngles")
        missing = [n for n in names if n not in angles]
        if missing:
            raise ConfigError(f"env.defaultJointAngles gives no angle for joints {missing}; joints: {names}")
        self.default_dof_pos = torch.tensor([float(angles[n]) for n in names], device=self.device)
        self.action_scale = float(env["control"]["actionScale"])
        limits = torch.tensor(self.sim.mj_model.jnt_range[-len(names):], device=self.device, dtype=torch.float)
        soft = float(env["rewards"].get("softDofPosLimit", 1.0))
        mid, half = limits.mean(dim=1), 0.5 * (limits[:, 1] - limits[:, 0])
        self.soft_dof_pos_limits = torch.stack((mid - soft * half, mid + soft * half), dim=1)

    def _init_bodies(self, asset: dict) -> None:
        names = self.sim.body_names
        self.feet = match_body_names(asset["footBodies"], names, "env.asset.footBodies")
        self.terminate_bodies = match_body_names(asset.get("terminateContactBodies", []), names,
                                        "env.asset.terminateContactBodies")
        self.penalize_bodies = match_body_names(asset.get("penalizeContactBodies", []), names,
                                       "env.asset.penalizeContactBodies")
        self.base_body = self.sim.body_id(asset.get("baseBody", names[1]))
        self.ground_geom = ground_geoms(self.sim.mj_model)[0]  # the parts of a terrain share one friction
        self._contact_forces = self.sim.sensor("contact_forces")  # (N, sensed bodies, 3), world frame
        position = {b: i for i, b in enumerate(self._sensed_bodies)}

        def rows(bodies: list[str]) -> torch.Tensor:
            return torch.tensor([position[b] for b in bodies], device=self.device, dtype=torch.long)

        self._feet_idx = rows(self.feet)
        self._feet_body_ids = torch.tensor([self.sim.body_id(b) for b in self.feet], device=self.device,
                                           dtype=torch.long)  # rows of xpos / cvel
        self._term_idx = rows(self.terminate_bodies)
        self._pen_idx = rows(self.penalize_bodies)

    def _init_buffers(self, env: dict) -> None:
        n, dev, nj = self.num_envs, self.device, self.num_actions
        self.actions = torch.zeros(n, nj, device=dev)
        self.last_actions = torch.zeros(n, nj, device=dev)
        self.last_dof_vel = torch.zeros(n, nj, device=dev)
        self.commands = torch.zeros(n, 3, device=dev)
        self.feet_air_time = torch.zeros(n, len(self.feet), device=dev)
        self.last_contacts = torch.zeros(n, len(self.feet), dtype=torch.bool, device=dev)
        # feet_air_time_biped's clocks: time since each foot last touched down / lifted off (s).
        self.feet_swing_time = torch.zeros(n, len(self.feet), device=dev)
        self.feet_stance_time = torch.zeros(n, len(self.feet), device=dev)
        height = env.get("terminationHeight")  # absent (the quadrupeds): no height termination
        self.termination_height = None if height is None else float(height)
        self.termination_tilt_cos = tilt_limit_cos(env.get("terminationTilt"))  # None: no tilt termination
        self.gravity_vec = torch.tensor([0.0, 0.0, -1.0], device=dev).repeat(n, 1)
        init = env["baseInitState"]
        self.base_init_pos = torch.tensor(init["pos"], device=dev, dtype=torch.float).repeat(n, 1)
        self.base_init_quat = torch.tensor(init.get("rot", [1.0, 0.0, 0.0, 0.0]), device=dev,
                                           dtype=torch.float).repeat(n, 1)
        self.reset_root_vel_range = float(env.get("resetRootVelocityRange", 0.5))
        self.reset_dof_pos_scale = tuple(env.get("resetDofPosScale", [0.5, 1.5]))

        cmd = env["commands"]
        self.command_ranges = torch.tensor([cmd["linVelX"], cmd["linVelY"], cmd["yawRate"]], device=dev,
                                           dtype=torch.float)
        self.command_resample_steps = max(1, int(round(float(cmd["resamplingTime_s"]) / self.control_dt)))
        self.min_command_norm = float(cmd.get("minLinearCommand", 0.0))
        self._init_heading_command(cmd.get("heading"))

        scales = env["obsScales"]
        self.obs_scales = {k: float(v) for k, v in scales.items()}
        self.commands_scale = torch.tensor([scales["linVel"], scales["linVel"], scales["angVel"]], device=dev)

        self.base_lin_vel = torch.zeros(n, 3, device=dev)
        self.base_ang_vel = torch.zeros(n, 3, device=dev)
        self.projected_gravity = torch.zeros(n, 3, device=dev)
        self.contact_force_norm = torch.zeros(n, self._contact_forces.shape[1], device=dev)
        self.torques = self.sim.qfrc_actuator[:, 6:]
        # The critic's privileged view of the randomised world: the ground's friction and the base's added mass,
        # read from the (possibly per-world) model fields the randomisation layer writes.
        self._ground_friction = self.sim.model_field("geom_friction")[:, self.ground_geom, 0:1]
        self._base_mass = self.sim.model_field("body_mass")[:, self.base_body:self.base_body + 1]
        self._nominal_base_mass = float(self.sim.mj_model.body_mass[self.base_body])

    def _init_rewards(self, env: dict) -> None:
        rew = env["rewards"]
        scales = dict(rew["scales"])
        self.tracking_sigma = float(rew.get("trackingSigma", 0.25))
        self.base_height_target = float(rew.get("baseHeightTarget", 0.5))
        self.air_time_target = float(rew.get("feetAirTimeTarget", 0.5))
        self.feet_clearance_target = float(rew.get("feetClearanceTarget", 0.08))
        names = self.sim.dof_names

        def joint_mask(key: str, term: str) -> torch.Tensor:
            patterns = rew.get(key)
            if float(scales.get(term, 0.0)) != 0.0 and not patterns:
                raise ConfigError(f"env.rewards.scales.{term} is not 0 but env.rewards.{key} names no joints: give a "
                                 f"list of joint names or regular expressions (joints: {names})")
            picked = match_joint_values({p: True for p in patterns or []}, names, f"env.rewards.{key}")
            return torch.tensor([n in picked for n in names], device=self.device, dtype=torch.float)

        # Scales are per second of policy time (legged_gym); legged_gym adds the termination term after the clamp
        # at 0: a fall still costs something while every other step is clamped to nothing (as early on, when
        # random actions cost more than tracking earns).
        self.rewards = RewardTerms.from_env(self, env, self.num_envs, self.device, dt=self.control_dt,
                                            only_positive=bool(rew.get("onlyPositiveRewards", True)),
                                            unclamped=("termination",), penalty_curriculum=rew.get("penaltyCurriculum"),
                                            step_count=self.episode.run_steps)
        self._deviation_mask = joint_mask("jointDeviationJoints", "joint_deviation")
        self._upper_body_mask = joint_mask("upperBodyJoints", "upper_body_posture")

    # ----------------------------------------------------------- observations
    def observation_terms(self) -> list[ObsTerm]:
        # Sensor noise per term comes from task.randomization_params.observations.terms (randomisation layer).
        s, nj = self.obs_scales, self.num_actions
        scan = self.ground.observation_terms(self.obs_scales, for_policy=True)
        return [
            ObsTerm("base_lin_vel", 3, s["linVel"], compute=lambda: self.base_lin_vel),  # body frame, m/s
            ObsTerm("base_ang_vel", 3, s["angVel"], compute=lambda: self.base_ang_vel),  # body frame, rad/s
            ObsTerm("projected_gravity", 3, compute=lambda: self.projected_gravity),  # unit vector, body frame
            # vx, vy (linVel scale), yaw rate (angVel scale)
            ObsTerm("commands", 3, compute=lambda: self.commands * self.commands_scale),
            ObsTerm("dof_pos", nj, s["dofPos"], compute=lambda: self.sim.dof_pos - self.default_dof_pos),
            ObsTerm("dof_vel", nj, s["dofVel"], compute=lambda: self.sim.dof_vel),
            # the action the drives received (delayed, if delayed)
            ObsTerm("actions", nj, compute=lambda: self.actions),
        ] + scan

    def state_terms(self) -> list[ObsTerm]:
        # The critic sees the noiseless policy observation (the observed sensors' terms included, env.observeSensors)
        # plus what the policy cannot measure.
        n = self.num_envs
        policy = [replace(t, noise=0.0) for t in self.observation_terms() + self.observations.sensor_terms]
        return policy + [
            ObsTerm("ground_friction", 1, compute=lambda: self._ground_friction.expand(n, 1)),
            ObsTerm("added_base_mass", 1, compute=lambda: (self._base_mass - self._nominal_base_mass).expand(n, 1)),
            ObsTerm("base_height", 1, compute=lambda: self.sim.root_pos[:, 2:3]),  # m
            # 1 where the foot's contact force exceeds 1 N
            ObsTerm("feet_contact", len(self.feet), compute=lambda: self._feet_contact().float()),
        ] + self.ground.observation_terms(self.obs_scales, for_policy=False)

    def evaluation_groups(self) -> dict[str, torch.Tensor]:
        return self.ground.evaluation_groups()

    def deployment_info(self) -> dict:
        info = super().deployment_info()
        gains = self.sim.joint_pd_gains()
        names = self.sim.dof_names
        info.update(
            joint_names=names,  # action i drives joint_names[i]
            default_joint_pos=self.default_dof_pos.tolist(),
            action_scale=self.action_scale,
            action_to_target="target = default_joint_pos + action_scale * clip(action, +-clip_actions)",
            stiffness=[gains[n][0] if n in gains else 0.0 for n in names],
            damping=[gains[n][1] if n in gains else 0.0 for n in names],
            commands_scale=self.commands_scale.tolist(),  # the `commands` term: (vx, vy, yaw rate) times this
            command_ranges={"lin_vel_x": self.command_ranges[0].tolist(), "lin_vel_y": self.command_ranges[1].tolist(),
                            "yaw_rate": self.command_ranges[2].tolist()},
            base_init_pos=self.base_init_pos[0].tolist(),
            base_init_quat=self.base_init_quat[0].tolist(),
        )
        return info

    # --------------------------------------------------------------- stepping
    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.actions[:] = actions
        self.sim.ctrl[:] = self.default_dof_pos + self.action_scale * actions

    def declared_metrics(self) -> list[Metric]:
        return [*super().declared_metrics(), LIN_VEL_TRACKING_ERROR, *self.ground.metrics()]

    def after_reset(self, new_episode: torch.Tensor) -> None:
        # Commands run on a timer: the envs whose episode goes on draw new ones every resamplingTime_s.
        self._resample_commands((self.progress_buf % self.command_resample_steps == 0) & ~new_episode)
        if self.metrics.evaluating:
            err = torch.norm(self.commands[:, :2] - self.base_lin_vel[:, :2], dim=1)
            self.metrics.record(LIN_VEL_TRACKING_ERROR, err)
        self.last_actions[:] = self.actions
        self.last_dof_vel[:] = self.sim.dof_vel

    def refresh_state(self) -> None:
        q = self.sim.root_quat
        self.base_lin_vel[:] = quat_rotate_inverse(q, self.sim.root_lin_vel)
        self.base_ang_vel[:] = self.sim.root_ang_vel
        self.projected_gravity[:] = quat_rotate_inverse(q, self.gravity_vec)
        self.contact_force_norm[:] = torch.norm(self._contact_forces, dim=-1)

    def check_termination(self) -> torch.Tensor:
        hit = (self.contact_force_norm[:, self._term_idx] > 1.0).any(dim=1)
        if self.termination_height is not None:
            hit |= self._base_height() < self.termination_height
        if self.termination_tilt_cos is not None:
            hit |= base_tilted(self.projected_gravity, self.termination_tilt_cos)
        return hit

    @property
    def terminated(self) -> torch.Tensor:
        """Failed this step, time-outs aside (legged_gym's termination), read by the termination and alive terms."""
        return self.terminate_buf & (self.timeout_buf == 0)

    def compute_reward(self) -> None:
        # A world that blew up this step earns nothing (VecTask zeroes its reward too).
        self.rew_buf[:] = self.rewards.compute(self.nonfinite_buf)

    def reset_idx(self, mask: torch.Tensor) -> None:
        n, dev = self.num_envs, self.device
        lo, hi = self.reset_dof_pos_scale
        dof_pos = self.default_dof_pos * (lo + (hi - lo) * torch.rand(n, self.num_actions, device=dev))
        # Scaling the default can leave a joint's range (Go1's knee); start inside the soft limits instead.
        dof_pos = torch.clamp(dof_pos, self.soft_dof_pos_limits[:, 0], self.soft_dof_pos_limits[:, 1])
        root_vel = self.reset_root_vel_range * (2.0 * torch.rand(n, 6, device=dev) - 1.0)
        root_pos = self.ground.place(self, mask, self.base_init_pos)  # a terrain cell's platform, or as given
        self.sim.reset_worlds(mask)
        self.sim.write_state(mask, dof_pos=dof_pos, dof_vel=torch.zeros_like(dof_pos),
                             root_pos=root_pos, root_quat=self.base_init_quat,
                             root_lin_vel=root_vel[:, :3], root_ang_vel=root_vel[:, 3:],
                             refresh=False)  # observations read qpos/qvel only; the next step recomputes poses
        self._resample_commands(mask)
        keep = ~mask
        rows = keep.unsqueeze(1)
        self.last_actions *= rows
        self.actions *= rows
        self.last_dof_vel *= rows
        self.feet_air_time *= rows
        self.feet_swing_time *= rows
        self.feet_stance_time *= rows
        self.last_contacts &= rows
        # The base velocities and gravity the observation reads, for the new states (VecTask.reset observes next).
        self.refresh_state()

    def _init_heading_command(self, cfg) -> None:
        """env.commands.heading {range, stiffness}: the masked envs draw a world-frame heading (rad) instead of a
        yaw rate, and every step the yaw-rate command is stiffness x the heading error, clipped to the yawRate
        range (legged_gym's and Isaac Lab's heading command). The robot turns, then walks straight: a curriculum
        that asks for half the commanded distance can then be met. Absent: yaw rates are drawn directly."""
        self.heading_range: tuple[float, float] | None = None
        if cfg is None:
            return
        key = "env.commands.heading"
        _require_keys(cfg, key, ("range", "stiffness"))
        rng, stiffness = cfg["range"], cfg["stiffness"]
        if (not isinstance(rng, (list, tuple)) or len(rng) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in rng)
                or not -math.pi - 1e-3 <= rng[0] <= rng[1] <= math.pi + 1e-3):
            raise ConfigError(f"{key}.range must be [low, high] in radians with -pi <= low <= high <= pi, got {rng!r}")
        if isinstance(stiffness, bool) or not isinstance(stiffness, (int, float)) or not stiffness > 0:
            raise ConfigError(f"{key}.stiffness must be a number > 0 (yaw rate per radian of heading error, 1/s), "
                             f"got {stiffness!r}")
        self.heading_range = (float(rng[0]), float(rng[1]))
        self.heading_stiffness = float(stiffness)
        self.heading_targets = torch.zeros(self.num_envs, device=self.device)

    def base_yaw(self) -> torch.Tensor:
        """The base's heading (rad): the yaw of its (w, x, y, z) quaternion."""
        return yaw_from_quat(self.sim.root_quat)

    def _resample_commands(self, mask: torch.Tensor) -> None:
        """Draw new commands for the masked envs; with heading commands, then steer every env (called every step)."""
        lo, hi = self.command_ranges[:, 0], self.command_ranges[:, 1]
        new = lo + (hi - lo) * torch.rand(self.num_envs, 3, device=self.device)
        small = torch.norm(new[:, :2], dim=1, keepdim=True) < self.min_command_norm
        new[:, :2] = torch.where(small, torch.zeros_like(new[:, :2]), new[:, :2])
        self.commands[:] = torch.where(mask.unsqueeze(1), new, self.commands)
        if self.heading_range is not None:
            h_lo, h_hi = self.heading_range
            heading = h_lo + (h_hi - h_lo) * torch.rand(self.num_envs, device=self.device)
            self.heading_targets[:] = torch.where(mask, heading, self.heading_targets)
            error = wrap_to_pi(self.heading_targets - self.base_yaw())
            self.commands[:, 2] = torch.clamp(self.heading_stiffness * error, lo[2], hi[2])

    # ------------------------------------------------------------ reward terms
    def _reward_tracking_lin_vel(self) -> torch.Tensor:
        err = torch.sum(torch.square(self.commands[:, :2] - self.base_lin_vel[:, :2]), dim=1)
        return torch.exp(-err / self.tracking_sigma)

    def _reward_tracking_ang_vel(self) -> torch.Tensor:
        err = torch.square(self.commands[:, 2] - self.base_ang_vel[:, 2])
        return torch.exp(-err / self.tracking_sigma)

    def _reward_lin_vel_z(self) -> torch.Tensor:
        return torch.square(self.base_lin_vel[:, 2])

    def _reward_ang_vel_xy(self) -> torch.Tensor:
        return torch.sum(torch.square(self.base_ang_vel[:, :2]), dim=1)

    def _reward_orientation(self) -> torch.Tensor:
        return torch.sum(torch.square(self.projected_gravity[:, :2]), dim=1)

    def _reward_base_height(self) -> torch.Tensor:
        # Squared distance of the base's height above the ground from baseHeightTarget.
        return torch.square(self._base_height() - self.base_height_target)

    def _reward_torques(self) -> torch.Tensor:
        return torch.sum(torch.square(self.torques), dim=1)

    def _reward_dof_vel(self) -> torch.Tensor:
        return torch.sum(torch.square(self.sim.dof_vel), dim=1)

    def _reward_dof_acc(self) -> torch.Tensor:
        return torch.sum(torch.square((self.last_dof_vel - self.sim.dof_vel) / self.control_dt), dim=1)

    def _reward_action_rate(self) -> torch.Tensor:
        return torch.sum(torch.square(self.last_actions - self.actions), dim=1)

    def _reward_collision(self) -> torch.Tensor:
        return torch.sum((self.contact_force_norm[:, self._pen_idx] > 0.1).float(), dim=1)

    def _reward_termination(self) -> torch.Tensor:
        return self.terminated.float()

    def _reward_dof_pos_limits(self) -> torch.Tensor:
        q = self.sim.dof_pos
        below = (self.soft_dof_pos_limits[:, 0] - q).clamp(min=0.0)
        above = (q - self.soft_dof_pos_limits[:, 1]).clamp(min=0.0)
        return torch.sum(below + above, dim=1)

    def _reward_feet_air_time(self) -> torch.Tensor:
        contact = self._feet_contact()
        touching = contact | self.last_contacts  # MuJoCo contacts can flicker for a step
        self.last_contacts[:] = contact
        first_contact = (self.feet_air_time > 0.0) & touching
        self.feet_air_time += self.control_dt
        reward = torch.sum((self.feet_air_time - self.air_time_target) * first_contact, dim=1)
        reward *= torch.norm(self.commands[:, :2], dim=1) > 0.1  # no stepping reward for standing still
        self.feet_air_time *= ~touching
        return reward

    def _reward_alive(self) -> torch.Tensor:
        # A constant bonus for every step the robot has not fallen (unitree_rl_gym's `alive`).
        return (~self.terminated).float()

    def _reward_feet_air_time_biped(self) -> torch.Tensor:
        # Time in the current single-stance phase, capped at feetAirTimeTarget, while commanded to move: pays
        # alternating steps with one foot down (Isaac Lab's feet_air_time_positive_biped).
        contact = self._feet_contact()
        self.feet_stance_time[:] = torch.where(contact, self.feet_stance_time + self.control_dt, 0.0)
        self.feet_swing_time[:] = torch.where(contact, 0.0, self.feet_swing_time + self.control_dt)
        phase_time = torch.where(contact, self.feet_stance_time, self.feet_swing_time)
        single_stance = contact.sum(dim=1) == 1
        reward = torch.where(single_stance, phase_time.min(dim=1).values, 0.0).clamp(max=self.air_time_target)
        return reward * (torch.norm(self.commands[:, :2], dim=1) > 0.1)

    def _reward_feet_slip(self) -> torch.Tensor:
        # Horizontal speed (m/s) of the feet that touch the ground, summed over feet.
        speed = torch.norm(self._feet_lin_vel()[..., :2], dim=-1)
        return torch.sum(speed * self._feet_contact(), dim=1)

    def _reward_feet_clearance(self) -> torch.Tensor:
        # Squared miss of feetClearanceTarget by each swinging foot's height above the ground, summed over feet.
        height = self._height_above_ground(self.sim.xpos[:, self._feet_body_ids])
        return torch.sum(torch.square(height - self.feet_clearance_target) * ~self._feet_contact(), dim=1)

    def _reward_joint_deviation(self) -> torch.Tensor:
        # L1 distance from the default pose of the joints in rewards.jointDeviationJoints (a biped's hip roll/yaw).
        return self._pose_deviation(self._deviation_mask)

    def _reward_upper_body_posture(self) -> torch.Tensor:
        # L1 distance from the default pose of the joints in rewards.upperBodyJoints (waist and arms).
        return self._pose_deviation(self._upper_body_mask)

    def _reward_stand_still(self) -> torch.Tensor:
        still = torch.norm(self.commands[:, :2], dim=1) < 0.1
        return self._pose_deviation() * still

    # ----------------------------------------------------------------- helpers
    def _height_above_ground(self, pos: torch.Tensor) -> torch.Tensor:
        """Height (m) of points (..., 3) above the ground under them: world z on flat ground, minus the terrain's
        height there."""
        return self.ground.height_above(pos)

    def _base_height(self) -> torch.Tensor:
        """Base height (m) above the ground under it."""
        return self._height_above_ground(self.sim.root_pos)

    def _pose_deviation(self, joints: torch.Tensor | float = 1.0) -> torch.Tensor:
        """L1 distance of the joints (a 0/1 mask over the joints; all by default) from the default pose."""
        return torch.sum(torch.abs(self.sim.dof_pos - self.default_dof_pos) * joints, dim=1)

    def _feet_contact(self) -> torch.Tensor:
        """(N, feet) bool: the foot's contact force exceeds 1 N."""
        return self.contact_force_norm[:, self._feet_idx] > 1.0

    def _feet_lin_vel(self) -> torch.Tensor:
        """(N, feet, 3) world-frame linear velocity of each foot body's origin."""
        return self.sim.body_lin_vel(self._feet_body_ids)


def _require_keys(cfg, key: str, names: tuple[str, ...]) -> None:
    """A YAML option given as a mapping must hold exactly ``names``: a missing or misspelt one is an error."""
    if not hasattr(cfg, "keys") or set(cfg.keys()) != set(names):
        raise ConfigError(f"{key} must be a mapping with exactly the keys {' and '.join(names)}, got {cfg!r}")


def tilt_limit_cos(limit: object) -> float | None:
    """``env.terminationTilt`` (rad, in (0, pi]) as the cosine a tilt test compares with; None when absent."""
    if limit is None:
        return None
    try:
        value = float(limit)
    except (TypeError, ValueError):
        value = float("nan")
    if not 0.0 < value <= math.pi:
        raise ConfigError(f"env.terminationTilt={limit!r} is invalid: give an angle in (0, pi] rad between the base's "
                          "up axis and the world's up")
    return math.cos(value)


def base_tilted(projected_gravity: torch.Tensor, limit_cos: float) -> torch.Tensor:
    """The envs whose base's up axis is more than the limit from the world's up: gravity in the base frame is
    (0, 0, -1) upright, so the cosine of the tilt is -g_z."""
    return -projected_gravity[:, 2] < limit_cos
