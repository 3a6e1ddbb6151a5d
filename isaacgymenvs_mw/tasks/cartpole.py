"""Cartpole: push a cart along a rail so that the hinged pole stays upright (IsaacGymEnvs' task)."""

from __future__ import annotations

import math

import torch

from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.utils.config import whole_number


class Cartpole(VecTask):
    """Observations [cart pos, cart vel, pole angle, pole vel]; action = cart force / maxEffort."""

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        self.cfg = cfg
        env = cfg["env"]
        self.reset_dist = float(env["resetDist"])
        self.max_push_effort = float(env["maxEffort"])
        self.max_episode_length = whole_number(env.get("maxEpisodeLength", 500), "env.maxEpisodeLength", 2)
        self.reset_position_noise = float(env.get("resetPositionNoise", 0.1))
        self.reset_velocity_noise = float(env.get("resetVelocityNoise", 0.25))
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        names = self.sim.dof_names
        self.cart_dof = names.index("slider_to_cart")
        self.pole_dof = names.index("cart_to_pole")

    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.sim.ctrl[:, 0] = actions[:, 0] * self.max_push_effort

    def post_physics_step(self) -> None:
        self.progress_buf += 1
        self.compute_reward()
        self.reset_idx(self.reset_buf != 0)
        self.compute_observations()

    def compute_reward(self) -> None:
        q, qd = self.sim.dof_pos, self.sim.dof_vel
        self.rew_buf[:], self.reset_buf[:] = compute_cartpole_reward(
            cart_pos=q[:, self.cart_dof], cart_vel=qd[:, self.cart_dof],
            pole_angle=q[:, self.pole_dof], pole_vel=qd[:, self.pole_dof],
            reset_dist=self.reset_dist, progress_buf=self.progress_buf,
            max_episode_length=self.max_episode_length,
        )

    def compute_observations(self) -> None:
        q, qd = self.sim.dof_pos, self.sim.dof_vel
        self.obs_buf[:] = torch.stack(
            (q[:, self.cart_dof], qd[:, self.cart_dof], q[:, self.pole_dof], qd[:, self.pole_dof]), dim=-1
        )

    def reset_idx(self, env_ids: torch.Tensor) -> None:
        mask = self.env_mask(env_ids)
        shape = (self.num_envs, self.sim.num_dof)
        pos = self.reset_position_noise * (2.0 * torch.rand(shape, device=self.device) - 1.0)
        vel = self.reset_velocity_noise * (2.0 * torch.rand(shape, device=self.device) - 1.0)
        self.sim.reset_worlds(mask)
        # Observations read joint positions and velocities only; body poses follow at the next physics step.
        self.sim.write_state(mask, dof_pos=pos, dof_vel=vel, refresh=False)
        self.progress_buf.masked_fill_(mask, 0)


def compute_cartpole_reward(cart_pos: torch.Tensor, cart_vel: torch.Tensor, pole_angle: torch.Tensor,
                            pole_vel: torch.Tensor, reset_dist: float, progress_buf: torch.Tensor,
                            max_episode_length: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Reward 1 - θ² - 0.01|ẋ| - 0.005|θ̇|, -2 on failure; reset on failure or at the last step."""
    reward = 1.0 - pole_angle * pole_angle - 0.01 * torch.abs(cart_vel) - 0.005 * torch.abs(pole_vel)
    failed = (torch.abs(cart_pos) > reset_dist) | (torch.abs(pole_angle) > math.pi / 2)
    reward = torch.where(failed, torch.full_like(reward, -2.0), reward)
    reset = failed | (progress_buf >= max_episode_length - 1)
    return reward, reset.long()
