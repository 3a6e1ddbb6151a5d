"""HumanoidAMP: IsaacGymEnvs' AMP humanoid imitating a motion clip (isaacgymenvs/tasks/humanoid_amp.py and
tasks/amp/humanoid_amp_base.py); settings in cfg/task/HumanoidAMP.yaml, the model assets/mjcf/amp_humanoid.xml, the
clips assets/amp/motions/.

The task's own reward is IsaacGymEnvs': 1 per step. The style reward comes from a discriminator trained by the
learner (learning/amp.py) on the AMP observations this task exposes: ``amp_obs`` ((num_envs, numAMPObsSteps x 105),
the step's transition, newest first, written before the step's resets) and ``fetch_amp_obs_demo(n)`` (the same from
the motion library).

Observation (105): tasks/amp/observations.py. Actions (28): PD targets, one per joint in dof order, target =
offset + scale x action, with IsaacGymEnvs' ranges: [-pi, pi] for each hinge of a 3-dof joint, the 1-dof joint's
range widened 1.4 times about its middle. Episodes start from a random frame of the clip (``stateInit``: Random),
its first frame (Start), the default pose (Default), or either at ``hybridInitProb`` (Hybrid); they end after
``episodeLength_s`` or on a fall: a body other than the ``contactBodies`` touches something while a body other than
them is below ``terminationHeight`` (after the episode's first 2 steps).

Where this differs from IsaacGymEnvs: joint coordinates are MuJoCo hinge angles (tasks/amp/motion_library.py);
a contact is a force component of magnitude over 0.1 N (IsaacGymEnvs compares the signed PhysX components with
+0.1); the Default start pose is the MJCF's zero pose, arms hanging (IsaacGymEnvs' sets the shoulders' x hinges to
+-pi/2, outside the MJCF's ranges; clamped into them, at +-pi/4, the arms cross into the chest and each other, 1-5 cm
deep, and the contact ends the episode at once).
"""

from __future__ import annotations

import math
from enum import Enum

import torch

from isaacgymenvs_mw.sim import ModelRequest
from isaacgymenvs_mw.tasks.amp.motion_library import (
    JointGroup,
    MotionLibrary,
    motion_files,
)
from isaacgymenvs_mw.tasks.amp.observations import dof_obs_size, humanoid_observation
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.sim_factory import ASSETS_DIR
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.utils.config import real_number, whole_number
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import quat_rotate_inverse

MOTIONS_DIR = ASSETS_DIR / "amp" / "motions"


class StateInit(Enum):
    Default = 0
    Start = 1
    Random = 2
    Hybrid = 3


class HumanoidAMP(VecTask):
    """Imitate the style of a motion clip; observation 105, actions 28 PD targets (module docstring)."""

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        init = env.get("stateInit", "Random")
        if init not in StateInit.__members__:
            raise ConfigError(f"env.stateInit={init!r} is invalid: give one of {list(StateInit.__members__)}")
        self.state_init = StateInit[init]
        self.hybrid_init_prob = real_number(env.get("hybridInitProb", 0.5), "env.hybridInitProb", 0.0, 1.0)
        self.num_amp_obs_steps = whole_number(env.get("numAMPObsSteps", 2), "env.numAMPObsSteps", 2)
        self.local_root_obs = bool(env.get("localRootObs", False))
        self.termination_height = real_number(env.get("terminationHeight", 0.5), "env.terminationHeight")
        self.early_termination = bool(env.get("enableEarlyTermination", True))
        if not env.get("pdControl", True):
            raise ConfigError("env.pdControl=False is not supported: the MJCF's actuators are PD servos; give True")
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        self._init_joints()
        self._init_bodies(env)
        self.motion_lib = MotionLibrary(motion_files(env.get("motion_file", "amp_humanoid_run.npy"), MOTIONS_DIR),
                                        self.joint_groups, self.key_bodies, self.device)
        n, dev = self.num_envs, self.device
        self.num_amp_obs_per_step = 1 + 6 + 3 + 3 + dof_obs_size(self.group_sizes) + self.sim.num_dof + 3 * len(
            self.key_bodies)
        self.num_amp_obs = self.num_amp_obs_steps * self.num_amp_obs_per_step
        self._amp_hist = torch.zeros(n, self.num_amp_obs_steps, self.num_amp_obs_per_step, device=dev)
        self.amp_obs = torch.zeros(n, self.num_amp_obs, device=dev)  # the last step's transitions, before resets
        self._obs = torch.zeros(n, self.num_amp_obs_per_step, device=dev)
        self.build_observation_layouts()

    # ------------------------------------------------------------------ model
    def model_request(self) -> ModelRequest:
        request = super().model_request()
        self._sensed_bodies = [b for b in request.body_names() if b != "world"]
        request.contact_bodies = self._sensed_bodies  # every body: the fall rule reads their contacts
        return request

    def _init_joints(self) -> None:
        m, sim = self.sim.mj_model, self.sim
        if not sim.floating_base:
            raise ConfigError("HumanoidAMP: the humanoid needs a floating base: set env.asset.fixBaseLink: False")
        if list(sim.actuator_joints) != list(sim.dof_names):
            raise ConfigError("HumanoidAMP: the MJCF needs one PD actuator per joint, in joint order; actuator -> "
                              f"joint: {dict(zip(sim.actuator_names, sim.actuator_joints))}")
        groups: dict[str, list[tuple[float, float, float]]] = {}
        for name in sim.dof_names:
            j = m.joint(name)
            groups.setdefault(m.body(int(j.bodyid[0])).name, []).append(tuple(float(v) for v in j.axis))
        self.joint_groups = [JointGroup(body, tuple(axes)) for body, axes in groups.items()]
        self.group_sizes = [g.size for g in self.joint_groups]
        lower, upper = sim.joint_limits()
        lo, hi, i = lower.clone(), upper.clone(), 0
        for size in self.group_sizes:  # IGE's _build_pd_action_offset_scale
            if size == 3:
                lo[i:i + 3], hi[i:i + 3] = -math.pi, math.pi
            else:
                mid, half = 0.5 * (upper[i] + lower[i]), 0.7 * (upper[i] - lower[i])
                lo[i], hi[i] = mid - half, mid + half
            i += size
        self.pd_offset, self.pd_scale = 0.5 * (hi + lo), 0.5 * (hi - lo)
        self.default_dof_pos = torch.zeros_like(lower)  # the zero pose (module docstring: why not IGE's)

    def _init_bodies(self, env: dict) -> None:
        names = self._sensed_bodies
        self.key_bodies = list(env.get("keyBodies", ["right_hand", "left_hand", "right_foot", "left_foot"]))
        for key, listed in (("env.keyBodies", self.key_bodies), ("env.contactBodies", env.get("contactBodies", []))):
            unknown = [b for b in listed if b not in names]
            if unknown:
                raise ConfigError(f"{key}={listed} names bodies the model lacks: {unknown}; bodies: {names}")
        self.key_ids = self.sim.body_ids(self.key_bodies)
        self.body_ids_all = self.sim.body_ids(names)
        feet = torch.tensor([b in env.get("contactBodies", []) for b in names], device=self.device)
        self.may_touch = feet  # (bodies,) the bodies allowed to touch and to go low
        self.contact_forces = self.sim.sensor("contact_forces")  # (N, bodies, 3), in the order of names

    # ------------------------------------------------------------ observation
    def observation_terms(self) -> list[ObsTerm]:
        k, nd = len(self.key_bodies), self.sim.num_dof
        sizes = [("root_height", 1), ("root_rot", 6), ("root_vel", 3), ("root_ang_vel", 3),
                 ("dof_obs", dof_obs_size(self.group_sizes)), ("dof_vel", nd), ("key_body_pos", 3 * k)]
        terms, start = [], 0
        for name, size in sizes:
            terms.append(ObsTerm(name, size, compute=lambda a=start, b=start + size: self._obs[:, a:b]))
            start += size
        return terms

    def compute_observations(self) -> None:
        self._obs.copy_(self._current_observation())
        super().compute_observations()

    def _current_observation(self) -> torch.Tensor:
        sim = self.sim
        return humanoid_observation(sim.root_pos, sim.root_quat, sim.root_lin_vel, sim.root_ang_vel_world(),
                                    sim.dof_pos, sim.dof_vel, sim.xpos[:, self.key_ids], self.group_sizes,
                                    self.local_root_obs)

    def fetch_amp_obs_demo(self, num_samples: int) -> torch.Tensor:
        """(num_samples, num_amp_obs) AMP observations of the motions at random times (IGE's fetch_amp_obs_demo)."""
        ids = self.motion_lib.sample_motions(num_samples)
        t0 = self.motion_lib.sample_times(ids)
        return self._motion_amp_obs(ids, t0, 0).view(num_samples, self.num_amp_obs)

    def _motion_amp_obs(self, ids: torch.Tensor, t0: torch.Tensor, first: int) -> torch.Tensor:
        """(n, steps - first, per step): the motion's observations at t0 - k dt for k = first .. steps - 1."""
        steps = torch.arange(first, self.num_amp_obs_steps, device=self.device, dtype=torch.float32)
        times = (t0.unsqueeze(1) - self.control_dt * steps).flatten()
        s = self.motion_lib.state(ids.repeat_interleave(steps.shape[0]), times)
        obs = humanoid_observation(s.root_pos, s.root_rot, s.root_vel, s.root_ang_vel, s.dof_pos, s.dof_vel,
                                   s.key_pos, self.group_sizes, self.local_root_obs)
        return obs.view(ids.shape[0], steps.shape[0], self.num_amp_obs_per_step)

    # --------------------------------------------------------------- stepping
    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.sim.ctrl[:] = self.pd_offset + self.pd_scale * actions

    def refresh_state(self) -> None:
        self.sim.refresh_kinematics()  # key bodies and body heights of the state the physics left
        self._amp_hist[:, 1:] = self._amp_hist[:, :-1].clone()
        self._amp_hist[:, 0] = self._current_observation()
        self.amp_obs.copy_(torch.nan_to_num(self._amp_hist.flatten(1)))

    def check_termination(self) -> torch.Tensor:
        if not self.early_termination:
            return torch.zeros_like(self.nonfinite_buf)
        others = ~self.may_touch
        touching = ((self.contact_forces.abs() > 0.1).any(dim=-1) & others).any(dim=-1)
        low = ((self.sim.xpos[:, self.body_ids_all, 2] < self.termination_height) & others).any(dim=-1)
        return touching & low & (self.progress_buf > 1)

    def compute_reward(self) -> None:
        self.rew_buf.fill_(1.0)  # IGE's compute_humanoid_reward: the style reward is the learner's

    def reset_idx(self, mask: torch.Tensor) -> None:
        n, dev, lib = self.num_envs, self.device, self.motion_lib
        ids = lib.sample_motions(n)
        times = torch.zeros(n, device=dev) if self.state_init == StateInit.Start else lib.sample_times(ids)
        if self.state_init == StateInit.Default:
            ref = torch.zeros_like(mask)
        elif self.state_init == StateInit.Hybrid:
            ref = mask & (torch.rand(n, device=dev) < self.hybrid_init_prob)
        else:
            ref = mask
        s = lib.state(ids, times)
        self.sim.reset_worlds(mask)
        self.sim.write_state(ref, root_pos=s.root_pos, root_quat=s.root_rot, root_lin_vel=s.root_vel,
                             root_ang_vel=quat_rotate_inverse(s.root_rot, s.root_ang_vel), dof_pos=s.dof_pos,
                             dof_vel=s.dof_vel, refresh=False)
        self.sim.write_state(mask & ~ref, dof_pos=self.default_dof_pos.expand(n, -1),
                             dof_vel=torch.zeros_like(self.sim.dof_vel))
        # IGE's _init_amp_obs: the history of a reference start is the motion before it, of a default start the
        # current observation repeated.
        now = self._current_observation().unsqueeze(1)
        past = torch.where(ref.view(-1, 1, 1), self._motion_amp_obs(ids, times, 1), now)
        self._amp_hist.copy_(torch.where(mask.view(-1, 1, 1), torch.cat((now, past), dim=1), self._amp_hist))
