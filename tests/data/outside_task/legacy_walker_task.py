"""A task written outside the repository against the public task API of 2026-11-27 (before VecTask had
``env_steps``), kept unchanged as a compatibility fixture: it keeps its own device counter of env steps under the
name ``env_steps`` (as a Trifinger port did), rebinds ``obs_buf`` as IsaacGymEnvs' tasks do, and writes its own
``post_physics_step``. tests/workflow/test_public_names.py builds, trains and evaluates it only through the documented
outside-task path (``task_module=`` and ``--config-dir``)."""

import torch

from isaacgymenvs_mw.tasks import register_task
from isaacgymenvs_mw.tasks.base.vec_task import VecTask


class LegacyWalker(VecTask):
    """Keep the torso up with the hip motors; the height reward fades in over the first 64 env steps of the run."""

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless, virtual_screen_capture=False,
                 force_render=False):
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless, virtual_screen_capture,
                         force_render)
        self.env_steps = torch.zeros((), dtype=torch.float64, device=self.device)  # this task's own counter

    def pre_physics_step(self, actions):
        self.sim.ctrl[:] = actions

    def post_physics_step(self):
        self.progress_buf += 1
        self.env_steps += self.num_envs
        fade_in = torch.clamp(self.env_steps / 64.0, max=1.0).float()
        self.rew_buf[:] = fade_in * self.sim.root_pos[:, 2]
        self.reset_buf[:] = (self.progress_buf >= self.max_episode_length - 1).long()
        self.reset_idx(self.reset_buf != 0)
        self.compute_observations()

    def reset_idx(self, env_ids):
        mask = self.env_mask(env_ids)
        self.sim.reset_worlds(mask)
        self.sim.refresh_kinematics()
        self.progress_buf.masked_fill_(mask, 0)

    def compute_observations(self):
        self.obs_buf = torch.cat((self.sim.root_pos[:, 2:3], self.sim.dof_pos, self.sim.dof_vel), dim=-1)


register_task("LegacyWalker", LegacyWalker)
