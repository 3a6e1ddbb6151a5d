"""Trifinger: three fingers of a TriFinger Pro move a 6.5 cm cube to a goal pose (IsaacGymEnvs' task).

IsaacGymEnvs' ``Trifinger`` (isaacgymenvs/tasks/trifinger.py, cfg/task/Trifinger.yaml) with its actions, observation,
privileged critic state, reward terms, reset draws and success rule. The scene (``cfg/task/Trifinger.yaml``): the
robot and the arena (``assets/mjcf/trifinger.xml``), the cube (``env.assets.object``, free) and the goal marker
(``env.assets.goal``, a mocap copy of the cube at the goal pose).

Actions (9): joint torques (``command_mode: torque``, IGE's default) or joint targets of IGE's PD (``position``); with
``normalize_action`` an action of ±1 spans the command's range. The torque is clamped to ±0.36 N m, then (with
``apply_safety_damping``) IGE's safety damping times the joint speed is taken off and it is clamped again. It is
computed once per policy step, as in IGE.

Episodes end at the time limit only (IGE); ``termination_conditions.success`` defines the success metric: the cube
within ``position_tolerance`` of the goal position (and, at ``task_difficulty`` 4, within ``orientation_tolerance``
of its orientation) at the episode's last step. IGE logs it as ``consecutive_successes``.

Differences from IsaacGymEnvs, on purpose: quaternions are MuJoCo's (w, x, y, z), IGE's (x, y, z, w); the fingertip
states are those of the last physics step's kinematics (one physics step, 5 ms, older than the joint and cube state;
IGE refreshes them after the step); an episode's first step compares its fingertips and cube with where the reset
put them (IGE: with the previous episode's last fingertip positions); each reward term's ``activate`` is honoured and
``keypoints_dist`` has its own weight (IGE reads only ``keypoints_dist.activate``: the keypoint term then replaces
``object_dist`` and ``object_rot`` and takes ``object_dist``'s weight, the same 2000 in its YAML).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch

from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, OUTCOME, Metric
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.rewards import RewardTerms
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.utils.config import real_number
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import (
    quat_about_axis,
    quat_rotate,
    rotation_distance,
)

FINGERTIPS = ("finger_tip_link_0", "finger_tip_link_120", "finger_tip_link_240")  # IGE's fingertip frames, in order
# IGE's limits (trifinger.py _robot_limits, _object_limits, _robot_dof_gains), per finger (upper, middle, lower joint)
JOINT_LOW, JOINT_HIGH = (-0.33, 0.0, -2.7), (1.0, 1.57, 0.0)
DEFAULT_POSE = (0.0, 0.9, -2.0)
MAX_TORQUE = 0.36        # N m
MAX_JOINT_SPEED = 10.0   # rad/s: the observation's joint speed range
PD_STIFFNESS, PD_DAMPING = (10.0, 10.0, 10.0), (0.1, 0.3, 0.001)
SAFETY_DAMPING = (0.08, 0.08, 0.04)
OBJECT_POS_LOW, OBJECT_POS_HIGH = (-0.3, -0.3, 0.0), (0.3, 0.3, 0.3)  # m: the observation's cube and goal ranges
# IGE's arena and cube (trifinger.py ARENA_RADIUS, CuboidalObject(0.065))
ARENA_RADIUS = 0.195
CUBE_SIZE = 0.065
CUBE_RADIUS_3D = CUBE_SIZE * math.sqrt(3.0) / 2.0
MAX_COM_DISTANCE = ARENA_RADIUS - CUBE_RADIUS_3D  # the cube's centre stays this close to the arena's centre
GOAL_MAX_HEIGHT = 0.1
SPAWN_LIFT = 0.0015      # IGE starts the cube this far above the table
DIFFICULTIES = (-1, 1, 2, 3, 4)
COMMAND_MODES = ("torque", "position")
DISTRIBUTIONS = {"object_initial_state": ("default", "random", "none"),
                 "robot_initial_state": ("default", "random", "none")}
REWARD_TERMS = ("finger_move_penalty", "finger_reach_object_rate", "object_dist", "object_rot", "keypoints_dist")

CONSECUTIVE_SUCCESSES = Metric("consecutive_successes", EPISODE_SUM, success=True)
SUCCESSES_POS = Metric("consecutive_successes_pos", EPISODE_SUM)
SUCCESSES_QUAT = Metric("consecutive_successes_quat", EPISODE_SUM)
EPISODE_SUCCESS = Metric("consecutive_successes", OUTCOME, success=True)
# Test mode's view of how near the cube ends when it misses: its distance (m) and angle (rad) to the goal at each
# episode's last step, and whether its position alone is within the tolerance.
EPISODE_SUCCESS_POS = Metric("consecutive_successes_pos", OUTCOME)
FINAL_GOAL_DISTANCE = Metric("final_goal_distance", OUTCOME)
FINAL_GOAL_ANGLE = Metric("final_goal_angle", OUTCOME)


class Trifinger(VecTask):
    """Observation (41): joint positions, joint speeds, the cube's pose, the goal pose and the last actions, each over
    IGE's limits onto [-1, 1] with ``normalize_obs``. Critic state with ``asymmetric_obs`` (113): those values
    unscaled, then the cube's velocity, the fingertips' states, the joint torques and the fingertip wrenches.
    Actions (9): joint commands (module docstring)."""

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        self.settings = read_settings(env)
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        n, dev = self.num_envs, self.device
        missing = [name for name in FINGERTIPS if name not in self.sim.body_names]
        if missing:
            raise ConfigError(f"env.asset.assetFileName={env['asset']['assetFileName']!r}: the robot has no fingertip "
                              f"bodies {missing}; Trifinger observes {list(FINGERTIPS)}")
        self.tip_ids = self.sim.body_ids(list(FINGERTIPS))
        self.tip_sensors = [self.sim.sensor(f"{name}_{kind}", key="env.asset.assetFileName")
                            for name in FINGERTIPS for kind in ("force", "torque")]
        self.cube = self.sim.asset("object")
        if not self.cube.floating_base:
            raise ConfigError("env.assets.object.fixBaseLink=True: the cube must float; set fixBaseLink: False")
        self.goal_marker = self.sim.mocap_index(self.sim.asset("goal").body_names[0])

        def per_joint(values: tuple[float, ...]) -> torch.Tensor:
            return torch.tensor(values * 3, dtype=torch.float32, device=dev)

        self.joint_low, self.joint_high = per_joint(JOINT_LOW), per_joint(JOINT_HIGH)
        self.default_pose = per_joint(DEFAULT_POSE)
        self.pd_stiffness, self.pd_damping = per_joint(PD_STIFFNESS), per_joint(PD_DAMPING)
        self.safety_damping = per_joint(SAFETY_DAMPING)
        if self.settings["command_mode"] == "torque":
            self.command_low, self.command_high = -MAX_TORQUE * torch.ones(9, device=dev), MAX_TORQUE * torch.ones(
                9, device=dev)
        else:
            self.command_low, self.command_high = self.joint_low, self.joint_high
        self.pos_low = torch.tensor(OBJECT_POS_LOW, device=dev)
        self.pos_high = torch.tensor(OBJECT_POS_HIGH, device=dev)

        self.actions = torch.zeros((n, 9), device=dev)
        self.goal_pos = torch.zeros((n, 3), device=dev)
        self.goal_quat = torch.zeros((n, 4), device=dev)
        self.goal_quat[:, 0] = 1.0
        self.prev_tip_pos = torch.zeros((n, 3, 3), device=dev)
        self.prev_object_pos = torch.zeros((n, 3), device=dev)
        self.goal_distance = torch.zeros(n, device=dev)  # the cube's to the goal: position (m), orientation (rad)
        self.goal_angle = torch.zeros(n, device=dev)
        self.success_pos = torch.zeros(n, dtype=torch.bool, device=dev)
        self.success_quat = torch.zeros(n, dtype=torch.bool, device=dev)
        self.success = torch.zeros(n, dtype=torch.bool, device=dev)
        self.rewards = RewardTerms(self, self.settings["scales"], n, dev, key="env.reward_terms")
        self.build_observation_layouts()

    def check_action_size(self) -> None:
        if self.num_actions != 9 or self.sim.num_actuators != 9:
            raise ConfigError(f"Trifinger: env.numActions={self.num_actions} is invalid: give 9 (one command per "
                              f"joint), with a model of 9 joint motors (it has {self.sim.num_actuators})")

    # ------------------------------------------------------------------ pre-physics
    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.actions.copy_(actions)
        self.sim.ctrl[:, :9] = self.joint_torques(actions)

    def joint_torques(self, actions: torch.Tensor) -> torch.Tensor:
        """IGE's command -> torque: unscale (``normalize_action``), PD in position mode, clamp, safety damping."""
        s = self.settings
        command = unscale(actions, self.command_low, self.command_high) if s["normalize_action"] else actions
        q, qd = self.sim.dof_pos, self.sim.dof_vel
        torque = command if s["command_mode"] == "torque" else self.pd_stiffness * (command - q) - self.pd_damping * qd
        torque = torque.clamp(-MAX_TORQUE, MAX_TORQUE)
        if s["apply_safety_damping"]:
            torque = (torque - self.safety_damping * qd).clamp(-MAX_TORQUE, MAX_TORQUE)
        return torque

    # ------------------------------------------------------------------ post-physics
    def refresh_state(self) -> None:
        self.tip_pos = self.sim.xpos[:, self.tip_ids]
        self.object_pos, self.object_quat = self.cube.root_pos, self.cube.root_quat
        tol = self.settings["success"]
        self.goal_distance.copy_(torch.linalg.norm(self.goal_pos - self.object_pos, dim=-1))
        self.goal_angle.copy_(rotation_distance(self.object_quat, self.goal_quat))
        self.success_pos.copy_(self.goal_distance <= tol["position_tolerance"])
        self.success_quat.copy_(self.goal_angle <= tol["orientation_tolerance"])
        difficulty = self.settings["task_difficulty"]
        self.success.copy_(self.success_pos & self.success_quat if difficulty == 4 else self.success_pos)

    def compute_reward(self) -> None:
        self.rew_buf[:] = self.rewards.compute(self.nonfinite_buf)
        self.prev_tip_pos.copy_(self.tip_pos)
        self.prev_object_pos.copy_(self.object_pos)

    def _reward_finger_move_penalty(self) -> torch.Tensor:
        return finger_movement(self.tip_pos, self.prev_tip_pos, self.control_dt)

    def _reward_finger_reach_object_rate(self) -> torch.Tensor:
        on = (self.env_steps <= self.settings["reach_until"]).float()
        return on * finger_reach_rate(self.tip_pos, self.object_pos, self.prev_tip_pos, self.prev_object_pos,
                                      self.settings["norm_p"])

    def _reward_object_dist(self) -> torch.Tensor:
        return self.control_dt * lgsk_kernel(torch.linalg.norm(self.object_pos - self.goal_pos, dim=-1), 50.0, 2.0)

    def _reward_object_rot(self) -> torch.Tensor:
        angle = rotation_distance(self.object_quat, self.goal_quat)
        return self.control_dt / (3.0 * angle.abs() + 0.01)

    def _reward_keypoints_dist(self) -> torch.Tensor:
        return self.control_dt * keypoints_kernel(self.object_pos, self.object_quat, self.goal_pos, self.goal_quat)

    def declared_metrics(self) -> list[Metric]:
        return [*super().declared_metrics(), CONSECUTIVE_SUCCESSES, SUCCESSES_POS, SUCCESSES_QUAT, EPISODE_SUCCESS,
                EPISODE_SUCCESS_POS, FINAL_GOAL_DISTANCE, FINAL_GOAL_ANGLE]

    # ------------------------------------------------------------------ observation
    def observation_terms(self) -> list[ObsTerm]:
        return self._policy_terms(self.settings["normalize_obs"])

    def state_terms(self) -> list[ObsTerm] | None:
        if not self.settings["asymmetric_obs"]:
            return None
        cube, sim = self.cube, self.sim
        return self._policy_terms(False, prefix="raw_") + [
            ObsTerm("object_vel", 6, compute=lambda: torch.cat(                                # m/s, rad/s, world
                (cube.root_lin_vel, quat_rotate(cube.root_quat, cube.root_ang_vel)), dim=-1)),
            ObsTerm("fingertip_state", 39,                                   # pos, quat (w, x, y, z), lin, ang vel
                    compute=lambda: sim.body_states(self.tip_ids).reshape(self.num_envs, -1)),
            ObsTerm("joint_torque", 9, compute=lambda: sim.qfrc_actuator[:, :9]),             # N m
            ObsTerm("fingertip_wrench", 18, compute=lambda: torch.cat(self.tip_sensors, dim=1)),  # N, N m per tip
        ]

    def _policy_terms(self, normalize: bool, prefix: str = "") -> list[ObsTerm]:
        """IGE's observation, normalised or not; ``prefix`` names the critic's unnormalised copy apart."""
        sim, cube = self.sim, self.cube

        def scaled(fn, low, high):
            return (lambda: scale_transform(fn(), low, high)) if normalize else fn

        def pose(pos_fn, quat_fn):
            return lambda: torch.cat((scaled(pos_fn, self.pos_low, self.pos_high)(), quat_fn()), dim=-1)

        action_low, action_high = ((-1.0, 1.0) if self.settings["normalize_action"]
                                   else (self.command_low, self.command_high))
        return [
            ObsTerm(prefix + "dof_pos", 9, compute=scaled(lambda: sim.dof_pos, self.joint_low, self.joint_high)),   # rad
            ObsTerm(prefix + "dof_vel", 9, compute=scaled(lambda: sim.dof_vel, -MAX_JOINT_SPEED, MAX_JOINT_SPEED)),  # rad/s
            ObsTerm(prefix + "object_pose", 7, compute=pose(lambda: cube.root_pos, lambda: cube.root_quat)),         # m, quat
            ObsTerm(prefix + "goal_pose", 7, compute=pose(lambda: self.goal_pos, lambda: self.goal_quat)),           # m, quat
            ObsTerm(prefix + "actions", 9, compute=scaled(lambda: self.actions, action_low, action_high)),
        ]

    # ------------------------------------------------------------------ reset
    def reset_idx(self, mask: torch.Tensor) -> None:
        n, dev = self.num_envs, self.device
        ended = self.success & mask
        self.metrics.record(CONSECUTIVE_SUCCESSES, ended.float().sum())
        self.metrics.record(SUCCESSES_POS, (self.success_pos & mask).float().sum())
        self.metrics.record(SUCCESSES_QUAT, (self.success_quat & mask).float().sum())
        self.metrics.record(EPISODE_SUCCESS, ended.float())
        self.metrics.record(EPISODE_SUCCESS_POS, (self.success_pos & mask).float())
        self.metrics.record(FINAL_GOAL_DISTANCE, torch.where(mask, self.goal_distance, 0.0))
        self.metrics.record(FINAL_GOAL_ANGLE, torch.where(mask, self.goal_angle, 0.0))
        zero3 = torch.zeros((n, 3), device=dev)
        # New states first ("none" keeps the current one), then the reset of every carried quantity, then the writes.
        robot = self.settings["robot_initial_state"]
        dof_pos, dof_vel = self.sim.dof_pos.clone(), self.sim.dof_vel.clone()
        if robot["type"] != "none":
            noise = 2.0 * torch.rand((n, 18), device=dev) - 1.0
            random = robot["type"] == "random"
            dof_pos = self.default_pose + (robot["dof_pos_stddev"] * noise[:, :9] if random else 0.0)
            dof_vel = robot["dof_vel_stddev"] * noise[:, 9:] if random else torch.zeros((n, 9), device=dev)
        cube = self.cube
        pos, quat = cube.root_pos.clone(), cube.root_quat.clone()
        lin_vel, ang_vel = cube.root_lin_vel.clone(), cube.root_ang_vel.clone()
        kind = self.settings["object_initial_state"]["type"]
        if kind == "random":
            x, y = random_xy(n, MAX_COM_DISTANCE, dev)
            pos = torch.stack((x, y, torch.full_like(x, CUBE_SIZE / 2 + SPAWN_LIFT)), dim=-1)
            quat = random_yaw(n, dev)
        elif kind == "default":
            pos = torch.tensor([0.0, 0.0, CUBE_SIZE / 2], device=dev).expand(n, 3)
            quat = torch.tensor([1.0, 0.0, 0.0, 0.0], device=dev).expand(n, 4)
        if kind != "none":
            lin_vel, ang_vel = zero3, zero3
        self.sim.reset_worlds(mask)
        self.sim.write_state(mask, dof_pos=dof_pos.expand(n, 9), dof_vel=dof_vel, refresh=False)
        self.sim.write_state(mask, root_pos=pos, root_quat=quat, root_lin_vel=lin_vel, root_ang_vel=ang_vel,
                             asset="object", refresh=False)
        self.sim.refresh_kinematics()  # the fingertips where the reset put them: the first step's reward reads them
        rows = mask.view(-1, 1)
        self.prev_tip_pos.copy_(torch.where(rows.unsqueeze(-1), self.sim.xpos[:, self.tip_ids], self.prev_tip_pos))
        self.prev_object_pos.copy_(torch.where(rows, self.cube.root_pos, self.prev_object_pos))
        goal_pos, goal_quat = sample_goals(self.settings["task_difficulty"], n, dev)
        self.goal_pos.copy_(torch.where(rows, goal_pos, self.goal_pos))
        self.goal_quat.copy_(torch.where(rows, goal_quat, self.goal_quat))
        self.sim.mocap_pos[:, self.goal_marker] = self.goal_pos
        self.sim.mocap_quat[:, self.goal_marker] = self.goal_quat
        self.actions.masked_fill_(rows, 0.0)


# ---------------------------------------------------------------------------------------------------- settings
def read_settings(env: Mapping) -> dict:
    """The task's keys of the ``env`` section, checked (one-line errors naming the key)."""
    def pick(value, key: str, valid: tuple):
        if value not in valid:
            raise ConfigError(f"env.{key}={value!r} is invalid: choose one of {list(valid)}")
        return value

    s: dict = {"task_difficulty": pick(env.get("task_difficulty", 4), "task_difficulty", DIFFICULTIES),
               "command_mode": pick(env.get("command_mode", "torque"), "command_mode", COMMAND_MODES)}
    for key in ("asymmetric_obs", "normalize_obs", "apply_safety_damping", "normalize_action"):
        s[key] = pick(env.get(key, True), key, (True, False))
    reset = env.get("reset_distribution") or {}
    for part, valid in DISTRIBUTIONS.items():
        cfg = dict(reset.get(part) or {})
        cfg["type"] = pick(cfg.get("type", "default" if part == "robot_initial_state" else "random"),
                           f"reset_distribution.{part}.type", valid)
        for key in ("dof_pos_stddev", "dof_vel_stddev"):
            if part == "robot_initial_state":
                cfg[key] = real_number(cfg.get(key, 0.0), f"env.reset_distribution.{part}.{key}", low=0)
        s[part] = cfg
    terms = env.get("reward_terms") or {}
    unknown = [k for k in terms if k not in REWARD_TERMS]
    if unknown:
        raise ConfigError(f"env.reward_terms.{unknown[0]}: unknown reward term; terms: {list(REWARD_TERMS)}")
    s["scales"] = {}
    for name in REWARD_TERMS:
        term = terms.get(name) or {}
        active = pick(term.get("activate", False), f"reward_terms.{name}.activate", (True, False))
        weight = real_number(term.get("weight", 0.0), f"env.reward_terms.{name}.weight")
        s["scales"][name] = weight if active else 0.0
    reach = terms.get("finger_reach_object_rate") or {}
    s["norm_p"] = real_number(reach.get("norm_p", 2), "env.reward_terms.finger_reach_object_rate.norm_p", low=1)
    s["reach_until"] = real_number(reach.get("active_until_env_steps", 5.0e7),
                                   "env.reward_terms.finger_reach_object_rate.active_until_env_steps", low=0)
    success = ((env.get("termination_conditions") or {}).get("success")) or {}
    s["success"] = {key: real_number(success.get(key, default), f"env.termination_conditions.success.{key}", low=0)
                    for key, default in (("orientation_tolerance", 0.4), ("position_tolerance", 0.02))}
    return s


# ---------------------------------------------------------------------------------------------------- formulas
def scale_transform(x: torch.Tensor, low, high) -> torch.Tensor:
    """[low, high] -> [-1, 1] (IGE's scale_transform)."""
    return 2.0 * (x - 0.5 * (low + high)) / (high - low)


def unscale(x: torch.Tensor, low, high) -> torch.Tensor:
    """[-1, 1] -> [low, high] (IGE's unscale_transform)."""
    return 0.5 * (high - low) * x + 0.5 * (high + low)


def lgsk_kernel(x: torch.Tensor, scale: float, eps: float) -> torch.Tensor:
    """IGE's logistic kernel 1 / (e^(scale x) + eps + e^(-scale x)): 1 / (2 + eps) at x = 0, falling off with |x|."""
    scaled = x * scale
    return 1.0 / (scaled.exp() + eps + (-scaled).exp())


def cube_corners(pos: torch.Tensor, quat: torch.Tensor, size: float = CUBE_SIZE) -> torch.Tensor:
    """(N, 8, 3) world positions of a cube's corners at pose (pos, quat (w, x, y, z))."""
    signs = torch.tensor([[sx, sy, sz] for sx in (1.0, -1.0) for sy in (1.0, -1.0) for sz in (1.0, -1.0)],
                         device=pos.device)
    local = (0.5 * size * signs).expand(pos.shape[0], 8, 3)
    return pos.unsqueeze(1) + quat_rotate(quat.unsqueeze(1).expand(-1, 8, 4).reshape(-1, 4),
                                          local.reshape(-1, 3)).view(-1, 8, 3)


def keypoints_kernel(object_pos: torch.Tensor, object_quat: torch.Tensor, goal_pos: torch.Tensor,
                     goal_quat: torch.Tensor) -> torch.Tensor:
    """IGE's keypoint reward before weight x dt: the mean over the 8 corners of lgsk(corner distance, 30, 2)."""
    dist = torch.linalg.norm(cube_corners(object_pos, object_quat) - cube_corners(goal_pos, goal_quat), dim=-1)
    return lgsk_kernel(dist, 30.0, 2.0).mean(dim=-1)


def finger_movement(tip_pos: torch.Tensor, prev_tip_pos: torch.Tensor, dt: float) -> torch.Tensor:
    """Sum over the fingertips of their squared speed (finite difference over ``dt``)."""
    return ((tip_pos - prev_tip_pos) / dt).pow(2).sum(dim=(1, 2))


def finger_reach_rate(tip_pos: torch.Tensor, object_pos: torch.Tensor, prev_tip_pos: torch.Tensor,
                      prev_object_pos: torch.Tensor, p: float = 2.0) -> torch.Tensor:
    """Sum over the fingertips of the change of their p-norm distance to the cube's centre."""
    now = torch.linalg.vector_norm(tip_pos - object_pos.unsqueeze(1), ord=p, dim=-1)
    before = torch.linalg.vector_norm(prev_tip_pos - prev_object_pos.unsqueeze(1), ord=p, dim=-1)
    return (now - before).sum(dim=-1)


# ---------------------------------------------------------------------------------------------------- draws
def random_xy(n: int, radius: float, device) -> tuple[torch.Tensor, torch.Tensor]:
    """Uniform over a disc of ``radius`` (IGE's random_xy)."""
    r = radius * torch.sqrt(torch.rand(n, device=device))
    theta = 2.0 * math.pi * torch.rand(n, device=device)
    return r * torch.cos(theta), r * torch.sin(theta)


def random_yaw(n: int, device) -> torch.Tensor:
    """A rotation about z by U(0, 2 pi), (w, x, y, z)."""
    return quat_about_axis(2.0 * math.pi * torch.rand(n, device=device), 2)


def sample_goals(difficulty: int, n: int, device) -> tuple[torch.Tensor, torch.Tensor]:
    """IGE's goal pose per ``task_difficulty`` (module docstring of its _sample_object_goal_poses): (pos, quat)."""
    x, y = random_xy(n, MAX_COM_DISTANCE, device)
    quat = torch.zeros((n, 4), device=device)
    quat[:, 0] = 1.0
    z = torch.full((n,), CUBE_SIZE / 2, device=device)
    if difficulty == -1:
        quat = random_yaw(n, device)
    elif difficulty == 2:
        x, y = torch.zeros_like(x), torch.zeros_like(y)
        z = z + 0.05
    elif difficulty == 3:
        z = CUBE_SIZE / 2 + (GOAL_MAX_HEIGHT - CUBE_SIZE / 2) * torch.rand(n, device=device)
    elif difficulty == 4:
        # any orientation (a normalised Gaussian 4-vector: uniform over rotations), high enough for every one of them
        quat = torch.nn.functional.normalize(torch.randn((n, 4), device=device), dim=-1)
        z = CUBE_RADIUS_3D + (GOAL_MAX_HEIGHT - CUBE_RADIUS_3D) * torch.rand(n, device=device)
    return torch.stack((x, y, z), dim=-1), quat
