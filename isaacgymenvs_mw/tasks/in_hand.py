"""What the in-hand reorientation tasks (IsaacGymEnvs' AllegroHand and ShadowHand) share: a hand welded palm up
turns a free cube to a goal orientation.

The scene (the task YAML): the hand (``env.asset``, its position servos the actions), the cube (``env.assets.object``,
free) starting above the palm, and the goal (``env.assets.goal``), a mocap copy of the cube beside the hand that only
shows the goal orientation.

Each policy step the actions set the servo targets: absolute targets spanning each servo's control range, smoothed
by ``actionsMovingAverage``, or, with ``useRelativeControl``, a change of the last targets. The reward (IsaacGymEnvs'
``compute_hand_reward``, as reward terms) pays for the cube's orientation near the goal's, charges its distance from
the goal position and the actions' size, and adds ``reachGoalBonus`` when the orientation is within
``successTolerance``: a success, after which a new goal orientation is drawn and the episode goes on. The episode
ends when the cube falls (``fallDistance`` from the goal position), at the time limit, or (with
``maxConsecutiveSuccesses`` > 0) after that many successes. ``consecutive_successes`` is IsaacGymEnvs' metric: a
running average, over the episodes that end, of the successes in each. With ``forceScale`` > 0 the cube is pushed
at random as IGE pushes it (``_push_cube``).

A servo may drive a tendon of several joints (the Shadow hand's J0 drives J1 + J2, which an equality holds equal):
its target then spans the tendon's range, so that each joint gets the target IsaacGymEnvs gives the joint it
actuates, and the reset sets it to the tendon's length at the drawn pose.

Differences from IsaacGymEnvs, on purpose: quaternions are MuJoCo's (w, x, y, z), IGE's (x, y, z, w); the DOF-force
observation (``full_state``) is the servos' generalised force on each joint; hand joints drawn outside their range
at a reset are clamped into it, and a joint an equality couples to another is drawn where the equality puts it; a new
goal after a success is shown in the same step's observation (IGE: the next step's).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch

from isaacgymenvs_mw.sim.couplings import joint_couplings, servo_transmission
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, OUTCOME, RUNNING, Metric
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.rewards import RewardTerms
from isaacgymenvs_mw.tasks.base.env_keys import refuse_reward_scale
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.utils.config import whole_number
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import (
    quat_about_axis,
    quat_conjugate,
    quat_mul,
    quat_rotate,
    rotation_distance,
)

# IGE's sim dt (its hand tasks' physics step, 1/60 s with 2 substeps, whatever controlFrequencyInv): the time unit of
# its relative control, kept so that dofSpeedScale means what it means there.
IGE_SIM_DT = 1.0 / 60.0
VEL_OBS_SCALE = 0.2  # IGE's vel_obs_scale: joint and cube angular velocities
FORCE_OBS_SCALE = 10.0  # IGE's force_torque_obs_scale: joint forces (and the Shadow hand's fingertip sensors)
# IGE: the reward's goal position is the cube's start position 4 cm lower, where a cube held in the palm sits.
GOAL_BELOW_START = 0.04
# env keys of the task YAML that are plain numbers
_NUMBER_KEYS = ("dofSpeedScale", "actionsMovingAverage", "resetPositionNoise", "resetDofPosRandomInterval",
                "resetDofVelRandomInterval", "rotEps", "fallDistance", "successTolerance", "averFactor")
# reward term -> the env key of its scale (IsaacGymEnvs' names)
# IGE's consecutive_successes (a running average over resets, averFactor), the goals reached per ended episode, and
# in test mode each env's first episode's count.
CONSECUTIVE_SUCCESSES = Metric("consecutive_successes", RUNNING, success=True)
SUCCESSES = Metric("successes", EPISODE_SUM)
EPISODE_SUCCESSES = Metric("consecutive_successes", OUTCOME, success=True)
REWARD_SCALE_KEYS = {"dist": "distRewardScale", "rot": "rotRewardScale", "action_penalty": "actionPenaltyScale",
                     "reach_goal": "reachGoalBonus", "fall": "fallPenalty"}


class InHandTask(VecTask):
    """The shared task; a subclass names its observation types (``observation_types``) and their terms
    (``_terms_of``). ``env.asymmetric_observations`` gives the critic the ``full_state`` observation."""

    observation_types: tuple[str, ...] = ()

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        missing = [k for k in _NUMBER_KEYS + tuple(REWARD_SCALE_KEYS.values()) if k not in env]
        if missing:
            raise ConfigError(f"{type(self).__name__}: the task YAML's env section lacks {missing}")
        refuse_reward_scale(type(self).__name__, env)
        self.env_numbers = {key: float(env[key]) for key in _NUMBER_KEYS}
        self.observation_type = observation_type(env.get("observationType", "full_state"), self.observation_types)
        self.asymmetric = bool(env.get("asymmetric_observations", False))
        check_settings(self.env_numbers)
        self.max_consecutive_successes = whole_number(env.get("maxConsecutiveSuccesses", 0),
                                                      "env.maxConsecutiveSuccesses", 0)
        self.relative_control = bool(env.get("useRelativeControl", False))
        self.force_scale = float(env.get("forceScale", 0.0))
        if self.force_scale > 0.0:
            self._check_push_settings(env)
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        n, dev = self.num_envs, self.device
        self.cube = self.sim.asset("object")
        if not self.cube.floating_base:
            raise ConfigError("env.assets.object.fixBaseLink=True: the cube must float (a free joint); set "
                              "fixBaseLink: False")
        m = self.sim.mj_model
        joint_ids = [m.joint(name).id for name in self.sim.dof_names]
        self.dof_lower, self.dof_upper = self.sim.joint_limits()
        servos = range(self.num_actions)
        self.target_lower = torch.tensor(m.actuator_ctrlrange[servos, 0], dtype=torch.float32, device=dev)
        self.target_upper = torch.tensor(m.actuator_ctrlrange[servos, 1], dtype=torch.float32, device=dev)
        transmission = servo_transmission(m, joint_ids, self.num_actions)
        self.transmission = torch.tensor(transmission, dtype=torch.float32, device=dev)
        self.couplings = joint_couplings(m, joint_ids)
        # Relative control: IGE moves a joint's target by dofSpeedScale x its sim dt x the action; a servo on the
        # tendon of two joints held equal (the Shadow hand's J1 + J2) moves twice as far, that much for each joint.
        per_joint = torch.tensor(transmission.sum(axis=1), dtype=torch.float32, device=dev)
        self.relative_step = self.env_numbers["dofSpeedScale"] * IGE_SIM_DT * per_joint

        free = self.cube.layout.free_qpos
        self.object_start_pos = torch.tensor(m.qpos0[free:free + 3], dtype=torch.float32, device=dev)  # env.assets
        self.goal_pos = (self.object_start_pos - torch.tensor([0.0, 0.0, GOAL_BELOW_START], device=dev)).repeat(n, 1)
        self.goal_quat = torch.zeros((n, 4), device=dev)
        self.goal_quat[:, 0] = 1.0
        # The goal marker: a mocap body beside the hand (env.goalDisplayOffset from the goal position, as IGE).
        self.goal_marker = self.sim.mocap_index(self.sim.asset("goal").body_names[0])
        offset = torch.tensor([float(v) for v in env.get("goalDisplayOffset", (0.0, 0.0, 0.0))], device=dev)
        self.sim.mocap_pos[:, self.goal_marker] = self.goal_pos + offset

        self.actions = torch.zeros((n, self.num_actions), device=dev)
        self.prev_targets = torch.zeros((n, self.num_actions), device=dev)
        self.successes = torch.zeros(n, device=dev)  # goals reached in the running episode
        self.consecutive_successes = torch.zeros((), device=dev)  # IGE's metric (module docstring)
        self.rewards = RewardTerms.from_env(self, env, n, dev, ige_keys=REWARD_SCALE_KEYS)
        self.terms: dict[str, torch.Tensor] = {}
        if self.force_scale > 0.0:
            # IGE's pushes: a force on the cube that decays, replaced at random moments by a new one (_push_cube)
            self.cube_body = self.sim.asset("object").body_names[0]
            self.cube_mass = float(m.body(self.cube_body).mass[0])  # nominal, as IGE (not the randomised mass)
            self.push_forces = torch.zeros((n, 1, 3), device=dev)  # cube frame (IGE: LOCAL_SPACE), N
            self.push_prob = torch.zeros(n, device=dev)
            self._draw_push_prob(torch.ones(n, dtype=torch.bool, device=dev))
            # A zero push now: the simulator's force buffer exists before the step is compiled, so the compiled step
            # does not meet a new model at the first real push and compile again.
            self.apply_body_forces(self.push_forces, bodies=[self.cube_body], frame="body")
        self.bind_hand()
        self.build_observation_layouts()

    def bind_hand(self) -> None:
        """Resolve what a subclass's observation terms read from the model (called before the layouts are built)."""

    # ------------------------------------------------------------------ pre-physics
    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.actions.copy_(actions)
        if self.relative_control:
            targets = self.prev_targets + self.relative_step * actions
        else:
            targets = self.target_lower + 0.5 * (actions + 1.0) * (self.target_upper - self.target_lower)
            alpha = self.env_numbers["actionsMovingAverage"]
            targets = alpha * targets + (1.0 - alpha) * self.prev_targets
        targets = torch.clamp(targets, self.target_lower, self.target_upper)
        self.prev_targets.copy_(targets)
        self.sim.ctrl[:, :self.num_actions] = targets
        if self.force_scale > 0.0:
            self._push_cube()

    def _check_push_settings(self, env: Mapping) -> None:
        lo, hi = (float(v) for v in env["forceProbRange"])
        if not 0.0 < lo <= hi <= 1.0:
            raise ConfigError(f"env.forceProbRange={[lo, hi]} is invalid: give [low, high] with 0 < low <= high <= 1 "
                              "(the chance of a new push per policy step)")
        decay, interval = float(env["forceDecay"]), float(env["forceDecayInterval"])
        if not 0.0 < decay <= 1.0 or interval <= 0.0:
            raise ConfigError(f"env.forceDecay={decay}, env.forceDecayInterval={interval} are invalid: give a decay "
                              "in (0, 1] and an interval > 0 (s)")
        self.push_prob_log_range = (math.log(lo), math.log(hi))
        # IGE multiplies the force by forceDecay^(dt / forceDecayInterval) each policy step, dt its sim dt
        self.push_decay = decay ** (IGE_SIM_DT / interval)

    def _draw_push_prob(self, mask: torch.Tensor) -> None:
        """Each masked env's chance of a new push per policy step, log-uniform over env.forceProbRange (IGE)."""
        lo, hi = self.push_prob_log_range
        drawn = torch.exp(lo + (hi - lo) * torch.rand(self.num_envs, device=self.device))
        self.push_prob.copy_(torch.where(mask, drawn, self.push_prob))

    def _push_cube(self) -> None:
        """IGE's random forces: the last push decays; with each env's chance, a new one replaces it, Gaussian per
        axis of the cube's frame with standard deviation forceScale x the cube's mass (N); it acts at the cube's
        centre of mass for the coming policy step."""
        self.push_forces.mul_(self.push_decay)
        new = (torch.rand(self.num_envs, device=self.device) < self.push_prob).view(-1, 1, 1)
        fresh = torch.randn_like(self.push_forces) * (self.cube_mass * self.force_scale)
        self.push_forces.copy_(torch.where(new, fresh, self.push_forces))
        self.apply_body_forces(self.push_forces, bodies=[self.cube_body], frame="body")

    # ------------------------------------------------------------------ post-physics
    def refresh_state(self) -> None:
        """The quantities the reward terms, the end conditions and the goal reset share, once per step."""
        self.terms = hand_terms(self.cube.root_pos, self.cube.root_quat, self.goal_pos, self.goal_quat,
                                self.env_numbers["successTolerance"], self.env_numbers["fallDistance"])
        reached = self.terms["reached"]
        self.successes += reached.float()
        if self.max_consecutive_successes > 0:
            # IGE: the time limit then counts from the last success.
            self.progress_buf.masked_fill_(reached, 0)

    def check_termination(self) -> torch.Tensor:
        # The cube fell: it is fallDistance or more from the goal position.
        return self.terms["fell"]

    def check_success(self) -> torch.Tensor:
        # maxConsecutiveSuccesses goals reached (0: no limit): the episode ends, bootstrapped like a time-out.
        if self.max_consecutive_successes <= 0:
            return torch.zeros_like(self.terms["fell"])
        return self.successes >= self.max_consecutive_successes

    def longest_episode(self) -> int:
        # With maxConsecutiveSuccesses each success restarts the time limit: up to that many limits, plus the last.
        return int(self.max_episode_length) * (self.max_consecutive_successes + 1)

    def compute_reward(self) -> None:
        self.rew_buf[:] = self.rewards.compute(self.nonfinite_buf)

    # Reward terms (IsaacGymEnvs' compute_hand_reward, one term per summand).
    def _reward_dist(self) -> torch.Tensor:
        # distance (m) of the cube from the goal position
        return self.terms["goal_dist"]

    def _reward_rot(self) -> torch.Tensor:
        # 1 / (rotation distance + rotEps): up to 1 / rotEps at the goal orientation
        return 1.0 / (self.terms["rot_dist"] + self.env_numbers["rotEps"])

    def _reward_action_penalty(self) -> torch.Tensor:
        # sum of the squared actions
        return torch.sum(self.actions ** 2, dim=-1)

    def _reward_reach_goal(self) -> torch.Tensor:
        # the cube's orientation is within successTolerance of the goal's
        return self.terms["reached"].float()

    def _reward_fall(self) -> torch.Tensor:
        # the cube fell; with maxConsecutiveSuccesses > 0 half of it also at the time limit (IGE)
        fell = self.terms["fell"].float()
        if self.max_consecutive_successes > 0:
            fell = fell + 0.5 * (self.timeout_buf & ~self.terms["fell"]).float()
        return fell

    def after_reset(self, new_episode: torch.Tensor) -> None:
        # A success in a running episode: a new goal orientation, seen in this step's observation. (At reset(),
        # before any step, no episode is running: nothing to do.)
        if self.terms:
            self._new_goals(self.terms["reached"] & ~new_episode)

    # ------------------------------------------------------------------ observation
    def observation_terms(self) -> list[ObsTerm]:
        return self._terms_of(self.observation_type)

    def state_terms(self) -> list[ObsTerm] | None:
        return self._terms_of("full_state") if self.asymmetric else None

    def _terms_of(self, kind: str) -> list[ObsTerm]:
        """The observation terms of ``kind`` (one of ``observation_types``), in the task's order."""
        raise NotImplementedError(f"{type(self).__name__} must implement _terms_of(kind): the observation terms of "
                                  f"each of its observation types {list(self.observation_types)}")

    def _joint_terms(self, kind: str) -> list[ObsTerm]:
        """IGE's hand-joint block: positions over each range, velocities unless ``full_no_vel``, forces in
        ``full_state``."""
        n = self.num_dof  # the welded hand is the main asset: its joints are the first dof columns
        terms = [ObsTerm("dof_pos", n, compute=self._unscaled_dof_pos)]                  # -1 ... 1 over the range
        if kind != "full_no_vel":
            terms.append(ObsTerm("dof_vel", n, VEL_OBS_SCALE, compute=lambda: self.sim.dof_vel))  # rad/s
        if kind == "full_state":
            terms.append(ObsTerm("dof_force", n, FORCE_OBS_SCALE,                        # servo forces (N m)
                                 compute=lambda: self.sim.qfrc_actuator[:, :n]))
        return terms

    def _object_terms(self, kind: str) -> list[ObsTerm]:
        """The cube's pose, with its velocities unless ``full_no_vel``."""
        cube = self.cube
        terms = [ObsTerm("object_pos", 3, compute=lambda: cube.root_pos),                 # m, world frame
                 ObsTerm("object_quat", 4, compute=lambda: cube.root_quat)]               # (w, x, y, z)
        if kind != "full_no_vel":
            terms += [ObsTerm("object_lin_vel", 3, compute=lambda: cube.root_lin_vel),     # m/s, world frame
                      ObsTerm("object_ang_vel", 3, VEL_OBS_SCALE,                          # rad/s, world frame
                              compute=lambda: quat_rotate(cube.root_quat, cube.root_ang_vel))]
        return terms

    def _goal_terms(self) -> list[ObsTerm]:
        """The goal pose and the rotation from the goal to the cube."""
        return [ObsTerm("goal_pos", 3, compute=lambda: self.goal_pos),                   # m, world frame
                ObsTerm("goal_quat", 4, compute=lambda: self.goal_quat),                 # (w, x, y, z)
                ObsTerm("object_to_goal_quat", 4, compute=self._object_to_goal_quat)]    # object x goal^-1

    def _object_to_goal_quat(self) -> torch.Tensor:
        return quat_mul(self.cube.root_quat, quat_conjugate(self.goal_quat))

    def _action_term(self) -> ObsTerm:
        return ObsTerm("actions", self.num_actions, compute=lambda: self.actions)          # the last actions

    @property
    def num_dof(self) -> int:
        """The hand's joints (the columns of ``sim.dof_pos``)."""
        return self.sim.num_dof

    def _unscaled_dof_pos(self) -> torch.Tensor:
        return (2.0 * self.sim.dof_pos - self.dof_upper - self.dof_lower) / (self.dof_upper - self.dof_lower)

    def declared_metrics(self) -> list[Metric]:
        return [*super().declared_metrics(), CONSECUTIVE_SUCCESSES, SUCCESSES, EPISODE_SUCCESSES]

    # ------------------------------------------------------------------ reset
    def reset_idx(self, mask: torch.Tensor) -> None:
        n, dev = self.num_envs, self.device
        ended = self.successes * mask
        # IGE's consecutive_successes: over the envs that reset, the mean successes of their episodes, averaged
        # into a running value with weight averFactor (unchanged in a step without resets).
        count = mask.sum()
        mean = ended.sum() / count.clamp(min=1)
        aver = self.env_numbers["averFactor"]
        self.consecutive_successes.copy_(torch.where(count > 0, aver * mean + (1.0 - aver) * self.consecutive_successes,
                                                     self.consecutive_successes))
        self.metrics.record(CONSECUTIVE_SUCCESSES, self.consecutive_successes)
        self.metrics.record(SUCCESSES, ended.sum())
        # Test mode: each env's first episode's successes (eval.json consecutive_successes, their mean).
        self.metrics.record(EPISODE_SUCCESSES, ended)
        self.successes.masked_fill_(mask, 0.0)

        # The hand: IGE's draw, default pose 0 + resetDofPosRandomInterval x a point of the joint range.
        u = torch.rand((n, self.num_dof), device=dev)
        span = self.dof_upper - self.dof_lower
        dof_pos = self.env_numbers["resetDofPosRandomInterval"] * (self.dof_lower + u * span)
        dof_pos = torch.clamp(dof_pos, self.dof_lower, self.dof_upper)
        for follower, leader, offset, ratio in self.couplings:
            dof_pos[:, follower] = offset + ratio * dof_pos[:, leader]
        dof_vel = (self.env_numbers["resetDofVelRandomInterval"]
                   * (2.0 * torch.rand((n, self.num_dof), device=dev) - 1.0))
        self.sim.reset_worlds(mask)
        self.sim.write_state(mask, dof_pos=dof_pos, dof_vel=dof_vel, refresh=False)
        rows = mask.unsqueeze(1)
        targets = dof_pos @ self.transmission.T  # each servo's length at the drawn pose: it holds it
        self.prev_targets.copy_(torch.where(rows, targets, self.prev_targets))
        self.sim.ctrl[:, :self.num_actions] = torch.where(rows, targets, self.sim.ctrl[:, :self.num_actions])
        self.actions.masked_fill_(rows, 0.0)
        if self.force_scale > 0.0:
            self.push_forces.masked_fill_(mask.view(-1, 1, 1), 0.0)
            self._draw_push_prob(mask)

        # The cube: its start position with uniform noise, a random orientation (IGE's draw), at rest.
        noise = self.env_numbers["resetPositionNoise"] * (2.0 * torch.rand((n, 3), device=dev) - 1.0)
        zero = torch.zeros((n, 3), device=dev)
        # No pose refresh: every observed quantity is read from qpos, the goal marker is a mocap body, and the next
        # physics step derives the poses (a Warp launch here would split the compiled step).
        self.sim.write_state(mask, root_pos=self.object_start_pos + noise, root_quat=random_rotation(n, dev),
                             root_lin_vel=zero, root_ang_vel=zero, asset="object", refresh=False)
        self._new_goals(mask)

    def _new_goals(self, mask: torch.Tensor) -> None:
        """New goal orientations for the masked envs, shown by the goal marker."""
        self.goal_quat.copy_(torch.where(mask.unsqueeze(1), random_rotation(self.num_envs, self.device),
                                         self.goal_quat))
        self.sim.mocap_quat[:, self.goal_marker] = self.goal_quat


def observation_type(value: object, valid: tuple[str, ...]) -> str:
    """``env.observationType``, checked: one of ``valid``."""
    if value not in valid:
        raise ConfigError(f"env.observationType={value!r} is invalid: choose one of {list(valid)}")
    return str(value)


def check_settings(k: dict[str, float]) -> None:
    """One-line errors for settings outside their domain."""
    if k["successTolerance"] <= 0.0:
        raise ConfigError(f"env.successTolerance={k['successTolerance']} is invalid: give an angle > 0 (rad)")
    if k["fallDistance"] <= 0.0:
        raise ConfigError(f"env.fallDistance={k['fallDistance']} is invalid: give a distance > 0 (m)")
    if k["rotEps"] <= 0.0:
        raise ConfigError(f"env.rotEps={k['rotEps']} is invalid: give a number > 0 (it bounds 1 / (rot_dist + "
                          "rotEps))")
    if not 0.0 < k["actionsMovingAverage"] <= 1.0:
        raise ConfigError(f"env.actionsMovingAverage={k['actionsMovingAverage']} is invalid: give a number in (0, 1]")
    if not 0.0 < k["averFactor"] <= 1.0:
        raise ConfigError(f"env.averFactor={k['averFactor']} is invalid: give a number in (0, 1]")


def random_rotation(n: int, device: torch.device | str) -> torch.Tensor:
    """IsaacGymEnvs' random orientation: R_x(pi u1) R_y(pi u2) with u1, u2 uniform in [-1, 1]. Not uniform over
    all rotations (DeXtreme adds a uniform draw); kept so that success counts compare with IGE's."""
    u = 2.0 * torch.rand((n, 2), device=device) - 1.0
    return quat_mul(quat_about_axis(math.pi * u[:, 0], 0), quat_about_axis(math.pi * u[:, 1], 1))


def hand_terms(object_pos: torch.Tensor, object_quat: torch.Tensor, goal_pos: torch.Tensor, goal_quat: torch.Tensor,
               success_tolerance: float, fall_distance: float) -> dict[str, torch.Tensor]:
    """IsaacGymEnvs' reward quantities: ``goal_dist`` (m), ``rot_dist`` (rad), ``reached`` (rot_dist within the
    tolerance; the position does not count) and ``fell`` (goal_dist >= fall_distance)."""
    goal_dist = torch.linalg.norm(object_pos - goal_pos, dim=-1)
    rot_dist = rotation_distance(object_quat, goal_quat)
    return {"goal_dist": goal_dist, "rot_dist": rot_dist, "reached": rot_dist <= success_tolerance,
            "fell": goal_dist >= fall_distance}
