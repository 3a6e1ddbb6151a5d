"""Pendulum: keep an inverted pendulum upright with a torque motor at its hinge.

The README's "Write your own task" walks through this file. It lives outside the package, as a user's own task
would, and registers itself on import; train it with

    python train.py task=Pendulum task_module=examples.pendulum_task headless=True

Its settings are in cfg/task/Pendulum.yaml and cfg/train/PendulumPPO.yaml; its robot in assets/urdf/pendulum.urdf.
"""

from __future__ import annotations

import torch

from isaacgymenvs_mw.tasks import register_task
from isaacgymenvs_mw.tasks.base.vec_task import VecTask


class Pendulum(VecTask):
    """Observations [cos θ, sin θ, θ̇] with θ = 0 upright; action = hinge torque / maxTorque."""

    def __init__(self, cfg: dict, rl_device: str, sim_device: str, graphics_device_id: int, headless: bool,
                 virtual_screen_capture: bool = False, force_render: bool = False) -> None:
        # Read this task's YAML keys first: VecTask.__init__ builds the simulator and the buffers from cfg.
        env = cfg["env"]
        self.max_torque = float(env["maxTorque"])
        self.fall_angle = float(env["fallAngle"])
        self.max_episode_length = int(env["maxEpisodeLength"])
        self.reset_angle = float(env["resetAngle"])
        self.reset_velocity = float(env["resetVelocity"])
        self.reward_scales = {name: float(value) for name, value in env["rewards"].items()}
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        # Joints are found by their URDF name, not by position.
        self.hinge = self.sim.dof_names.index("hinge")

    def pre_physics_step(self, actions: torch.Tensor) -> None:
        """Actions arrive clipped to ±clipActions; the hinge's effort drive takes a torque in N m."""
        self.sim.ctrl[:, 0] = actions[:, 0] * self.max_torque

    def post_physics_step(self) -> None:
        """Reward and resets see the state the actions led to; observations see the state after resets."""
        self.progress_buf += 1
        self.compute_reward()
        self.reset_idx(self.reset_buf != 0)
        self.compute_observations()

    def compute_reward(self) -> None:
        """Score the state the actions led to; the formula is a plain function, so a test can check it alone."""
        self.rew_buf[:], self.reset_buf[:] = compute_pendulum_reward(
            angle=self.sim.dof_pos[:, self.hinge],
            velocity=self.sim.dof_vel[:, self.hinge],
            effort=self.sim.ctrl[:, 0] / self.max_torque,
            progress_buf=self.progress_buf,
            fall_angle=self.fall_angle,
            max_episode_length=self.max_episode_length,
            scales=self.reward_scales,
        )

    def compute_observations(self) -> None:
        """cos θ and sin θ rather than θ: they do not jump when the pole turns past ±π."""
        angle, velocity = self.sim.dof_pos[:, self.hinge], self.sim.dof_vel[:, self.hinge]
        self.obs_buf[:] = torch.stack((torch.cos(angle), torch.sin(angle), velocity), dim=-1)

    def reset_idx(self, env_ids: torch.Tensor) -> None:
        """Restart the selected envs at a random angle and speed near upright.

        ``env_ids`` is a boolean mask over all envs: every env draws a new state, and only the masked rows are
        written, so nothing waits on the device to find out which envs are done.
        """
        mask = self.env_mask(env_ids)
        shape = (self.num_envs, self.sim.num_dof)
        angle = self.reset_angle * (2.0 * torch.rand(shape, device=self.device) - 1.0)
        velocity = self.reset_velocity * (2.0 * torch.rand(shape, device=self.device) - 1.0)
        self.sim.reset_worlds(mask)
        self.sim.write_state(mask, dof_pos=angle, dof_vel=velocity)
        self.progress_buf.masked_fill_(mask, 0)


def compute_pendulum_reward(angle: torch.Tensor, velocity: torch.Tensor, effort: torch.Tensor,
                            progress_buf: torch.Tensor, fall_angle: float, max_episode_length: int,
                            scales: dict[str, float]) -> tuple[torch.Tensor, torch.Tensor]:
    """Reward upright·cos θ + velocity·θ̇² + effort·a² (+ fall on the step it falls); reset on a fall or at the cap.

    The hinge is continuous, so θ is wrapped to (-π, π] before it is compared with fallAngle.
    """
    fallen = torch.abs(torch.atan2(torch.sin(angle), torch.cos(angle))) > fall_angle
    reward = (scales["upright"] * torch.cos(angle)
              + scales["velocity"] * velocity * velocity
              + scales["effort"] * effort * effort
              + scales["fall"] * fallen.float())
    reset = fallen | (progress_buf >= max_episode_length - 1)
    return reward, reset.long()


register_task("Pendulum", Pendulum)
