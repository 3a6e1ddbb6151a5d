"""FrankaCubeLift, FrankaCubeLiftDepth and FrankaCubeLiftRGB: the Panda grasps the 5 cm cube and lifts it.

The scene (``cfg/task/FrankaCubeLift.yaml``) is FrankaCubeStack's without cube B: the Panda at the world origin (its
base frame), the table top 0.1 m below it, and cube A (``env.assets.cubeA``) placed at every reset with its xy
uniform within ±``startPositionNoise`` of the table centre (0.45, 0) and its yaw within ±``startRotationNoise``,
resting on the table. The cube counts as lifted when its centre is ``liftHeight`` above where it rests; held there
(between the closed finger pads) is a success: the episode ends and the learner bootstraps it like a time-out
(VecTask.check_success).

Control: ``joint_pos`` only (``env.controlType``, the arm controller of tasks/arm_control.py): each step the 7 arm
servo targets move by ``actionScale`` x control dt x a, clamped to the joint ranges; the last action opens (>= 0) or
closes (< 0) the gripper, as FrankaCubeStack.

FrankaCubeLift observes the cube's pose. FrankaCubeLiftDepth is the same problem, but its policy does not observe
the cube: it sees a depth image of the table from a fixed camera (``env.cameras.overhead``) and its own arm; the
critic reads the cube's pose too (asymmetric actor-critic, the train YAML's ``obs_groups``). FrankaCubeLiftRGB sees
the same camera's colour image instead: a stronger cue of where the cube is.
"""

from __future__ import annotations

import torch

from isaacgymenvs_mw.tasks import franka
from isaacgymenvs_mw.tasks.arm_control import arm_control
from isaacgymenvs_mw.tasks.base.observation_terms import (
    ImageTerm,
    ObsTerm,
    camera_terms,
)
from isaacgymenvs_mw.tasks.base.rewards import RewardTerms
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.tasks.franka import FrankaArm
from isaacgymenvs_mw.utils.config import boolean, real_number
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import quat_from_yaw

REST_HEIGHT = franka.TABLE_TOP + franka.CUBE_A_SIZE / 2.0  # the cube's centre when it rests on the table (m)
# env keys of the task YAML that are plain numbers, and whether they must be > 0 (else >= 0)
_NUMBER_KEYS = {"actionScale": True, "frankaDofNoise": False, "startPositionNoise": False,
                "startRotationNoise": False, "liftHeight": True}
# reward term -> the env key of its scale
REWARD_SCALE_KEYS = {"dist": "distRewardScale", "grasp": "graspRewardScale",
                     "lift_height": "liftHeightRewardScale", "lift": "liftRewardScale"}
DOF_VEL_SCALE = 0.1  # joint speeds (up to about 2.6 rad/s) observed x 0.1, as IGE's Franka tasks (dof_vel_scale)


class FrankaCubeLift(VecTask):
    """Observation: the arm (joints, speeds, servo targets, grasp point) and the cube's pose. Actions (8): 7 arm
    joint-target changes and the gripper."""

    reports_success = True

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        name = type(self).__name__
        missing = [k for k in (*_NUMBER_KEYS, *REWARD_SCALE_KEYS.values(), "startDofPos") if k not in env]
        if missing:
            raise ConfigError(f"{name}: the task YAML's env section lacks {missing}")
        self.control = arm_control(env, name, ("joint_pos",))  # tasks/arm_control.py, before the model is built
        self.env_numbers = {key: real_number(env[key], f"env.{key}", 0.0, low_open=must_be_positive)
                            for key, must_be_positive in _NUMBER_KEYS.items()}
        # True: the critic also reads what the simulator knows (franka.privileged_terms)
        self.asymmetric = boolean(env.get("asymmetric_observations", False), "env.asymmetric_observations")
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        self.arm = FrankaArm(self.sim, name)
        self.start_dof_pos = self.arm.start_pose(env["startDofPos"], "env.startDofPos")
        self.cube = self.sim.asset("cubeA")
        self.control.bind(self)
        self.table_centre = torch.tensor([*franka.TABLE_CENTRE_XY], device=self.device)
        self.rewards = RewardTerms.from_env(self, env, self.num_envs, self.device, ige_keys=REWARD_SCALE_KEYS)
        self.terms: dict[str, torch.Tensor] = {}
        self.build_observation_layouts()

    # ------------------------------------------------------------------ pre-physics
    def check_action_size(self) -> None:
        self.control.check_action_size(self)

    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.control.apply(actions)

    # ------------------------------------------------------------------ post-physics
    def refresh_state(self) -> None:
        """The quantities the reward terms and the success test share, once per step."""
        grasp = self.arm.grasp_pos()
        self.terms = cube_lift_terms(self.cube.root_pos, grasp, *franka.fingertips(self.arm), self.sim.dof_pos[:, 7],
                                     self.env_numbers["liftHeight"])

    def check_success(self) -> torch.Tensor:
        # held at or above the lift height: the episode ends, bootstrapped (see VecTask.check_success)
        return self.terms["success"]

    def compute_reward(self) -> None:
        self.rew_buf[:] = self.rewards.compute(self.nonfinite_buf)

    def _reward_dist(self) -> torch.Tensor:
        # approach (IGE): 1 - tanh(10 x mean distance of the cube to the grasp point and the fingertips)
        return self.terms["dist"]

    def _reward_grasp(self) -> torch.Tensor:
        # shaping: the cube between the finger pads with the gripper closed on it
        return self.terms["held"]

    def _reward_lift_height(self) -> torch.Tensor:
        # shaping: while held, the cube's rise from the table toward liftHeight, 0 ... 1
        return self.terms["lift_height"]

    def _reward_lift(self) -> torch.Tensor:
        # the cube's centre at least liftHeight above where it rests, held or not
        return self.terms["lifted"]

    # ------------------------------------------------------------------ observations
    def proprioception_terms(self) -> list[ObsTerm]:
        """What the arm knows of itself (29 values)."""
        return [*self.control.observation_terms(),                                      # rad; fingers m
                ObsTerm("dof_vel", 9, scale=DOF_VEL_SCALE, compute=lambda: self.sim.dof_vel),  # rad/s; m/s
                # the servo targets the actions move (rad; gripper m): state the next step's motion depends on
                ObsTerm("dof_targets", 8, compute=lambda: self.arm.targets),
                ObsTerm("grasp_pos", 3, compute=self.arm.grasp_pos)]                   # m, between the pads

    def cube_terms(self) -> list[ObsTerm]:
        """The cube's pose (10 values)."""
        return [ObsTerm("cube_pos", 3, compute=lambda: self.cube.root_pos),           # m, robot base frame
                ObsTerm("cube_quat", 4, compute=lambda: self.cube.root_quat),         # (w, x, y, z)
                ObsTerm("cube_to_grasp", 3,
                        compute=lambda: self.arm.grasp_pos() - self.cube.root_pos)]   # m, grasp point - cube

    def observation_terms(self) -> list[ObsTerm]:
        return self.proprioception_terms() + self.cube_terms()

    def privileged_terms(self) -> list[ObsTerm]:
        """env.asymmetric_observations: what only the critic reads besides the policy's observation."""
        if not self.asymmetric:
            return []
        return franka.privileged_terms(self.arm, {"cube": self.cube}, observed=self.proprioception_terms())

    def state_terms(self) -> list[ObsTerm] | None:
        return self.observation_terms() + self.privileged_terms() if self.asymmetric else None

    # ------------------------------------------------------------------ reset
    def reset_idx(self, mask: torch.Tensor) -> None:
        n = self.num_envs
        self.sim.reset_worlds(mask)
        numbers = self.env_numbers
        self.arm.reset(mask, franka.noisy_start_pose(self.start_dof_pos, numbers["frankaDofNoise"], self.arm, n))
        self.control.on_reset(mask)
        pos, quat = sample_cube(n, self.table_centre, numbers["startPositionNoise"], numbers["startRotationNoise"])
        zero = torch.zeros_like(pos)
        # The observation reads the grasp site and the cube: poses recomputed once, after both writes.
        self.sim.write_state(mask, root_pos=pos, root_quat=quat, root_lin_vel=zero, root_ang_vel=zero,
                             asset="cubeA", refresh=True)


class FrankaCubeLiftDepth(FrankaCubeLift):
    """FrankaCubeLift whose policy finds the cube in a depth image: it observes the arm and what its camera renders
    (``env.cameras.overhead``, depth; the "camera" group); the cube's pose goes to the critic's state."""

    def observation_terms(self) -> list[ObsTerm]:
        return self.proprioception_terms()

    def state_terms(self) -> list[ObsTerm]:
        return self.cube_terms() + self.privileged_terms()

    def image_terms(self) -> list[ImageTerm]:
        return camera_terms(self.sim.cameras)


class FrankaCubeLiftRGB(FrankaCubeLiftDepth):
    """FrankaCubeLiftDepth seeing the same camera's colour image: the dark red cube on the brown table top differs
    from it by 37-49 of 255 levels per channel, where in depth the cube's height is at most 13 of 255 levels. Only its
    YAML differs: the camera renders rgb."""


def sample_cube(n: int, centre: torch.Tensor, xy_noise: float, yaw_noise: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Start poses of the cube in ``n`` worlds: position (n, 3) with xy uniform within ±``xy_noise`` of ``centre``,
    resting on the table; orientation (n, 4) a yaw uniform within ±``yaw_noise``."""
    dev = centre.device
    xy = centre + xy_noise * (2.0 * torch.rand((n, 2), device=dev) - 1.0)
    pos = torch.cat((xy, torch.full((n, 1), REST_HEIGHT, device=dev)), dim=1)
    return pos, quat_from_yaw(yaw_noise * (2.0 * torch.rand(n, device=dev) - 1.0))


def cube_lift_terms(cube: torch.Tensor, grasp: torch.Tensor, tip_left: torch.Tensor, tip_right: torch.Tensor,
                    finger_opening: torch.Tensor, lift_height: float) -> dict[str, torch.Tensor]:
    """The reward and success quantities from positions (N, 3) and the finger opening (N,): ``dist`` (IGE's
    approach), ``held`` and ``lift_height`` (``grasp_terms`` with the rise to ``lift_height``), ``lifted`` (float
    0/1: the cube's centre at least ``lift_height`` above where it rests) and ``success`` (bool: held and lifted)."""
    terms = franka.grasp_terms(cube, grasp, finger_opening, full_rise=lift_height)
    terms["dist"] = franka.approach_term(cube, grasp, tip_left, tip_right)
    lifted = cube[:, 2] - REST_HEIGHT >= lift_height
    terms["lifted"] = lifted.float()
    terms["success"] = lifted & (terms["held"] > 0.0)
    return terms
