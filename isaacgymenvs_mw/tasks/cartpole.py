"""Cartpole: push a cart along a rail so that the hinged pole stays upright (IsaacGymEnvs' task)."""

from __future__ import annotations

import math

import torch

from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.vec_task import VecTask


class Cartpole(VecTask):
    """Observations [cart pos, cart vel, pole angle, pole vel]; action = cart force / maxEffort."""

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        self.reset_dist = float(env["resetDist"])
        self.max_push_effort = float(env["maxEffort"])
        self.reset_position_noise = float(env.get("resetPositionNoise", 0.1))
        self.reset_velocity_noise = float(env.get("resetVelocityNoise", 0.25))
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        names = self.sim.dof_names
        self.cart_dof = names.index("slider_to_cart")
        self.pole_dof = names.index("cart_to_pole")
        self.build_observation_layouts()

    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.sim.ctrl[:, 0] = actions[:, 0] * self.max_push_effort

    def check_termination(self) -> torch.Tensor:
        q = self.sim.dof_pos
        return cartpole_failed(q[:, self.cart_dof], q[:, self.pole_dof], self.reset_dist)

    def compute_reward(self) -> None:
        q, qd = self.sim.dof_pos, self.sim.dof_vel
        self.rew_buf[:] = compute_cartpole_reward(cart_vel=qd[:, self.cart_dof], pole_angle=q[:, self.pole_dof],
                                                  pole_vel=qd[:, self.pole_dof], failed=self.terminate_buf)

    def observation_terms(self) -> list[ObsTerm]:
        q, qd, cart, pole = self.sim.dof_pos, self.sim.dof_vel, self.cart_dof, self.pole_dof
        return [ObsTerm("cart_pos", 1, compute=lambda: q[:, cart:cart + 1]),     # m
                ObsTerm("cart_vel", 1, compute=lambda: qd[:, cart:cart + 1]),    # m/s
                ObsTerm("pole_angle", 1, compute=lambda: q[:, pole:pole + 1]),   # rad, 0 upright
                ObsTerm("pole_vel", 1, compute=lambda: qd[:, pole:pole + 1])]    # rad/s

    def reset_idx(self, mask: torch.Tensor) -> None:
        shape = (self.num_envs, self.sim.num_dof)
        pos = self.reset_position_noise * (2.0 * torch.rand(shape, device=self.device) - 1.0)
        vel = self.reset_velocity_noise * (2.0 * torch.rand(shape, device=self.device) - 1.0)
        self.sim.reset_worlds(mask)
        # Observations read joint positions and velocities only; body poses follow at the next physics step.
        self.sim.write_state(mask, dof_pos=pos, dof_vel=vel, refresh=False)


def cartpole_failed(cart_pos: torch.Tensor, pole_angle: torch.Tensor, reset_dist: float) -> torch.Tensor:
    """The cart left ±resetDist or the pole fell past horizontal."""
    return (torch.abs(cart_pos) > reset_dist) | (torch.abs(pole_angle) > math.pi / 2)


def compute_cartpole_reward(cart_vel: torch.Tensor, pole_angle: torch.Tensor, pole_vel: torch.Tensor,
                            failed: torch.Tensor) -> torch.Tensor:
    """Reward 1 - θ² - 0.01|ẋ| - 0.005|θ̇|, -2 on failure (IsaacGymEnvs' formula)."""
    reward = 1.0 - pole_angle * pole_angle - 0.01 * torch.abs(cart_vel) - 0.005 * torch.abs(pole_vel)
    return torch.where(failed, torch.full_like(reward, -2.0), reward)
