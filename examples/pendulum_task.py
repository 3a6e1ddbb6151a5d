"""Pendulum: keep an inverted pendulum upright with a torque motor at its hinge.

The README's "Write your own task" walks through this file. It lives outside the package, as a user's own task
would, and registers itself on import; train it with

    python train.py task=Pendulum task_module=examples.pendulum_task headless=True

Its settings are in cfg/task/Pendulum.yaml and cfg/train/PendulumPPO.yaml; its robot in assets/urdf/pendulum.urdf.
"""

from __future__ import annotations

import torch

from isaacgymenvs_mw.tasks import register_task
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.vec_task import VecTask


class Pendulum(VecTask):
    """Observations [cos θ, sin θ, θ̇] with θ = 0 upright; action = hinge torque / maxTorque."""

    def __init__(self, cfg: dict, rl_device: str, sim_device: str, graphics_device_id: int, headless: bool,
                 virtual_screen_capture: bool = False, force_render: bool = False) -> None:
        # Read this task's YAML keys first: VecTask.__init__ builds the simulator and the buffers from cfg.
        env = cfg["env"]
        self.max_torque = float(env["maxTorque"])
        self.fall_angle = float(env["fallAngle"])
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

    def check_termination(self) -> torch.Tensor:
        """A fall ends the episode; VecTask adds the time-out at env.episodeLength_s."""
        return pendulum_fallen(self.sim.dof_pos[:, self.hinge], self.fall_angle)

    def compute_reward(self) -> None:
        """Score the state the actions led to; the formula is a plain function, so a test can check it alone."""
        self.rew_buf[:] = compute_pendulum_reward(
            angle=self.sim.dof_pos[:, self.hinge],
            velocity=self.sim.dof_vel[:, self.hinge],
            effort=self.sim.ctrl[:, 0] / self.max_torque,
            fallen=self.terminate_buf,
            scales=self.reward_scales,
        )

    def observation_terms(self) -> list[ObsTerm]:
        """cos θ and sin θ rather than θ: they do not jump when the pole turns past ±π."""
        hinge = slice(self.hinge, self.hinge + 1)  # (numEnvs, 1) views: the lambdas read each step's state
        angle, velocity = self.sim.dof_pos[:, hinge], self.sim.dof_vel[:, hinge]
        return [ObsTerm("cos_angle", 1, compute=lambda: torch.cos(angle)),
                ObsTerm("sin_angle", 1, compute=lambda: torch.sin(angle)),
                ObsTerm("angular_velocity", 1, compute=lambda: velocity)]  # rad/s

    def reset_idx(self, mask: torch.Tensor) -> None:
        """Restart the masked envs at a random angle and speed near upright."""
        shape = (self.num_envs, self.sim.num_dof)
        angle = self.reset_angle * (2.0 * torch.rand(shape, device=self.device) - 1.0)
        velocity = self.reset_velocity * (2.0 * torch.rand(shape, device=self.device) - 1.0)
        self.sim.reset_worlds(mask)
        self.sim.write_state(mask, dof_pos=angle, dof_vel=velocity)


def pendulum_fallen(angle: torch.Tensor, fall_angle: float) -> torch.Tensor:
    """|θ| past fallAngle; the hinge is continuous, so θ is wrapped to (-π, π] first."""
    return torch.abs(torch.atan2(torch.sin(angle), torch.cos(angle))) > fall_angle


def compute_pendulum_reward(angle: torch.Tensor, velocity: torch.Tensor, effort: torch.Tensor,
                            fallen: torch.Tensor, scales: dict[str, float]) -> torch.Tensor:
    """Reward upright·cos θ + velocity·θ̇² + effort·a² (+ fall on the step it falls)."""
    return (scales["upright"] * torch.cos(angle)
            + scales["velocity"] * velocity * velocity
            + scales["effort"] * effort * effort
            + scales["fall"] * fallen.float())


register_task("Pendulum", Pendulum)
