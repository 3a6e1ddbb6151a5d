"""FrankaCubeStack: a Franka Panda picks up cube A (5 cm) and puts it on cube B (7 cm) (IsaacGymEnvs' task).

The scene (``cfg/task/FrankaCubeStack.yaml``): the Panda (``env.asset``) at the world origin, which is its base
frame; a table (``env.assets.table``) whose top is 0.1 m below the base with its centre 0.45 m in front (+x); the
two cubes (``env.assets.cubeA`` / ``cubeB``), free bodies placed at every reset. The episode ends when A is stacked
(a success, reported as ``success``; the learner bootstraps it like a time-out, VecTask.check_success) or at the time
limit.

Reward (``env.reward.kind``):
  * ``staged`` (default): one stage at a time, after ManiSkill's StackCube: reach A, grasp it, lift it clear of B,
    carry it over B, place it on B, release it (``staged_stack_reward``). Each stage pays within its own band, above
    every earlier one (``env.reward.stageLevels``); the most, once A is stacked: on B, the gripper open, A at rest.
    That ends the episode, and the learner's bootstrap values it as that reward paid on every later step.
  * ``isaacgymenvs`` (the task FrankaCubeStackIGE, cfg/task/FrankaCubeStackIGE.yaml): IsaacGymEnvs' reward
    (``cube_stack_terms``: approach, lifted, aligned, and 16 on the step A is on B with the grasp point 4 cm away from
    it, which ends the episode), plus this project's grasp shaping (``graspRewardScale``, ``liftHeightRewardScale``; 0
    gives IGE's reward exactly).

Resets: IGE's (the arm at ``startDofPos`` with noise, both cubes on the table), except ``env.graspedResetFraction`` of
them, which start with A already in the closed hand (``GraspedStarts``).

Control (``env.controlType``: ``joint_pos``, the default, ``joint_tor`` or IsaacGymEnvs' ``osc``) is a component,
tasks/arm_control.py; the last action is the gripper in every mode (8 actions in the joint modes, IGE's 7 in osc).

Differences from IsaacGymEnvs, on purpose: cube B rests on the table (IGE spawns it with cube A's half-size, 1 cm
into the table); quaternions are MuJoCo's (w, x, y, z), IGE's (x, y, z, w); positions are in the robot's base
frame (IGE: the env frame with the table top at 1.025 m); the fingers are coupled (8 actions, not 9 in joint_tor);
joint_pos observes all 9 joint positions, as IGE's joint_tor does (the joint-space policy needs to know the joint
configuration to turn a wanted hand motion into joint motions).
"""

from __future__ import annotations

import itertools
import math

import torch

from isaacgymenvs_mw.tasks.arm_control import arm_control
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, OUTCOME, Metric
from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.base.rewards import RewardTerms
from isaacgymenvs_mw.tasks.base.vec_task import VecTask
from isaacgymenvs_mw.tasks.franka import (
    CUBE_A_SIZE,
    OPEN,
    TABLE_CENTRE_XY,
    TABLE_TOP,
    ArmKinematics,
    FrankaArm,
    approach_term,
    fingertips,
    grasp_terms,
    noisy_start_pose,
    privileged_terms,
)
from isaacgymenvs_mw.utils.config import boolean, one_of, real_number
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import quat_from_matrix, quat_from_yaw

REWARD_KINDS = ("staged", "isaacgymenvs")  # env.reward.kind; the YAML's default is the first
# env keys of the task YAML that are plain numbers
_NUMBER_KEYS = ("actionScale", "frankaDofNoise", "startPositionNoise", "startRotationNoise")
# reward term -> the env key of its scale (IsaacGymEnvs' names)
# Shaping of this project (IGE has neither; 0 gives IGE's reward): holding A, and A's height on the way to "lifted".
SHAPING_SCALE_KEYS = {"grasp": "graspRewardScale", "lift_height": "liftHeightRewardScale"}
REWARD_SCALE_KEYS = {"dist": "distRewardScale", "lift": "liftRewardScale", "align": "alignRewardScale",
                     "stack": "stackRewardScale"}

CUBE_B_SIZE = 0.07  # edge length (m), assets/mjcf/cube_7cm.xml (A's, CUBE_A_SIZE, is in franka.py)
# IGE: A is re-drawn until its xy distance from B is at least 2 (a + b) sqrt(2) / 2 = 0.170 m (twice the sum of the
# cubes' half-diagonals), so that the cubes never overlap, whatever their yaws.
MIN_CUBE_DISTANCE = 2.0 * (CUBE_A_SIZE + CUBE_B_SIZE) * math.sqrt(2.0) / 2.0
CANDIDATES = 32  # draws for A per reset; the first far enough from B is taken (all 32 too close: p < 1e-13)
GRASPED_LIFT = 0.01  # a grasped start holds A's bottom this far above the table (m): off it, not yet lifted
GRASP_POSES = 256    # grasped-start arm poses solved at construction (A's start places and yaws)

# The staged reward's stages, in order. Each pays its level (env.reward.stageLevels, the YAML's) plus its progress,
# 0 ... 1 ("stacked" its level alone), all divided by stacked's level: the reward per step is 0 ... 1.
STAGES = ("reach", "grasp", "carry", "place", "release", "stacked")
STACKED = STAGES.index("stacked")
STACK_XY_TOLERANCE = 0.02  # A's centre within this of B's in xy (m), IGE's tolerance
STACK_Z_TOLERANCE = 0.01   # A's centre within this of its height resting on B (m); above it by more: A clears B
HOVER = 0.03               # carry's aim: A's centre this far above its place on B (m)
RELEASED_OPENING = 0.035   # each finger opened at least this (m): both pads 1 cm clear of A's faces, A centred
# A at rest: slower than these (m/s, rad/s), ManiSkill's StackCube (its is_static thresholds)
STILL_LIN_VEL, STILL_ANG_VEL = 0.01, 0.5
# Training logs the furthest stage the episodes reached (0 reach ... 5 stacked), averaged over those that ended; test
# mode each env's first episode's (eval.json), so that a policy that stacks rarely still shows how far it gets.
FURTHEST_STAGE = Metric("furthest_stage", EPISODE_SUM)
FURTHEST_STAGE_OF_EACH = Metric("furthest_stage", OUTCOME)


class FrankaCubeStack(VecTask):
    """Observation: cube A's orientation and position, B - A, the grasp frame's position and orientation, then the
    two finger positions (osc, the default) or all 9 joint positions (the joint modes). Actions: a pose error of the
    grasp frame (6, osc) or 7 arm commands (the joint modes), then the gripper."""

    reports_success = True

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        env = cfg["env"]
        self.reward_kind = one_of((env.get("reward") or {}).get("kind"), "env.reward.kind", REWARD_KINDS)
        ige_scales = tuple(REWARD_SCALE_KEYS.values()) if self.reward_kind == "isaacgymenvs" else ()
        missing = [k for k in _NUMBER_KEYS + ige_scales + ("startDofPos",) if k not in env]
        if self.reward_kind == "staged" and "stageLevels" not in env["reward"]:
            missing.append("reward.stageLevels")
        if missing:
            raise ConfigError(f"FrankaCubeStack: the task YAML's env section lacks {missing}")
        if self.reward_kind == "staged":
            self.stage_levels = stage_levels(env["reward"]["stageLevels"], "env.reward.stageLevels")
        self.control = arm_control(env, "FrankaCubeStack")  # env.controlType, before the model is built
        self.env_numbers = {key: float(env[key]) for key in _NUMBER_KEYS}
        # the share of resets that start with A in the closed hand (GraspedStarts); absent: none, as IGE
        self.grasped_fraction = real_number(env.get("graspedResetFraction", 0.0), "env.graspedResetFraction",
                                            0.0, 1.0)
        # True: the critic also reads what the simulator knows (franka.privileged_terms)
        self.asymmetric = boolean(env.get("asymmetric_observations", False), "env.asymmetric_observations")
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless,
                         virtual_screen_capture, force_render)
        self.arm = FrankaArm(self.sim, "FrankaCubeStack")
        self.start_dof_pos = self.arm.start_pose(env["startDofPos"], "env.startDofPos")
        self.cube_a, self.cube_b = self.sim.asset("cubeA"), self.sim.asset("cubeB")
        self.table_centre = torch.tensor([*TABLE_CENTRE_XY], device=self.device)
        if self.reward_kind == "staged":
            scales = {"staged": 1.0}  # one term, already within 0 ... 1
        else:
            scales = {t: float(env[k]) for t, k in REWARD_SCALE_KEYS.items()}
            scales.update({t: float(env.get(k, 0.0)) for t, k in SHAPING_SCALE_KEYS.items()})
        self.rewards = RewardTerms(self, scales, self.num_envs,
                                   self.device, key="env")
        self.terms: dict[str, torch.Tensor] = {}
        self.furthest_stage = torch.zeros(self.num_envs, device=self.device)  # this episode's, staged reward
        self.control.bind(self)
        # whether each env's episode started with A in the hand
        self.grasped_start = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        self.grasped_starts = GraspedStarts(self) if self.grasped_fraction > 0.0 else None
        self.build_observation_layouts()

    # ------------------------------------------------------------------ pre-physics
    def check_action_size(self) -> None:
        # osc: IGE's 7 actions (a 6-component pose error and the gripper) drive the 8 actuators through the law
        self.control.check_action_size(self)

    def pre_physics_step(self, actions: torch.Tensor) -> None:
        self.control.apply(actions)

    # ------------------------------------------------------------------ post-physics
    def refresh_state(self) -> None:
        """The quantities the reward terms and the success test share, once per step."""
        grasp = self.arm.grasp_pos()
        if self.reward_kind == "staged":
            reward, stage = staged_stack_reward(self.cube_a.root_pos, self.cube_b.root_pos, grasp,
                                                self.sim.dof_pos[:, 7], self.cube_a.root_lin_vel,
                                                self.cube_a.root_ang_vel, self.stage_levels)
            self.terms = {"staged": reward, "stacked": stage == STACKED}
            torch.maximum(self.furthest_stage, stage.float(), out=self.furthest_stage)
            return
        self.terms = cube_stack_terms(self.cube_a.root_pos, self.cube_b.root_pos, grasp, *fingertips(self.arm))
        self.terms.update(grasp_terms(self.cube_a.root_pos, grasp, self.sim.dof_pos[:, 7]))

    def check_success(self) -> torch.Tensor:
        # A stacked: the episode ends, bootstrapped (see VecTask.check_success). Staged: A on B, the gripper open,
        # A at rest; isaacgymenvs: IGE's end condition, A on B with the grasp point 4 cm away from its centre.
        return self.terms["stacked"]

    def declared_metrics(self) -> list[Metric]:
        staged = [FURTHEST_STAGE, FURTHEST_STAGE_OF_EACH] if self.reward_kind == "staged" else []
        return [*super().declared_metrics(), *staged]

    def compute_reward(self) -> None:
        self.rew_buf[:] = self.rewards.compute(self.nonfinite_buf)

    def _reward_staged(self) -> torch.Tensor:
        # env.reward.kind staged: the furthest stage that holds now pays, within its band (staged_stack_reward)
        return self.terms["staged"]

    # Reward terms of env.reward.kind isaacgymenvs (IGE's formula): stack replaces the other three on the step it
    # succeeds.
    def _reward_dist(self) -> torch.Tensor:
        # approach: 1 - tanh(10 x mean distance of A to grasp point and fingertips), at least the align term
        return self.terms["dist"] * ~self.terms["stacked"]

    def _reward_lift(self) -> torch.Tensor:
        # A's centre more than 9 cm above the table
        return self.terms["lifted"] * ~self.terms["stacked"]

    def _reward_align(self) -> torch.Tensor:
        # while lifted: 1 - tanh(10 x distance of A from its place on top of B)
        return self.terms["align"] * ~self.terms["stacked"]

    def _reward_grasp(self) -> torch.Tensor:
        # shaping: A between the finger pads with the gripper closed on it
        return self.terms["held"] * ~self.terms["stacked"]

    def _reward_lift_height(self) -> torch.Tensor:
        # shaping: while held, A's rise from the table toward the "lifted" height, 0 ... 1
        return self.terms["lift_height"] * ~self.terms["stacked"]

    def _reward_stack(self) -> torch.Tensor:
        # A on B, the gripper released
        return self.terms["stacked"].float()

    def observation_terms(self) -> list[ObsTerm]:
        def grasp_quat() -> torch.Tensor:
            return quat_from_matrix(self.arm.grasp_axes())

        terms = [ObsTerm("cube_a_quat", 4, compute=lambda: self.cube_a.root_quat),    # (w, x, y, z) MuJoCo order
                 ObsTerm("cube_a_pos", 3, compute=lambda: self.cube_a.root_pos),      # m, robot base frame
                 ObsTerm("cube_a_to_b", 3,
                         compute=lambda: self.cube_b.root_pos - self.cube_a.root_pos),  # m, B - A
                 ObsTerm("grasp_pos", 3, compute=self.arm.grasp_pos),                 # m, between the fingertips
                 ObsTerm("grasp_quat", 4, compute=grasp_quat)]                        # (w, x, y, z)
        return terms + self.control.observation_terms()  # the joints (joint modes) or the fingers (osc)

    def state_terms(self) -> list[ObsTerm] | None:
        # env.asymmetric_observations: the policy's observation and the privileged terms, for the critic
        if not self.asymmetric:
            return None
        return self.observation_terms() + privileged_terms(self.arm, {"cube_a": self.cube_a, "cube_b": self.cube_b})

    # ------------------------------------------------------------------ reset
    def reset_idx(self, mask: torch.Tensor) -> None:
        n, dev = self.num_envs, self.device
        if self.reward_kind == "staged":  # the ending episodes' furthest stage, then a new count
            ending = torch.where(mask, self.furthest_stage, 0.0)
            self.metrics.record(FURTHEST_STAGE, ending.sum())
            self.metrics.record(FURTHEST_STAGE_OF_EACH, ending)
            self.furthest_stage.masked_fill_(mask, 0.0)
        dof_pos = noisy_start_pose(self.start_dof_pos, self.env_numbers["frankaDofNoise"], self.arm, n)
        pos_a, pos_b, quat_a, quat_b = sample_cubes(n, self.table_centre, self.env_numbers["startPositionNoise"],
                                                    self.env_numbers["startRotationNoise"], dev)
        if self.grasped_starts is not None:  # a share of the resets hold A (env.graspedResetFraction)
            grasped, dof_pos, pos_a, quat_a, pos_b = self.grasped_starts.draw(dof_pos, pos_a, quat_a, pos_b)
            self.grasped_start.copy_(torch.where(mask, grasped, self.grasped_start))
        self.sim.reset_worlds(mask)
        self.arm.reset(mask, dof_pos)  # servo targets at the new joint positions, in the reset worlds' ctrl
        if self.grasped_starts is not None:
            self.arm.close_gripper(mask & self.grasped_start)
        self.control.on_reset(mask)
        zero = torch.zeros_like(pos_a)
        self.sim.write_state(mask, root_pos=pos_a, root_quat=quat_a, root_lin_vel=zero, root_ang_vel=zero,
                             asset="cubeA", refresh=False)
        # The observation reads the grasp site and the cubes: poses recomputed once, after all writes.
        self.sim.write_state(mask, root_pos=pos_b, root_quat=quat_b, root_lin_vel=zero, root_ang_vel=zero,
                             asset="cubeB", refresh=True)


def stage_levels(value: object, key: str) -> tuple[float, ...]:
    """``env.reward.stageLevels``, checked: one number per stage (STAGES), the first >= 0 and each at least 1 above the
    one before, so that every stage, paying its level + 0 ... 1, pays more than all earlier ones."""
    numbers = list(value) if isinstance(value, (list, tuple)) else None
    ok = numbers is not None and len(numbers) == len(STAGES) and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in numbers)
    if ok:
        ok = numbers[0] >= 0 and all(b >= a + 1 for a, b in itertools.pairwise(numbers))
    if not ok:
        shown = numbers if numbers is not None else value
        raise ConfigError(f"{key}={shown!r} is invalid: give {len(STAGES)} numbers, one per stage {list(STAGES)}, "
                          "the first >= 0 and each at least 1 above the one before (a stage pays its number + 0 ... 1)")
    return tuple(float(v) for v in numbers)


def sample_cubes(n: int, centre: torch.Tensor, xy_noise: float, yaw_noise: float,
                 device: torch.device | str) -> tuple[torch.Tensor, ...]:
    """Start poses of cubes A and B in ``n`` worlds, IsaacGymEnvs' way: each xy uniform within ±``xy_noise`` of the
    table centre, yaw uniform within ±``yaw_noise``, A at least MIN_CUBE_DISTANCE from B in xy (the first of
    CANDIDATES draws that is; no host sync). Both rest on the table (IGE puts B 1 cm into it)."""
    def uniform(*shape: int) -> torch.Tensor:
        return 2.0 * torch.rand(shape, device=device) - 1.0

    xy_b = centre + xy_noise * uniform(n, 2)
    xy_a = first_far(centre + xy_noise * uniform(n, CANDIDATES, 2), xy_b)
    pos_a = torch.cat((xy_a, torch.full((n, 1), TABLE_TOP + CUBE_A_SIZE / 2, device=device)), dim=1)
    pos_b = torch.cat((xy_b, torch.full((n, 1), TABLE_TOP + CUBE_B_SIZE / 2, device=device)), dim=1)
    return pos_a, pos_b, quat_from_yaw(yaw_noise * uniform(n)), quat_from_yaw(yaw_noise * uniform(n))


def first_far(candidates: torch.Tensor, other: torch.Tensor) -> torch.Tensor:
    """(n, 2) the first of the ``candidates`` (n, CANDIDATES, 2) at least MIN_CUBE_DISTANCE from ``other`` (n, 2) in
    xy (the first candidate if none is), without a host sync."""
    far = torch.linalg.norm(candidates - other.unsqueeze(1), dim=-1) >= MIN_CUBE_DISTANCE
    first = torch.argmax(far.to(torch.uint8), dim=1)
    return candidates[torch.arange(candidates.shape[0], device=candidates.device), first]


class GraspedStarts:
    """Resets with cube A already in the closed hand (``env.graspedResetFraction`` of them): A lifted GRASPED_LIFT
    above its resting place, centred between the finger pads, the fingers on its faces (each opened A's half-width),
    the gripper commanded closed, the hand straight down and turned to A's yaw (modulo a quarter turn, a cube's
    symmetry). The arm poses are solved once, by damped least squares on the hand's kinematics
    (franka.ArmKinematics), for GRASP_POSES draws of A's start place and yaw from the reset's own distribution; a
    grasped reset takes one of them at random, and B is drawn anew until it is far enough from A."""

    def __init__(self, task: FrankaCubeStack) -> None:
        self.task, dev = task, task.device
        k, numbers = GRASP_POSES, task.env_numbers
        xy = task.table_centre + numbers["startPositionNoise"] * (2.0 * torch.rand((k, 2), device=dev) - 1.0)
        yaw = numbers["startRotationNoise"] * (2.0 * torch.rand(k, device=dev) - 1.0)
        pos = torch.cat((xy, torch.full((k, 1), TABLE_TOP + CUBE_A_SIZE / 2.0 + GRASPED_LIFT, device=dev)), dim=1)
        hand_yaw = yaw - (math.pi / 2.0) * torch.round(yaw / (math.pi / 2.0))  # within a quarter turn of the start
        c, s, zero, one = torch.cos(hand_yaw), torch.sin(hand_yaw), torch.zeros_like(yaw), torch.ones_like(yaw)
        # the grasp frame's axes as columns: x along the hand's yaw, y (the fingers' opening) x turned -90 degrees
        # about the vertical, z (the approach) straight down: at yaw 0 the start pose's orientation
        rot = torch.stack((torch.stack((c, s, zero), 1), torch.stack((s, -c, zero), 1),
                           torch.stack((zero, zero, -one), 1)), dim=2)
        arm = task.arm
        q, error = ArmKinematics(task.sim, arm.grasp_site).solve(pos, rot, task.start_dof_pos[:7],
                                                                 arm.dof_lower[:7], arm.dof_upper[:7])
        reached = (error < 1e-5).cpu()  # once, at construction
        if not bool(reached.any()):
            raise ConfigError(f"env.graspedResetFraction={task.grasped_fraction} is invalid with "
                              f"env.startPositionNoise={numbers['startPositionNoise']}: the hand reaches none of "
                              "cube A's start places; give 0 or a smaller noise")
        keep = reached.nonzero().flatten().to(dev)
        fingers = torch.full((len(keep), 2), CUBE_A_SIZE / 2.0, device=dev)
        self.dof_pos = torch.cat((q[keep].float(), fingers), dim=1)  # (K, 9)
        self.pos_a, self.quat_a = pos[keep], quat_from_yaw(yaw[keep])

    def draw(self, dof_pos: torch.Tensor, pos_a: torch.Tensor, quat_a: torch.Tensor,
             pos_b: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Which envs start grasped (n,) and the reset's arm joints, A's pose and B's position with those envs'
        replaced."""
        task, n, dev = self.task, dof_pos.shape[0], dof_pos.device
        grasped = torch.rand(n, device=dev) < task.grasped_fraction
        pick = torch.randint(self.dof_pos.shape[0], (n,), device=dev)
        noise = task.env_numbers["startPositionNoise"]
        candidates = task.table_centre + noise * (2.0 * torch.rand((n, CANDIDATES, 2), device=dev) - 1.0)
        xy_b = first_far(candidates, self.pos_a[pick, :2])
        rows = grasped.unsqueeze(1)
        new_b = torch.cat((xy_b, pos_b[:, 2:]), dim=1)
        return (grasped, torch.where(rows, self.dof_pos[pick], dof_pos), torch.where(rows, self.pos_a[pick], pos_a),
                torch.where(rows, self.quat_a[pick], quat_a), torch.where(rows, new_b, pos_b))


def cube_stack_terms(cube_a: torch.Tensor, cube_b: torch.Tensor, grasp: torch.Tensor, tip_left: torch.Tensor,
                     tip_right: torch.Tensor, table_top: float = TABLE_TOP) -> dict[str, torch.Tensor]:
    """IsaacGymEnvs' FrankaCubeStack reward quantities from positions (N, 3): ``dist``, ``lifted`` (float 0/1),
    ``align`` and ``stacked`` (bool): IsaacGymEnvs' reward is ``stack_scale`` when stacked, else the weighted ``dist``,
    ``lifted`` and ``align`` (the task's reward terms)."""
    height_a = cube_a[:, 2] - table_top  # A's centre above the table
    d = torch.linalg.norm(cube_a - grasp, dim=-1)
    dist = approach_term(cube_a, grasp, tip_left, tip_right)
    lifted = ((height_a - CUBE_A_SIZE) > 0.04).float()
    offset = torch.zeros_like(cube_a)
    offset[:, 2] = (CUBE_A_SIZE + CUBE_B_SIZE) / 2.0  # A's centre above B's when stacked
    to_stacked = cube_b - cube_a + offset
    align = (1.0 - torch.tanh(10.0 * torch.linalg.norm(to_stacked, dim=-1))) * lifted
    dist = torch.maximum(dist, align)
    aligned_xy = torch.linalg.norm(to_stacked[:, :2], dim=-1) < 0.02
    on_top = torch.abs(height_a - CUBE_B_SIZE - CUBE_A_SIZE / 2.0) < 0.02
    released = d > 0.04
    return {"dist": dist, "lifted": lifted, "align": align, "stacked": aligned_xy & on_top & released}


def staged_stack_reward(cube_a: torch.Tensor, cube_b: torch.Tensor, grasp: torch.Tensor,
                        finger_opening: torch.Tensor, lin_vel_a: torch.Tensor, ang_vel_a: torch.Tensor,
                        levels: tuple[float, ...], table_top: float = TABLE_TOP) -> tuple[torch.Tensor, torch.Tensor]:
    """The staged reward (``env.reward.kind: staged``): (reward (N,) in 0 ... 1, stage (N,) long, an index of STAGES).

    Inputs: positions (N, 3) of cube A, cube B and the grasp point, each finger's opening (N,; m) and cube A's
    linear and angular velocity (N, 3; m/s, rad/s). A's place is its centre resting on B, (A + B) / 2 above B's
    centre; A is clear of B when its centre is more than STACK_Z_TOLERANCE above that height (its bottom above B's
    top), and over B when also within STACK_XY_TOLERANCE of B in xy. The stage is the furthest that holds; it pays
    its value in ``levels`` (one per stage, ``stage_levels``) plus its progress (0 ... 1), all / stacked's level:

      reach    A not held:                    1 - tanh(5 |grasp point - A|)
      grasp    A held (franka.grasp_terms):   A's rise from the table toward clearing B, 0 ... 1
      carry    held and clear of B:           1 - tanh(5 |A - HOVER above its place|)
      place    held, clear and over B:        1 - tanh(5 |A - its place|)
      release  A on B (over B, within STACK_Z_TOLERANCE of its place), held or not:
               (how far the fingers opened beyond A's faces, 0 ... 1, + 1 - tanh(10 |v_A| + |w_A|)) / 2
      stacked  on B, each finger opened RELEASED_OPENING or more, A still (|v_A|, |w_A| under STILL_LIN_VEL,
               STILL_ANG_VEL): nothing more; it is the success (the episode ends)
    """
    offset = torch.zeros_like(cube_a)
    offset[:, 2] = (CUBE_A_SIZE + CUBE_B_SIZE) / 2.0
    place = cube_b + offset
    over_xy = torch.linalg.norm((cube_a - place)[:, :2], dim=-1) < STACK_XY_TOLERANCE
    above_place = cube_a[:, 2] - place[:, 2]
    clear = above_place > STACK_Z_TOLERANCE
    on_b = over_xy & (above_place.abs() <= STACK_Z_TOLERANCE)
    held = grasp_terms(cube_a, grasp, finger_opening, table_top)["held"] > 0.0
    speed, spin = torch.linalg.norm(lin_vel_a, dim=-1), torch.linalg.norm(ang_vel_a, dim=-1)
    stacked = on_b & (finger_opening >= RELEASED_OPENING) & (speed < STILL_LIN_VEL) & (spin < STILL_ANG_VEL)

    def closeness(target: torch.Tensor) -> torch.Tensor:
        return 1.0 - torch.tanh(5.0 * torch.linalg.norm(target - cube_a, dim=-1))

    rest_height = table_top + CUBE_A_SIZE / 2.0  # A's centre resting on the table
    clear_height = place[:, 2] + STACK_Z_TOLERANCE
    # B knocked off the table could put the clear height below the rest height: the rise then counts as complete
    rise = (cube_a[:, 2] - rest_height) / torch.clamp(clear_height - rest_height, min=1e-3)
    hover = place.clone()
    hover[:, 2] += HOVER
    opened = torch.clamp((finger_opening - CUBE_A_SIZE / 2.0) / (OPEN - CUBE_A_SIZE / 2.0), 0.0, 1.0)
    at_rest = 1.0 - torch.tanh(10.0 * speed + spin)
    # each stage from reach on: whether it holds, and its progress
    stages = ((torch.ones_like(held), closeness(grasp)), (held, torch.clamp(rise, 0.0, 1.0)),
              (held & clear, closeness(hover)), (held & clear & over_xy, closeness(place)),
              (on_b, (opened + at_rest) / 2.0), (stacked, torch.zeros_like(speed)))
    reward, stage = torch.zeros_like(speed), torch.zeros_like(speed, dtype=torch.long)
    for index, ((reached, progress), level) in enumerate(zip(stages, levels, strict=True)):
        reward = torch.where(reached, level + progress, reward)
        stage = torch.where(reached, index, stage)
    return reward / levels[STACKED], stage
