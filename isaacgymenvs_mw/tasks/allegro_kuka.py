"""AllegroKuka: a KUKA iiwa 7 arm with a Wonik Allegro hand lifts a cube off a table and turns it to goal poses in the
air (IsaacGymEnvs' AllegroKuka task, subtask ``reorientation``).

Facts from isaac-sim/IsaacGymEnvs (commit aeed298): isaacgymenvs/tasks/allegro_kuka/allegro_kuka_base.py,
allegro_kuka_reorientation.py, allegro_kuka_utils.py and cfg/task/AllegroKuka.yaml. The scene
(``cfg/task/AllegroKuka.yaml``): the robot (``env.asset``, ``assets/mjcf/allegro_kuka.xml``, 23 position servos)
with its base at (0, 0.8, 0), the 5 cm cube (``env.assets.object``) 0.1 m above the table (``env.assets.table``) and
the goal marker (``env.assets.goal``, a mocap copy of the cube). IGE's other two subtasks, regrasping and throw, are
subclasses in tasks/allegro_kuka_subtasks.py: they override the keypoints, the goal draw (``_sample_goals``), the
failure rule and what a success resets.

Actions (23): the arm's 7 targets move by ``dofSpeedScale`` x 1/60 s x the action (IGE's sim dt) each policy step;
the hand's 16 are absolute targets over each joint's range, smoothed by ``actionsMovingAverage``; all clamped to the
ranges. Reward (IGE's compute_kuka_reward, as reward terms): fingertips approaching the cube (until it is lifted),
its height (until lifted) and a one-off lifting bonus, the furthest keypoint approaching its goal (once lifted),
``reachGoalBonus`` near the goal, and joint speed penalties. Near the goal is the furthest of the cube's 4 keypoints
within ``successTolerance`` x ``keypointScale`` of its goal position; ``successSteps`` such steps make a success, after
which a new goal pose is drawn. The episode ends when the cube drops below z 0.1 m or the hand is 1.5 m from it
(failures), after ``maxConsecutiveSuccesses`` successes, or at the time limit (which a success restarts). The success
tolerance follows IGE's curriculum, on the device.
"""

from __future__ import annotations

import math

import torch

from isaacgymenvs_mw.tasks.base.env_keys import refuse_reward_scale
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, OUTCOME, RUNNING, Metric
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.rewards import RewardTerms
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.utils.config import whole_number
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import quat_rotate

IGE_SIM_DT = 1.0 / 60.0  # IGE's sim dt: the time unit of the arm's relative targets and of the push decay
NUM_ARM_DOFS = 7
# IGE's arm pose ("pose v1"); the hand's default pose is 0
ARM_DEFAULT_DOF_POS = (-1.571, 1.571, 0.0, 1.376, 0.0, 1.485, 2.358)
PALM_BODY = "iiwa7_link_7"  # IGE's palm handle
PALM_OFFSET = (0.0, -0.02, 0.16)  # the palm centre in that body's frame (m)
FINGERTIP_BODIES = ("index_link_3", "middle_link_3", "ring_link_3", "thumb_link_3")
FINGERTIP_OFFSETS = ((0.05, 0.005, 0.0), (0.05, 0.005, 0.0), (0.05, 0.005, 0.0), (0.06, 0.005, 0.0))
KEYPOINTS = ((1, 1, 1), (1, 1, -1), (-1, -1, 1), (-1, -1, -1))  # the reorientation task's, x half the keypoint span
# Goals: uniform in this box (m, world frame), and uniform over all orientations.
TARGET_VOLUME_MIN = (-0.4, 0.0, 0.68)
TARGET_VOLUME_MAX = (0.4, 0.35, 1.05)
FALL_HEIGHT = 0.1        # the cube below this (m) has fallen
HAND_FAR = 1.5           # a fingertip this far (m) from the cube: the episode ends
LIFT_OFFSET = 0.05       # IGE: z_lift = 0.05 + cube height - start height
LIFT_CLIP = 0.5
FINGERTIP_DELTA_CLIP = 10.0
KEYPOINT_DELTA_CLIP = 100.0
CURRICULUM_MIN_SUCCESSES = 3.0  # the tolerance tightens only when the last episodes averaged this many successes
REWARD_OBS_SCALE = 0.01  # the step's reward is observed x this
_NUMBER_KEYS = ("dofSpeedScale", "actionsMovingAverage", "resetPositionNoiseX", "resetPositionNoiseY",
                "resetPositionNoiseZ", "resetDofPosRandomIntervalFingers", "resetDofPosRandomIntervalArm",
                "resetDofVelRandomInterval", "forceScale", "forceDecay", "forceDecayInterval", "liftingBonusThreshold",
                "objectBaseSize", "keypointScale", "successTolerance", "targetSuccessTolerance",
                "toleranceCurriculumIncrement")
REWARD_SCALE_KEYS = {"fingertip_delta": "distanceDeltaRewScale", "lifting": "liftingRewScale",
                     "lift_bonus": "liftingBonus", "keypoint": "keypointRewScale", "bonus": "reachGoalBonus",
                     "kuka_actions_penalty": "kukaActionsPenaltyScale",
                     "allegro_actions_penalty": "allegroActionsPenaltyScale"}
SUCCESSES = Metric("successes", EPISODE_SUM, success=True)           # successes per ended episode (IGE's extras)
EPISODE_SUCCESSES = Metric("consecutive_successes", OUTCOME, success=True)  # test mode: each env's first episode
SUCCESS_TOLERANCE = Metric("success_tolerance", RUNNING)            # the curriculum's tolerance now (m)


class AllegroKuka(VecTask):
    """Observation (117, IGE's ``full_state``): joint positions over their ranges and speeds, the palm centre, the
    palm's orientation and velocities, the cube's, fingertips and keypoints relative to the palm, keypoints relative
    to their goals, the cube's scales, the episode's closest keypoint and fingertip distances, the lifted flag,
    log progress, log successes and the step's reward. Actions (23): arm and hand joint targets.

    Subclasses (the other subtasks) set ``keypoint_pattern`` (each keypoint's sign per axis, x half the keypoint
    span; the observation has 3 values per keypoint twice) and ``hand_far_ends_episode``, and override
    ``_sample_goals``."""

    keypoint_pattern: tuple[tuple[int, int, int], ...] = KEYPOINTS
    hand_far_ends_episode: bool = True  # IGE's reorientation rule only (its _extra_reset_rules)

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        missing = [k for k in _NUMBER_KEYS + tuple(REWARD_SCALE_KEYS.values()) if env.get(k) is None]
        if missing:
            raise ConfigError(f"AllegroKuka: the task YAML's env section lacks {missing}")
        refuse_reward_scale("AllegroKuka", env)
        self.k = {key: float(env[key]) for key in _NUMBER_KEYS}
        check_settings(env, self.k)
        self.max_consecutive_successes = whole_number(env.get("maxConsecutiveSuccesses", 0),
                                                      "env.maxConsecutiveSuccesses", 0)
        self.success_steps = whole_number(env.get("successSteps", 1), "env.successSteps", 1)
        self.curriculum_interval = whole_number(env.get("toleranceCurriculumInterval", 3000),
                                                "env.toleranceCurriculumInterval", 1)
        lo, hi = (float(v) for v in env["forceProbRange"])
        if not 0.0 < lo <= hi <= 1.0:
            raise ConfigError(f"env.forceProbRange={[lo, hi]} is invalid: give [low, high] with 0 < low <= high <= 1 "
                              "(the chance of a new push per policy step)")
        self.push_prob_log_range = (math.log(lo), math.log(hi))
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        n, dev, sim = self.num_envs, self.device, self.sim
        self.cube = sim.asset("object")
        if not self.cube.floating_base:
            raise ConfigError("env.assets.object.fixBaseLink=True: the cube must float (a free joint); set "
                              "fixBaseLink: False")
        self.dof_lower, self.dof_upper = sim.joint_limits()
        self.default_dof_pos = torch.zeros(sim.num_dof, device=dev)
        self.default_dof_pos[:NUM_ARM_DOFS] = torch.tensor(ARM_DEFAULT_DOF_POS, device=dev)
        self.reset_noise = torch.full((sim.num_dof,), self.k["resetDofPosRandomIntervalFingers"], device=dev)
        self.reset_noise[:NUM_ARM_DOFS] = self.k["resetDofPosRandomIntervalArm"]
        self.palm_ids = sim.body_ids([PALM_BODY])
        self.tip_ids = sim.body_ids(list(FINGERTIP_BODIES))
        self.palm_offset = torch.tensor(PALM_OFFSET, device=dev).expand(n, 3)
        self.tip_offsets = torch.tensor(FINGERTIP_OFFSETS, device=dev).expand(n, 4, 3)
        half_span = self.k["objectBaseSize"] * self.k["keypointScale"] / 2.0
        pattern = torch.tensor(self.keypoint_pattern, dtype=torch.float32, device=dev)
        self.num_keypoints = pattern.shape[0]
        self.keypoint_offsets = (pattern * half_span).expand(n, self.num_keypoints, 3)
        self.object_scales = torch.ones((n, 3), device=dev)  # the default cube: scale 1 on each axis
        free = self.cube.layout.free_qpos
        self.object_start_pos = torch.tensor(sim.mj_model.qpos0[free:free + 3], dtype=torch.float32, device=dev)
        self.position_noise = torch.tensor([self.k["resetPositionNoiseX"], self.k["resetPositionNoiseY"],
                                            self.k["resetPositionNoiseZ"]], device=dev)
        self.goal_marker = sim.mocap_index(sim.asset("goal").body_names[0])
        self.goal_pos = self.object_start_pos.repeat(n, 1)
        self.goal_quat = torch.zeros((n, 4), device=dev)
        self.goal_quat[:, 0] = 1.0

        self.prev_targets = torch.zeros((n, self.num_actions), device=dev)
        self.successes = torch.zeros(n, device=dev)
        self.prev_episode_successes = torch.zeros(n, device=dev)
        self.near_goal_steps = torch.zeros(n, dtype=torch.long, device=dev)
        self.lifted = torch.zeros(n, dtype=torch.bool, device=dev)
        self.closest_keypoint_max_dist = -torch.ones(n, device=dev)  # -1: set from the next measurement
        self.closest_fingertip_dist = -torch.ones((n, 4), device=dev)
        self.goal_reset = torch.zeros(n, dtype=torch.bool, device=dev)  # successes of this step: new goals
        # IGE's tolerance curriculum, kept on the device: no host sync in the step
        self.success_tolerance = torch.tensor(self.k["successTolerance"], device=dev)
        self.frame = torch.zeros((), dtype=torch.long, device=dev)
        self.last_curriculum_update = torch.zeros((), dtype=torch.long, device=dev)
        # IGE's pushes on the cube: a force in its frame that decays, replaced at random moments
        self.cube_body = self.cube.body_names[0]
        self.cube_mass = float(sim.mj_model.body(self.cube_body).mass[0])  # nominal, as IGE
        self.push_decay = self.k["forceDecay"] ** (IGE_SIM_DT / self.k["forceDecayInterval"])
        self.push_forces = torch.zeros((n, 1, 3), device=dev)
        self.push_prob = torch.zeros(n, device=dev)
        self._draw_push_prob(torch.ones(n, dtype=torch.bool, device=dev))
        if self.k["forceScale"] > 0.0:  # the force buffer exists before the step is compiled
            self.apply_body_forces(self.push_forces, bodies=[self.cube_body], frame="body")
        self.rewards = RewardTerms.from_env(self, env, n, dev, ige_keys=REWARD_SCALE_KEYS)
        self.terms: dict[str, torch.Tensor] = {}
        self._measure()
        self.build_observation_layouts()

    # ------------------------------------------------------------------ pre-physics
    def pre_physics_step(self, actions: torch.Tensor) -> None:
        arm = self.prev_targets[:, :NUM_ARM_DOFS] + self.k["dofSpeedScale"] * IGE_SIM_DT * actions[:, :NUM_ARM_DOFS]
        lo, hi = self.dof_lower, self.dof_upper
        hand = lo[NUM_ARM_DOFS:] + 0.5 * (actions[:, NUM_ARM_DOFS:] + 1.0) * (hi[NUM_ARM_DOFS:] - lo[NUM_ARM_DOFS:])
        alpha = self.k["actionsMovingAverage"]
        hand = alpha * hand + (1.0 - alpha) * self.prev_targets[:, NUM_ARM_DOFS:]
        targets = torch.clamp(torch.cat((arm, hand), dim=1), lo, hi)
        self.prev_targets.copy_(targets)
        self.sim.ctrl[:, :self.num_actions] = targets
        if self.k["forceScale"] > 0.0:
            self._push_cube()

    def _draw_push_prob(self, mask: torch.Tensor) -> None:
        """Each masked env's chance of a new push per policy step, log-uniform over env.forceProbRange (IGE)."""
        lo, hi = self.push_prob_log_range
        drawn = torch.exp(lo + (hi - lo) * torch.rand(self.num_envs, device=self.device))
        self.push_prob.copy_(torch.where(mask, drawn, self.push_prob))

    def _push_cube(self) -> None:
        """IGE's random forces: the push decays; with each env's chance a new one, Gaussian per axis of the cube's
        frame with standard deviation forceScale x the cube's mass (N), replaces it."""
        self.push_forces.mul_(self.push_decay)
        new = (torch.rand(self.num_envs, device=self.device) < self.push_prob).view(-1, 1, 1)
        fresh = torch.randn_like(self.push_forces) * (self.cube_mass * self.k["forceScale"])
        self.push_forces.copy_(torch.where(new, fresh, self.push_forces))
        self.apply_body_forces(self.push_forces, bodies=[self.cube_body], frame="body")

    # ------------------------------------------------------------------ post-physics
    def _measure(self) -> None:
        """IGE's compute_observations quantities: palm centre, fingertip points, keypoints and their distances; the
        episode's closest distances are initialised where they are unset (-1)."""
        sim = self.sim
        self.palm_state = sim.body_states(self.palm_ids, com=True)[:, 0]
        self.palm_center = self.palm_state[:, :3] + quat_rotate(self.palm_state[:, 3:7], self.palm_offset)
        tip_pos, tip_quat = sim.xpos[:, self.tip_ids], sim.xquat[:, self.tip_ids]
        self.tip_pos = tip_pos + quat_rotate(tip_quat.reshape(-1, 4), self.tip_offsets.reshape(-1, 3)).view_as(tip_pos)
        obj_pos, obj_quat = self.cube.root_pos, self.cube.root_quat
        self.tip_rel_object = self.tip_pos - obj_pos.unsqueeze(1)
        self.tip_dist = torch.linalg.norm(self.tip_rel_object, dim=-1)
        self.obj_keypoints = keypoints(obj_pos, obj_quat, self.keypoint_offsets)
        self.goal_keypoints = keypoints(self.goal_pos, self.goal_quat, self.keypoint_offsets)
        self.keypoints_max_dist = torch.linalg.norm(self.obj_keypoints - self.goal_keypoints, dim=-1).max(dim=-1).values
        unset = self.closest_fingertip_dist < 0.0
        self.closest_fingertip_dist.copy_(torch.where(unset, self.tip_dist, self.closest_fingertip_dist))
        unset = self.closest_keypoint_max_dist < 0.0
        self.closest_keypoint_max_dist.copy_(torch.where(unset, self.keypoints_max_dist,
                                                         self.closest_keypoint_max_dist))

    def refresh_state(self) -> None:
        """IGE's reward quantities in its order (lifting, fingertip deltas, keypoint delta, near goal), the
        success count and the tolerance curriculum, once per step."""
        self.sim.refresh_kinematics()  # palm and fingertips where the physics left them
        self._curriculum()
        self._measure()
        lifting, lift_bonus, self.lifted = lifting_terms(self.cube.root_pos[:, 2], self.object_start_pos[2],
                                                         self.lifted, self.k["liftingBonusThreshold"])
        approach = torch.clamp(self.closest_fingertip_dist - self.tip_dist, 0.0, FINGERTIP_DELTA_CLIP)
        torch.minimum(self.closest_fingertip_dist, self.tip_dist, out=self.closest_fingertip_dist)
        keypoint = torch.clamp(self.closest_keypoint_max_dist - self.keypoints_max_dist, 0.0, KEYPOINT_DELTA_CLIP)
        torch.minimum(self.closest_keypoint_max_dist, self.keypoints_max_dist, out=self.closest_keypoint_max_dist)
        near_goal = self.near_goal()
        self.near_goal_steps += near_goal.long()
        success = self.near_goal_steps >= self.success_steps
        self.successes += success.float()
        self.goal_reset.copy_(success)
        vel = self.sim.dof_vel
        self.terms = {"lifting": lifting, "lift_bonus": lift_bonus,
                      "fingertip_delta": approach.sum(dim=-1) * ~self.lifted, "keypoint": keypoint * self.lifted,
                      "bonus": near_goal.float() / self.success_steps,
                      "kuka_actions_penalty": -vel[:, :NUM_ARM_DOFS].abs().sum(dim=-1),
                      "allegro_actions_penalty": -vel[:, NUM_ARM_DOFS:].abs().sum(dim=-1)}
        if self.max_consecutive_successes > 0:
            self.progress_buf.masked_fill_(success, 0)  # IGE: the time limit counts from the last success

    def near_goal(self) -> torch.Tensor:
        """(num_envs,) bool: IGE's success test, the furthest keypoint within successTolerance x keypointScale of its
        goal (with one keypoint at the centre, the cube's centre that close to the goal position)."""
        return self.keypoints_max_dist <= self.success_tolerance * self.k["keypointScale"]

    def _curriculum(self) -> None:
        """IGE's tolerance_curriculum: every toleranceCurriculumInterval policy steps at most, if the episodes that
        ended last in each env averaged 3 successes or more, the tolerance x toleranceCurriculumIncrement, kept
        between targetSuccessTolerance and successTolerance."""
        self.frame += 1
        due = ((self.frame - self.last_curriculum_update >= self.curriculum_interval)
               & (self.prev_episode_successes.mean() >= CURRICULUM_MIN_SUCCESSES))
        tighter = torch.clamp(self.success_tolerance * self.k["toleranceCurriculumIncrement"],
                              min=self.k["targetSuccessTolerance"], max=self.k["successTolerance"])
        self.success_tolerance.copy_(torch.where(due, tighter, self.success_tolerance))
        self.last_curriculum_update.copy_(torch.where(due, self.frame, self.last_curriculum_update))
        self.metrics.record(SUCCESS_TOLERANCE, self.success_tolerance)

    def check_termination(self) -> torch.Tensor:
        # the cube fell below 0.1 m, or (reorientation) the hand is 1.5 m from it
        fell = self.cube.root_pos[:, 2] < FALL_HEIGHT
        if not self.hand_far_ends_episode:
            return fell
        return fell | (self.tip_dist.max(dim=-1).values > HAND_FAR)

    def check_success(self) -> torch.Tensor:
        # maxConsecutiveSuccesses successes (0: no limit): the episode ends, bootstrapped like a time-out
        if self.max_consecutive_successes <= 0:
            return torch.zeros_like(self.goal_reset)
        return self.successes >= self.max_consecutive_successes

    def longest_episode(self) -> int:
        # each success restarts the time limit: up to that many limits, plus the last
        return int(self.max_episode_length) * (self.max_consecutive_successes + 1)

    def compute_reward(self) -> None:
        self.rew_buf[:] = self.rewards.compute(self.nonfinite_buf)

    # Reward terms (IGE's compute_kuka_reward, one term per summand; values computed in refresh_state).
    def _reward_fingertip_delta(self) -> torch.Tensor:
        return self.terms["fingertip_delta"]

    def _reward_lifting(self) -> torch.Tensor:
        return self.terms["lifting"]

    def _reward_lift_bonus(self) -> torch.Tensor:
        return self.terms["lift_bonus"]

    def _reward_keypoint(self) -> torch.Tensor:
        return self.terms["keypoint"]

    def _reward_bonus(self) -> torch.Tensor:
        return self.terms["bonus"]

    def _reward_kuka_actions_penalty(self) -> torch.Tensor:
        return self.terms["kuka_actions_penalty"]

    def _reward_allegro_actions_penalty(self) -> torch.Tensor:
        return self.terms["allegro_actions_penalty"]

    def after_reset(self, new_episode: torch.Tensor) -> None:
        # A success in a running episode: a new goal pose, seen in this step's observation (IGE: the next step's).
        self._new_goals(self.goal_reset & ~new_episode)
        self.goal_reset.zero_()
        self.sim.refresh_kinematics()  # the reset poses: the observation reads the palm and fingertips
        self._measure()

    # ------------------------------------------------------------------ observation
    def observation_terms(self) -> list[ObsTerm]:
        sim, cube, n = self.sim, self.cube, self.num_envs
        kp = 3 * self.num_keypoints
        return [
            ObsTerm("dof_pos", sim.num_dof, compute=self._unscaled_dof_pos),                # -1 ... 1 over the range
            ObsTerm("dof_vel", sim.num_dof, compute=lambda: sim.dof_vel),                   # rad/s
            ObsTerm("palm_pos", 3, compute=lambda: self.palm_center),                       # m, world frame
            ObsTerm("palm_state", 10, compute=lambda: self.palm_state[:, 3:13]),            # quat (w, x, y, z), vels
            ObsTerm("object_state", 10, compute=lambda: torch.cat(
                (cube.root_quat, cube.root_lin_vel, quat_rotate(cube.root_quat, cube.root_ang_vel)), dim=-1)),
            ObsTerm("fingertip_rel_palm", 12,
                    compute=lambda: (self.tip_pos - self.palm_center.unsqueeze(1)).reshape(n, 12)),
            ObsTerm("keypoints_rel_palm", kp,
                    compute=lambda: (self.obj_keypoints - self.palm_center.unsqueeze(1)).reshape(n, kp)),
            ObsTerm("keypoints_rel_goal", kp,
                    compute=lambda: (self.obj_keypoints - self.goal_keypoints).reshape(n, kp)),
            ObsTerm("object_scales", 3, compute=lambda: self.object_scales),
            ObsTerm("closest_keypoint_max_dist", 1, compute=lambda: self.closest_keypoint_max_dist.unsqueeze(-1)),
            ObsTerm("closest_fingertip_dist", 4, compute=lambda: self.closest_fingertip_dist),
            ObsTerm("lifted_object", 1, compute=lambda: self.lifted.float().unsqueeze(-1)),
            ObsTerm("progress_log", 1, compute=lambda: torch.log(self.progress_buf / 10.0 + 1.0).unsqueeze(-1)),
            ObsTerm("successes_log", 1, compute=lambda: torch.log(self.successes + 1.0).unsqueeze(-1)),
            ObsTerm("reward", 1, REWARD_OBS_SCALE, compute=lambda: self.rew_buf.unsqueeze(-1)),
        ]

    def _unscaled_dof_pos(self) -> torch.Tensor:
        return (2.0 * self.sim.dof_pos - self.dof_upper - self.dof_lower) / (self.dof_upper - self.dof_lower)

    def declared_metrics(self) -> list[Metric]:
        return [*super().declared_metrics(), SUCCESSES, EPISODE_SUCCESSES, SUCCESS_TOLERANCE]

    # ------------------------------------------------------------------ reset
    def reset_idx(self, mask: torch.Tensor) -> None:
        n, dev, nd = self.num_envs, self.device, self.sim.num_dof
        ended = self.successes * mask
        self.metrics.record(SUCCESSES, ended.sum())
        self.metrics.record(EPISODE_SUCCESSES, ended)
        self.prev_episode_successes.copy_(torch.where(mask, self.successes, self.prev_episode_successes))
        self.successes.masked_fill_(mask, 0.0)

        # The robot: IGE's draw, default + noise x a uniform point of (range - default), clamped into the range.
        delta_lo, delta_hi = self.dof_lower - self.default_dof_pos, self.dof_upper - self.default_dof_pos
        u = torch.rand((n, nd), device=dev)
        dof_pos = self.default_dof_pos + self.reset_noise * (delta_lo + (delta_hi - delta_lo) * u)
        dof_pos = torch.clamp(dof_pos, self.dof_lower, self.dof_upper)
        dof_vel = self.k["resetDofVelRandomInterval"] * (2.0 * torch.rand((n, nd), device=dev) - 1.0)
        self.sim.reset_worlds(mask)
        self.sim.write_state(mask, dof_pos=dof_pos, dof_vel=dof_vel, refresh=False)
        rows = mask.unsqueeze(1)
        self.prev_targets.copy_(torch.where(rows, dof_pos, self.prev_targets))
        self.sim.ctrl[:, :self.num_actions] = self.prev_targets
        self.push_forces.masked_fill_(mask.view(-1, 1, 1), 0.0)
        self._draw_push_prob(mask)
        self._reset_object(mask)
        self._new_goals(mask)

    def _reset_object(self, mask: torch.Tensor) -> None:
        """IGE's reset_object_pose for the masked envs: the cube at its start position with uniform noise per axis,
        any orientation, at rest; not lifted, and the closest fingertip distances unset."""
        n, dev = self.num_envs, self.device
        noise = self.position_noise * (2.0 * torch.rand((n, 3), device=dev) - 1.0)
        zero = torch.zeros((n, 3), device=dev)
        self.sim.write_state(mask, root_pos=self.object_start_pos + noise, root_quat=random_quaternion(n, dev),
                             root_lin_vel=zero, root_ang_vel=zero, asset="object", refresh=False)
        self.lifted.masked_fill_(mask, False)
        self.closest_fingertip_dist.masked_fill_(mask.unsqueeze(1), -1.0)

    def _new_goals(self, mask: torch.Tensor) -> None:
        """New goals for the masked envs (IGE's reset_target_pose), shown by the goal marker."""
        self._sample_goals(mask)
        self.sim.mocap_pos[:, self.goal_marker] = self.goal_pos
        self.sim.mocap_quat[:, self.goal_marker] = self.goal_quat
        self.near_goal_steps.masked_fill_(mask, 0)
        self.closest_keypoint_max_dist.masked_fill_(mask, -1.0)

    def _sample_goals(self, mask: torch.Tensor) -> None:
        """IGE's reorientation _reset_target: goal positions uniform in the target box, orientations uniform."""
        rows = mask.unsqueeze(1)
        self.goal_pos.copy_(torch.where(rows, uniform_in_box(self.num_envs, self.device), self.goal_pos))
        self.goal_quat.copy_(torch.where(rows, random_quaternion(self.num_envs, self.device), self.goal_quat))


def check_settings(env, k: dict[str, float]) -> None:
    """One-line errors for what this port does not do and settings outside their domain."""
    if env.get("objectType", "block") != "block":
        raise ConfigError(f"env.objectType={env.get('objectType')!r} is invalid: IsaacGymEnvs' AllegroKuka has "
                          "'block' only")
    if env.get("randomizeObjectDimensions", False):
        raise ConfigError("env.randomizeObjectDimensions=True is not supported: give False (one cube of "
                          "env.objectBaseSize in every env)")
    if env.get("useRelativeControl", False):
        raise ConfigError("env.useRelativeControl=True is not supported (IsaacGymEnvs' AllegroKuka has absolute hand "
                          "targets only): give False")
    if env.get("observationType", "full_state") != "full_state":
        raise ConfigError(f"env.observationType={env.get('observationType')!r} is invalid: choose 'full_state'")
    if not 0.0 < k["actionsMovingAverage"] <= 1.0:
        raise ConfigError(f"env.actionsMovingAverage={k['actionsMovingAverage']} is invalid: give a number in (0, 1]")
    for key in ("objectBaseSize", "keypointScale", "successTolerance", "targetSuccessTolerance",
                "forceDecayInterval"):
        if k[key] <= 0.0:
            raise ConfigError(f"env.{key}={k[key]} is invalid: give a number > 0")
    if k["targetSuccessTolerance"] > k["successTolerance"]:
        raise ConfigError(f"env.targetSuccessTolerance={k['targetSuccessTolerance']} is invalid: give at most "
                          f"env.successTolerance ({k['successTolerance']})")
    if not 0.0 < k["toleranceCurriculumIncrement"] <= 1.0:
        raise ConfigError(f"env.toleranceCurriculumIncrement={k['toleranceCurriculumIncrement']} is invalid: give a "
                          "number in (0, 1]")
    if not 0.0 < k["forceDecay"] <= 1.0 or k["forceScale"] < 0.0:
        raise ConfigError(f"env.forceDecay={k['forceDecay']}, env.forceScale={k['forceScale']} are invalid: give a "
                          "decay in (0, 1] and a scale >= 0")


def keypoints(pos: torch.Tensor, quat: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
    """(n, K, 3) world positions of the keypoints ``offsets`` ((n, K, 3), body frame) of bodies at ``pos``, ``quat``
    (w, x, y, z)."""
    k = offsets.shape[1]
    q = quat.unsqueeze(1).expand(-1, k, 4).reshape(-1, 4)
    return pos.unsqueeze(1) + quat_rotate(q, offsets.reshape(-1, 3)).view(-1, k, 3)


def lifting_terms(object_z: torch.Tensor, start_z: torch.Tensor | float, lifted: torch.Tensor,
                  threshold: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """IGE's _lifting_reward: (lifting, lift bonus, lifted). z_lift = 0.05 + height - start height; lifting =
    clip(z_lift, 0, 0.5) while not lifted; lifted once z_lift > threshold (and for the rest of the episode); the
    bonus is 1 on the step it is first lifted."""
    z_lift = LIFT_OFFSET + object_z - start_z
    now = (z_lift > threshold) | lifted
    return torch.clamp(z_lift, 0.0, LIFT_CLIP) * ~now, (now & ~lifted).float(), now


def uniform_in_box(n: int, device: torch.device | str) -> torch.Tensor:
    """(n, 3) points uniform in IGE's target volume (origin (0, 0.05, 0.8) + extent, world frame)."""
    low = torch.tensor(TARGET_VOLUME_MIN, device=device)
    high = torch.tensor(TARGET_VOLUME_MAX, device=device)
    return low + torch.rand((n, 3), device=device) * (high - low)


def random_quaternion(n: int, device: torch.device | str) -> torch.Tensor:
    """IGE's get_random_quat (uniform over all rotations), as (w, x, y, z)."""
    u = torch.rand((n, 3), device=device)
    a, b = torch.sqrt(1.0 - u[:, 0]), torch.sqrt(u[:, 0])
    angle1, angle2 = 2.0 * math.pi * u[:, 1], 2.0 * math.pi * u[:, 2]
    return torch.stack((a * torch.sin(angle1), a * torch.cos(angle1), b * torch.sin(angle2), b * torch.cos(angle2)),
                       dim=-1)
