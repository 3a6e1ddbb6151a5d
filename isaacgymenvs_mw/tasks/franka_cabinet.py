"""FrankaCabinet: a Franka Panda opens the top drawer of a cabinet by its handle (IsaacGymEnvs' task).

The scene: the Panda (``env.asset``, at the world origin) faces the cabinet (``env.assets.cabinet``), whose top
drawer slides out toward the robot. Actions move the 7 joint targets and the gripper target by
``actionScale x control dt x a`` per step (the gripper 10 times slower), as IsaacGymEnvs (``env.controlType``
joint_pos, the arm controller of tasks/arm_control.py); the episode ends when the
drawer is open past ``openDistance`` (a success) or at the time limit.

Differences from IsaacGymEnvs, on purpose: the fingers are coupled (8 actions, not 9; the observation keeps both
finger positions, 23 values as IGE); the grasp point is the ``grasp`` site between the fingertip pads (IGE adds
4 cm along a link7 axis to the finger bodies' midpoint); the drawer's grasp point is the handle bar's centre (IGE:
1 cm beside it); the cabinet is the robot's IGE pose expressed the other way round (the robot at the origin, the
cabinet turned to face it), so "a finger past the handle" is measured along the drawer's opening axis, not world x;
no loose boxes in the drawer (as Isaac Lab's port).
"""

from __future__ import annotations

import torch

from isaacgymenvs_mw.tasks.arm_control import arm_control
from isaacgymenvs_mw.tasks.base.env_keys import refuse_reward_scale
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.rewards import RewardTerms
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.tasks.franka import FrankaArm
from isaacgymenvs_mw.utils.errors import ConfigError

# env keys of the task YAML (IsaacGymEnvs' names) that are plain numbers.
_NUMBER_KEYS = ("actionScale", "fingerSpeedScale", "dofVelocityScale", "startDofNoise", "openDistance",
                "pastHandleReward")
# reward term -> the env key of its scale (IsaacGymEnvs' names)
REWARD_SCALE_KEYS = {"handle_distance": "distRewardScale", "alignment": "rotRewardScale",
                     "around_handle": "aroundHandleRewardScale", "open": "openRewardScale",
                     "finger_distance": "fingerDistRewardScale", "open_bonus": "openBonusScale",
                     "success": "successRewardScale", "action": "actionPenaltyScale"}


class FrankaCabinet(VecTask):
    """Observation (23): scaled joint positions, joint velocities, grasp-to-handle vector, drawer position and
    velocity. Actions (8): changes of the 7 joint targets and the gripper target."""

    reports_success = True

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        missing = [k for k in _NUMBER_KEYS + tuple(REWARD_SCALE_KEYS.values()) + ("startDofPos", "drawer")
                   if k not in env]
        if missing:
            raise ConfigError(f"FrankaCabinet: the task YAML's env section lacks {missing}")
        refuse_reward_scale(type(self).__name__, env)
        self.env_numbers = {key: float(env[key]) for key in _NUMBER_KEYS}
        # joint_pos only, the gripper target moved like a joint's (IGE's); before the model is built
        self.control = arm_control(env, "FrankaCabinet", ("joint_pos",),
                                   gripper_speed=self.env_numbers["fingerSpeedScale"])
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        self.arm = FrankaArm(self.sim, "FrankaCabinet")
        self._init_drawer(env["drawer"])
        self.start_dof_pos = self.arm.start_pose(env["startDofPos"], "env.startDofPos")
        # Per step, a target moves by at most actionScale x control dt (rad for the arm; the gripper
        # fingerSpeedScale times that, m): tasks/arm_control.py
        self.control.bind(self)
        self.actions = torch.zeros((self.num_envs, self.num_actions), device=self.device)
        self.rewards = RewardTerms.from_env(self, env, self.num_envs, self.device, ige_keys=REWARD_SCALE_KEYS)
        self.build_observation_layouts()

    def _init_drawer(self, drawer: dict) -> None:
        """The drawer's joint and handle site, by the names ``env.drawer`` gives (prefixed by the cabinet asset)."""
        try:
            self.cabinet = self.sim.asset(str(drawer["asset"]))
        except KeyError:
            raise ConfigError(f"env.drawer.asset={drawer.get('asset')!r} is not an asset of the scene: give one "
                              f"of {list(self.sim.assets)} (env.assets)") from None
        joint = self.cabinet.prefix + str(drawer["joint"])
        if joint not in self.cabinet.dof_names:
            raise ConfigError(f"env.drawer.joint={drawer['joint']!r}: the asset "
                              f"'{self.cabinet.name}' has no such joint; its joints: "
                              f"{[n[len(self.cabinet.prefix):] for n in self.cabinet.dof_names]}")
        self.drawer_dof = self.cabinet.dof_names.index(joint)
        try:
            self.handle_site = self.sim.site_id(self.cabinet.prefix + str(drawer["handleSite"]))
        except KeyError as err:
            raise ConfigError(f"env.drawer.handleSite={drawer['handleSite']!r}: {err.args[0]}") from None
        m = self.sim.mj_model
        self.drawer_body = int(m.site_bodyid[self.handle_site])
        # The drawer's opening direction in the world: its joint axis (the cabinet is fixed, so it never changes).
        axis = torch.tensor(m.jnt_axis[m.joint(joint).id], dtype=torch.float32, device=self.device)
        self.sim.refresh_kinematics()
        self.opening_axis = self.sim.xmat[0, self.drawer_body] @ axis

    # ------------------------------------------------------------------ pre-physics
    def check_action_size(self) -> None:
        self.control.check_action_size(self)

    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.actions.copy_(actions)
        self.control.apply(actions)

    # ------------------------------------------------------------------ post-physics
    def drawer_pos(self) -> torch.Tensor:
        return self.cabinet.dof_pos[:, self.drawer_dof]

    def refresh_state(self) -> None:
        """The positions the reward terms share, read once per step: the handle, the fingers, and whether the
        fingers are around the handle."""
        self.handle_pos = self.sim.site_xpos[:, self.handle_site]
        self.left_finger, self.right_finger = self.arm.finger_pos()
        self.around = around_handle(self.left_finger[:, 2], self.right_finger[:, 2], self.handle_pos[:, 2])

    def check_success(self) -> torch.Tensor:
        # open past openDistance (IGE's end condition): the episode ends, bootstrapped (see VecTask.check_success)
        return self.drawer_pos() > self.env_numbers["openDistance"]

    def compute_reward(self) -> None:
        reward = self.rewards.compute(self.nonfinite_buf)
        past = fingers_past_handle(self.left_finger, self.right_finger, self.handle_pos, self.opening_axis)
        self.rew_buf[:] = torch.where(past, self.env_numbers["pastHandleReward"], reward)

    # Reward terms: each returns its per-step value; its YAML scale multiplies it (REWARD_SCALE_KEYS).
    def _reward_handle_distance(self) -> torch.Tensor:
        # closeness of the grasp point to the handle, doubled within 2 cm
        return handle_distance_reward(torch.norm(self.arm.grasp_pos() - self.handle_pos, dim=-1))

    def _reward_alignment(self) -> torch.Tensor:
        # the gripper approaches along the drawer's inward axis with its fingers one above the other
        grip, drawer = self.arm.grasp_axes(), self.sim.xmat[:, self.drawer_body]  # axes as columns
        return alignment_reward(grip[..., 2], grip[..., 1], -drawer[..., 0], drawer[..., 2])

    def _reward_around_handle(self) -> torch.Tensor:
        # the left finger above the handle and the right one below it
        return self.around

    def _reward_finger_distance(self) -> torch.Tensor:
        # with the fingers around the handle: how close each is to the handle's height
        return finger_distance_reward(self.left_finger[:, 2], self.right_finger[:, 2], self.handle_pos[:, 2])

    def _reward_open(self) -> torch.Tensor:
        # how far the drawer is open, counted 1.5 times while the fingers are around the handle
        return open_reward(self.drawer_pos(), self.around)

    def _reward_open_bonus(self) -> torch.Tensor:
        # IsaacGymEnvs' bonuses for passing 0.01 m, 0.2 m and 0.39 m of opening
        return open_bonus(self.drawer_pos(), self.around)

    def _reward_success(self) -> torch.Tensor:
        # 1 on the step the drawer passes openDistance and the episode ends (IGE has no such term: scale 0)
        return self.success_buf.float()

    def _reward_action(self) -> torch.Tensor:
        # squared size of the action (a penalty: its scale is subtracted)
        return -torch.sum(self.actions ** 2, dim=-1)

    def observation_terms(self) -> list[ObsTerm]:
        def to_handle() -> torch.Tensor:
            return self.sim.site_xpos[:, self.handle_site] - self.arm.grasp_pos()

        d = self.drawer_dof
        return [*self.control.observation_terms(scaled=True),                         # 7 arm + 2 fingers, [-1, 1]
                ObsTerm("dof_vel", 9, scale=self.env_numbers["dofVelocityScale"],
                        compute=lambda: self.sim.dof_vel),                              # rad/s, m/s
                ObsTerm("to_handle", 3, compute=to_handle),                             # m, world frame
                ObsTerm("drawer_pos", 1, compute=lambda: self.cabinet.dof_pos[:, d:d + 1]),  # m, 0 closed
                ObsTerm("drawer_vel", 1, compute=lambda: self.cabinet.dof_vel[:, d:d + 1])]  # m/s

    # ------------------------------------------------------------------ reset
    def reset_idx(self, mask: torch.Tensor) -> None:
        noise = self.env_numbers["startDofNoise"] * (torch.rand((self.num_envs, 9), device=self.device) - 0.5)
        dof_pos = torch.clamp(self.start_dof_pos + noise, self.arm.dof_lower, self.arm.dof_upper)
        self.arm.reset(mask, dof_pos)
        self.control.on_reset(mask)
        closed = torch.zeros_like(self.cabinet.dof_pos)
        # No pose refresh: it would run the kinematics of every world at every step (reset_idx runs each step,
        # with an empty mask mostly), 13 % of VecTask.step on a GPU. A new episode's first observation then
        # holds the previous episode's grasp-to-handle vector (joint and drawer values are current), as IGE's.
        self.sim.write_state(mask, dof_pos=closed, dof_vel=closed, asset=self.cabinet.name, refresh=False)
        self.actions.masked_fill_(mask.unsqueeze(1), 0.0)


# --------------------------------------------------------------------------- reward functions (IsaacGymEnvs')
def handle_distance_reward(distance: torch.Tensor) -> torch.Tensor:
    """(1 / (1 + d²))², doubled when d <= 0.02 m."""
    r = 1.0 / (1.0 + distance ** 2)
    r = r * r
    return torch.where(distance <= 0.02, 2.0 * r, r)


def alignment_reward(grip_forward: torch.Tensor, grip_up: torch.Tensor, drawer_inward: torch.Tensor,
                     drawer_up: torch.Tensor) -> torch.Tensor:
    """½ (sign(c1) c1² + sign(c2) c2²) with c1 = forward·inward and c2 = up·up: 1 when aligned, -1 when opposed."""
    c1 = torch.sum(grip_forward * drawer_inward, dim=-1)
    c2 = torch.sum(grip_up * drawer_up, dim=-1)
    return 0.5 * (torch.sign(c1) * c1 ** 2 + torch.sign(c2) * c2 ** 2)


def around_handle(z_left: torch.Tensor, z_right: torch.Tensor, z_handle: torch.Tensor) -> torch.Tensor:
    """0.5 when the left finger is above the handle and the right one below it, else 0."""
    return torch.where((z_left > z_handle) & (z_right < z_handle), 0.5, 0.0)


def finger_distance_reward(z_left: torch.Tensor, z_right: torch.Tensor, z_handle: torch.Tensor) -> torch.Tensor:
    """(0.04 - |z_l - z_h|) + (0.04 - |z_r - z_h|) while the fingers are around the handle, else 0."""
    closeness = (0.04 - torch.abs(z_left - z_handle)) + (0.04 - torch.abs(z_right - z_handle))
    return torch.where(around_handle(z_left, z_right, z_handle) > 0.0, closeness, 0.0)


def open_reward(drawer_pos: torch.Tensor, around: torch.Tensor) -> torch.Tensor:
    """q_d (1 + around): the opening, worth 1.5 times as much with the fingers around the handle."""
    return drawer_pos * around + drawer_pos


def open_bonus(drawer_pos: torch.Tensor, around: torch.Tensor) -> torch.Tensor:
    """+0.5 past 0.01 m, + around past 0.2 m, + 2 around past 0.39 m."""
    return (0.5 * (drawer_pos > 0.01) + around * (drawer_pos > 0.2) + 2.0 * around * (drawer_pos > 0.39)).float()


def fingers_past_handle(left: torch.Tensor, right: torch.Tensor, handle: torch.Tensor,
                        opening_axis: torch.Tensor) -> torch.Tensor:
    """A finger more than 4 cm behind the handle, toward the cabinet along the drawer's opening axis (IsaacGymEnvs
    then overwrites the reward with -1)."""
    def behind(finger: torch.Tensor) -> torch.Tensor:
        return torch.sum((finger - handle) * opening_axis, dim=-1) < -0.04

    return behind(left) | behind(right)
