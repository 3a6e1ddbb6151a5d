"""Ingenuity: fly a two-rotor Mars helicopter to a target that moves every 5 s (IsaacGymEnvs' task).

IsaacGymEnvs' ``Ingenuity`` (isaacgymenvs/tasks/ingenuity.py) with its observation, actions, reward, target draws,
resets and failure rule, under Mars gravity (3.721 m/s², the task YAML's ``sim.gravity``); the model is
``assets/mjcf/ingenuity.xml``, written from the figures IGE builds its model from, and the target is shown by the
mocap sphere ``assets/mjcf/ingenuity_marker.xml`` (``env.assets.marker``).

Actions (6, IGE's order), per rotor i (0: lower, 1: upper) at columns 3i .. 3i+2: the vertical thrust
``a[3i+2] · 2000 · dt`` N (dt the policy step, 0.01 s: ±20 N at ±1; IGE allows it negative), and the lateral
components ``thrust · clamp(a[3i:3i+2], ±0.2)`` along the rotor's x and y axes. The actions set the forces directly
(IGE's Quadcopter integrates its actions; Ingenuity does not). The first step of an episode applies no force (IGE
zeroes the forces of the envs it resets in that step).

Thrust: a force in each rotor body's own frame at its centre of mass, ``apply_body_forces(frame="body")``, which is
IGE's ``apply_rigid_body_force_tensors(..., LOCAL_SPACE)`` on its two ``rotor_physics_<i>`` bodies. The model has no
actuators.
"""

from __future__ import annotations


import torch

from isaacgymenvs_mw.tasks.base.metrics import Metric
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.tasks.quadcopter import TARGET_DISTANCE, check_rotor_bodies, flight_terms
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import quat_axis

ROTOR_BODIES = ["rotor_physics_0", "rotor_physics_1"]
THRUST_ACTION_SPEED_SCALE = 2000.0  # IGE: the vertical thrust is action x this x dt (N)
THRUST_UPPER_LIMIT = 2000.0         # IGE: |action x scale| is clamped to this before the x dt
THRUST_LATERAL_COMPONENT = 0.2      # IGE: the lateral fractions are clamped to +-this
TARGET_INTERVAL = 500               # IGE: a new target every 500 policy steps of an episode (5 s)
TARGET_XY = 5.0                     # IGE: target x, y ~ U(-5, 5) m
TARGET_Z = (1.0, 2.0)               # IGE: target z ~ U(1, 2) m
FAIL_DISTANCE = 8.0                 # IGE: an episode fails beyond 8 m from the target
FAIL_HEIGHT = 0.5                   # IGE: ... or with the craft below 0.5 m


class Ingenuity(VecTask):
    """Observation (13): target offset / 3, root quaternion (w, x, y, z), linear velocity / 2, angular velocity / π
    (world frame). Actions (6): per rotor, lateral x and y fractions and the vertical thrust."""

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        self.rotor_bodies = list(env.get("rotorBodies", ROTOR_BODIES))
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        check_rotor_bodies(self.rotor_bodies, 2, self.sim.body_names, env)
        n, dev = self.num_envs, self.device
        self.forces = torch.zeros((n, 2, 3), device=dev)
        self.fresh = torch.ones(n, dtype=torch.bool, device=dev)  # first step of an episode: no force (IGE)
        self.target = torch.zeros((n, 3), device=dev)
        self.target[:, 2] = 1.0                                    # IGE's initial target, before the first draw
        self.marker = self.sim.mocap_index(self.sim.asset("marker").body_names[0])
        self.initial_root_pos = self.sim.root_pos[0].clone()
        self.initial_root_quat = self.sim.root_quat[0].clone()
        # Zero forces now: the simulator's force buffer exists before the step is compiled (as Quadcopter does).
        self.apply_body_forces(self.forces, bodies=self.rotor_bodies, frame="body")
        self.build_observation_layouts()

    def check_action_size(self) -> None:
        # 6 actions, no actuators: the thrusts are forces on the rotor bodies (module docstring).
        if self.num_actions != 6 or self.sim.num_actuators != 0:
            raise ConfigError(
                f"Ingenuity: env.numActions={self.num_actions} is invalid: give 6 (per rotor: lateral x, y fractions "
                f"and vertical thrust), with a model without actuators (it has {self.sim.num_actuators})")

    def pre_physics_step(self, actions: torch.Tensor) -> None:
        # IGE draws a new target for every env whose episode has run a multiple of 500 steps (its reset draws one
        # too: here in reset_idx, so an episode's first step keeps the target its first observation showed).
        due = (self.progress_buf > 0) & (self.progress_buf % TARGET_INTERVAL == 0)
        self.set_targets(due)
        self.forces.copy_(ingenuity_forces(actions, self.control_dt))
        self.forces.masked_fill_(self.fresh.view(-1, 1, 1), 0.0)
        self.fresh.zero_()
        self.apply_body_forces(self.forces, bodies=self.rotor_bodies, frame="body")

    def set_targets(self, mask: torch.Tensor) -> None:
        """New targets for the envs of ``mask`` (IGE's set_targets), and the marker moved there."""
        drawn = draw_targets(self.num_envs, self.device)
        self.target.copy_(torch.where(mask.view(-1, 1), drawn, self.target))
        self.sim.mocap_pos[:, self.marker] = self.target

    def check_termination(self) -> torch.Tensor:
        return ingenuity_failed(self.sim.root_pos, self.target)

    def declared_metrics(self) -> list[Metric]:
        return [*super().declared_metrics(), TARGET_DISTANCE]

    def compute_reward(self) -> None:
        self.rew_buf[:] = compute_ingenuity_reward(self.sim.root_pos, self.sim.root_quat,
                                                   self.sim.root_ang_vel_world(), self.target)
        if self.metrics.evaluating:  # test mode: how far from the target it flies, step by step (eval.json)
            self.metrics.record(TARGET_DISTANCE, torch.linalg.norm(self.sim.root_pos - self.target, dim=-1))

    def observation_terms(self) -> list[ObsTerm]:
        return flight_terms(self.sim, lambda: self.target)

    def reset_idx(self, mask: torch.Tensor) -> None:
        n, dev = self.num_envs, self.device
        self.sim.reset_worlds(mask)
        self.set_targets(mask)
        pos = self.initial_root_pos.expand(n, 3).clone()
        pos[:, 0:2] += 3.0 * torch.rand((n, 2), device=dev) - 1.5          # IGE: x, y += U(-1.5, 1.5)
        pos[:, 2] += 1.7 * torch.rand(n, device=dev) - 0.2                 # IGE: z += U(-0.2, 1.5)
        self.sim.write_state(mask, root_pos=pos, root_quat=self.initial_root_quat.expand(n, 4),
                             root_lin_vel=torch.zeros((n, 3), device=dev), root_ang_vel=torch.zeros((n, 3), device=dev))
        self.fresh |= mask


def draw_targets(n: int, device) -> torch.Tensor:
    """IGE's target draw: x, y ~ U(-5, 5) m, z ~ U(1, 2) m; (n, 3)."""
    target = torch.rand((n, 3), device=device)
    target[:, 0:2] = 2.0 * TARGET_XY * target[:, 0:2] - TARGET_XY
    target[:, 2] = TARGET_Z[0] + (TARGET_Z[1] - TARGET_Z[0]) * target[:, 2]
    return target


def ingenuity_forces(actions: torch.Tensor, dt: float) -> torch.Tensor:
    """IGE's action mapping: (num_envs, 6) actions -> (num_envs, 2, 3) rotor forces in the rotors' frames (N)."""
    a = actions.view(-1, 2, 3)
    vertical = dt * (a[:, :, 2] * THRUST_ACTION_SPEED_SCALE).clamp(-THRUST_UPPER_LIMIT, THRUST_UPPER_LIMIT)
    lateral = vertical.unsqueeze(-1) * a[:, :, 0:2].clamp(-THRUST_LATERAL_COMPONENT, THRUST_LATERAL_COMPONENT)
    return torch.cat((lateral, vertical.unsqueeze(-1)), dim=-1)


def ingenuity_failed(root_pos: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """IGE's rule: more than 8 m from the target, or the body below 0.5 m."""
    return (torch.linalg.norm(root_pos - target, dim=-1) > FAIL_DISTANCE) | (root_pos[:, 2] < FAIL_HEIGHT)


def compute_ingenuity_reward(root_pos: torch.Tensor, root_quat: torch.Tensor, root_ang_vel: torch.Tensor,
                             target: torch.Tensor) -> torch.Tensor:
    """IGE's reward p + p (u + s): p = 1 / (1 + d²) with d the distance to the target, u = 5 / (1 + (1 - z_up)²)
    with z_up the z component of the body's z axis, s = 1 / (1 + ω_z²) with ω_z the world-frame yaw rate.
    ``root_quat`` is (w, x, y, z)."""
    dist = torch.linalg.norm(root_pos - target, dim=-1)
    pos_reward = 1.0 / (1.0 + dist * dist)
    tilt = torch.abs(1.0 - quat_axis(root_quat, 2)[:, 2])
    up_reward = 5.0 / (1.0 + tilt * tilt)
    spin = torch.abs(root_ang_vel[:, 2])
    spin_reward = 1.0 / (1.0 + spin * spin)
    return pos_reward + pos_reward * (up_reward + spin_reward)
