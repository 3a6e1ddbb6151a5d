"""BallBalance: a tripod tilts and lifts its tray to keep a dropped ball near the point 0.7 m above its floor's centre.

IsaacGymEnvs' ``BallBalance`` (isaac-sim/IsaacGymEnvs, isaacgymenvs/tasks/ball_balance.py and
cfg/task/BallBalance.yaml) with its observation, actions, reward, resets and failure rule. The model is
``assets/mjcf/ball_balance.xml`` (the "balance bot", written from the figures IGE builds its MJCF from) plus the ball,
``assets/mjcf/ball_balance_ball.xml``, a scene asset (IGE's second actor).

Actions (3): the rates of the position targets of the three knee drives (``lower_leg_joint<i>``: IGE's actuated dofs
1, 3, 5; the hinges at the tray, dofs 0, 2, 4, are free), integrated over the policy step as IGE does
(``target += dt * actionSpeedScale * action``, clamped to the joint ranges). The first step of an episode applies no
action: IGE zeroes the targets of the envs it resets in that step's ``pre_physics_step``.

The three feet are pinned to the ground by equality constraints (IGE: translational attractors), and the knee drives
carry 0.5 kg m² of armature that IGE's do not: with IGE's gains (kp 4000, kd 100) at IGE's dt 0.01 the pinned chain
diverges in MuJoCo without it, and with less it still does under the random actions of early training
(docs/config.md, "BallBalance"). The leg force sensors are MuJoCo's ``<force>`` / ``<torque>`` at each leg's hinge
on the tray, read by name (``env.legForceSensors``, ``env.legTorqueSensors``), not IsaacGym's sensors on the tray
body (the asset's header and docs/porting.md, "Sensors", say what differs).
"""

from __future__ import annotations

import math

import torch

from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.utils.errors import ConfigError

BALL = "ball"                   # the env.assets entry of the ball
BALL_RADIUS = 0.1               # m (IGE's create_sphere radius)
TARGET_HEIGHT = 0.7             # m: the reward's point (0, 0, 0.7) above the floor's centre (IGE)
SENSOR_SCALE = 1.0 / 20.0       # IGE's "lousy normalization" of the sensor readings
# IGE's ball resets: horizontal distance from the axis, drop height, inward speed, downward speed.
RESET_DIST = (0.001, 0.5)       # m
RESET_HEIGHT = (1.0, 2.0)       # m
RESET_HORIZONTAL_SPEED = 5.0    # m/s at most, scaled by the distance (a ball near the axis starts slow)
RESET_DOWN_SPEED = 5.0          # m/s


class BallBalance(VecTask):
    """Observation (24, IGE's layout): knee angles, knee speeds, ball position, ball linear velocity (world frame,
    which is the env's), then the three legs' sensor x forces, x torques, y torques, z torques, each / 20. Actions
    (3): knee target rates."""
    # done well when its episodes last to the time limit (the ball kept on the tray): sweeps and save_best follow it
    primary_metric = "timeout_fraction"

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        env = cfg["env"]
        n, dev = self.num_envs, self.device
        self.action_speed_scale = float(env.get("actionSpeedScale", 20.0))
        # The legs' MuJoCo sensors, one view per leg (no copies; each physics step rewrites them).
        self.leg_forces = self._leg_sensors(env, "legForceSensors")
        self.leg_torques = self._leg_sensors(env, "legTorqueSensors")
        self.ball = self.sim.asset(BALL)
        self.knees = [self.sim.dof_names.index(j) for j in self.sim.actuator_joints]
        self.knee_lower, self.knee_upper = self.sim.joint_limits(self.sim.actuator_joints)
        self.dof_position_targets = torch.zeros((n, 3), device=dev)
        self.fresh = torch.ones(n, dtype=torch.bool, device=dev)  # first step of an episode: no action (IGE)
        self.build_observation_layouts()

    def _leg_sensors(self, env, key: str) -> list[torch.Tensor]:
        names = list(env.get(key) or [])
        if len(names) != 3:
            raise ConfigError(f"env.{key}={names} is invalid: give the 3 legs' sensor names, leg 0 to 2")
        return [self.sim.sensor(str(name), key=f"env.{key}") for name in names]

    def check_action_size(self) -> None:
        # Three knee drives and nothing else: the actions are their target rates.
        if self.num_actions != 3 or self.sim.num_actuators != 3:
            raise ConfigError(
                f"BallBalance: env.numActions={self.num_actions} is invalid: give 3, with a position drive on each "
                f"knee (lower_leg_joint<i>) only (the model has {self.sim.num_actuators} actuators: "
                f"{self.sim.actuator_names})")

    # ------------------------------------------------------------------ before physics
    def pre_physics_step(self, actions: torch.Tensor) -> None:
        targets = self.dof_position_targets + self.control_dt * self.action_speed_scale * actions
        targets = torch.minimum(torch.maximum(targets, self.knee_lower), self.knee_upper)
        self.dof_position_targets.copy_(torch.where(self.fresh.view(-1, 1), torch.zeros_like(targets), targets))
        self.fresh.zero_()
        self.sim.ctrl.copy_(self.dof_position_targets)

    # ------------------------------------------------------------------ after physics
    def check_termination(self) -> torch.Tensor:
        return ball_dropped(self.ball.root_pos)

    def compute_reward(self) -> None:
        self.rew_buf[:] = compute_ball_balance_reward(self.ball.root_pos, self.ball.root_lin_vel)

    def observation_terms(self) -> list[ObsTerm]:
        sim, ball = self.sim, self.ball
        return [ObsTerm("dof_pos", 3, compute=lambda: sim.dof_pos[:, self.knees]),     # rad
                ObsTerm("dof_vel", 3, compute=lambda: sim.dof_vel[:, self.knees]),     # rad/s
                ObsTerm("ball_pos", 3, compute=lambda: ball.root_pos),                 # m
                ObsTerm("ball_lin_vel", 3, compute=lambda: ball.root_lin_vel),         # m/s, world frame
                # IGE reads component 0 of each sensor's force (the comment beside it says otherwise), then each
                # torque component over the three sensors.
                ObsTerm("leg_force_x", 3, scale=SENSOR_SCALE, compute=lambda: legs(self.leg_forces, 0)),    # N
                ObsTerm("leg_torque_x", 3, scale=SENSOR_SCALE, compute=lambda: legs(self.leg_torques, 0)),  # N m
                ObsTerm("leg_torque_y", 3, scale=SENSOR_SCALE, compute=lambda: legs(self.leg_torques, 1)),
                ObsTerm("leg_torque_z", 3, scale=SENSOR_SCALE, compute=lambda: legs(self.leg_torques, 2))]

    def reset_idx(self, mask: torch.Tensor) -> None:
        """The tripod back to its initial pose at rest, the ball dropped from IGE's random start."""
        n, dev = self.num_envs, self.device
        self.sim.reset_worlds(mask)
        dist = RESET_DIST[0] + (RESET_DIST[1] - RESET_DIST[0]) * torch.rand((n, 1), device=dev)
        angle = (2.0 * torch.rand((n, 1), device=dev) - 1.0) * math.pi
        direction = torch.cat((torch.cos(angle), torch.sin(angle)), dim=1)
        height = RESET_HEIGHT[0] + (RESET_HEIGHT[1] - RESET_HEIGHT[0]) * torch.rand((n, 1), device=dev)
        # Towards the axis, faster the farther out the ball starts.
        inward = (dist - RESET_DIST[0]) / (RESET_DIST[1] - RESET_DIST[0]) * RESET_HORIZONTAL_SPEED
        inward = inward * torch.rand((n, 1), device=dev)
        vel = torch.cat((-inward * direction, torch.full((n, 1), -RESET_DOWN_SPEED, device=dev)), dim=1)
        quat = torch.tensor([1.0, 0.0, 0.0, 0.0], device=dev).expand(n, 4)
        self.sim.write_state(mask, root_pos=torch.cat((dist * direction, height), dim=1), root_quat=quat,
                             root_lin_vel=vel, root_ang_vel=torch.zeros((n, 3), device=dev), asset=BALL)
        self.dof_position_targets.masked_fill_(mask.view(-1, 1), 0.0)
        self.fresh |= mask


def legs(sensors: list[torch.Tensor], axis: int) -> torch.Tensor:
    """(N, 3): component ``axis`` of each leg's (N, 3) sensor reading, leg 0 to 2."""
    return torch.stack([reading[:, axis] for reading in sensors], dim=1)


def ball_dropped(ball_pos: torch.Tensor) -> torch.Tensor:
    """IGE's failure rule: the ball's centre below 1.5 radii (it is on the ground, or nearly)."""
    return ball_pos[:, 2] < 1.5 * BALL_RADIUS


def compute_ball_balance_reward(ball_pos: torch.Tensor, ball_lin_vel: torch.Tensor) -> torch.Tensor:
    """IGE's reward 1 / (1 + d) · 1 / (1 + s): d the ball's distance to (0, 0, 0.7), s its speed."""
    target = torch.tensor([0.0, 0.0, TARGET_HEIGHT], device=ball_pos.device)
    dist = torch.linalg.norm(ball_pos - target, dim=-1)
    speed = torch.linalg.norm(ball_lin_vel, dim=-1)
    return 1.0 / (1.0 + dist) * (1.0 / (1.0 + speed))
