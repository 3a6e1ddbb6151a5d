"""AllegroKukaRegrasping and AllegroKukaThrow: IsaacGymEnvs' other two AllegroKuka subtasks, on AllegroKuka's
scene, observation, actions and reward (tasks/allegro_kuka.py).

Facts from isaac-sim/IsaacGymEnvs (commit aeed298): isaacgymenvs/tasks/allegro_kuka/allegro_kuka_regrasping.py,
allegro_kuka_throw.py, allegro_kuka_base.py and cfg/task/env/{regrasping,throw}.yaml. Both subtasks differ from
reorientation in the same ways, and only those (IGE's compute_kuka_reward is the base class's for all three):

* one keypoint, at the cube's centre (orientation does not matter): the keypoint reward pays for bringing the centre
  closer than ever to the goal position, a success is the centre within successTolerance x keypointScale of it, and
  the observation has 3 + 3 keypoint values instead of 12 + 12 (99 values);
* a success puts the cube back on the table (IGE's _reset_target calls reset_object_pose and clears the lifted flag),
  so each goal is reached from a fresh grasp and the lifting reward and bonus are paid again;
* the episode fails only when the cube falls below 0.1 m (the hand-far rule is reorientation's alone).

Regrasping: the goal is a position uniform in reorientation's target box; successSteps 30 (half a second) near it
make a success, so the cube must be held there. The goal marker shows the position (its orientation stays identity).

Throw: the goal is 5 cm above the origin of a bucket (``env.assets.bucket``, assets/mjcf/bucket_allegro_kuka.xml, a
mocap body moved at each draw) placed left or right of the table: x = +-(0.5 + U(0, 0.4)), y ~ U(-1.0, 0.7),
z ~ U(0, 1) (m, world frame); successSteps 5 near it make a success. No pushes on the cube (forceScale 0) and a fixed
tolerance (targetSuccessTolerance = successTolerance), as IGE's throw.yaml.
"""

from __future__ import annotations

import torch

from isaacgymenvs_mw.tasks.allegro_kuka import AllegroKuka, uniform_in_box
from isaacgymenvs_mw.utils.errors import ConfigError

CENTRE_KEYPOINT = ((0, 0, 0),)  # IGE's _object_keypoint_offsets of both subtasks
# Throw's bucket draw (allegro_kuka_throw.py, _reset_target), world frame (m)
BUCKET_SIDE_OFFSET = 0.5  # |x| at least this: left or right of the table, with equal chance
BUCKET_SIDE_SPREAD = 0.4  # ... plus U(0, this)
BUCKET_Y_RANGE = (-1.0, 0.7)
BUCKET_Z_RANGE = (0.0, 1.0)
BUCKET_GOAL_HEIGHT = 0.05  # the goal: this far above the bucket's origin (its outer bottom)


class _CentreGoalSubtask(AllegroKuka):
    """What regrasping and throw share: the centre keypoint, the fall-only failure rule, and a goal draw that puts
    the cube back on the table (subclasses draw the goal position in ``_goal_positions``)."""

    keypoint_pattern = CENTRE_KEYPOINT
    hand_far_ends_episode = False

    def _sample_goals(self, mask: torch.Tensor) -> None:
        rows = mask.unsqueeze(1)
        self.goal_pos.copy_(torch.where(rows, self._goal_positions(mask), self.goal_pos))
        # The cube back at its start pose, not lifted: each goal starts from a new grasp (IGE: after a success too).
        self._reset_object(mask)

    def _goal_positions(self, mask: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError


class AllegroKukaRegrasping(_CentreGoalSubtask):
    """Lift the cube and hold its centre at a goal position drawn in the air for successSteps policy steps; after
    each success the cube is back on the table. Observation 99 values, actions 23 (as AllegroKuka)."""

    def _goal_positions(self, mask: torch.Tensor) -> torch.Tensor:
        return uniform_in_box(self.num_envs, self.device)


class AllegroKukaThrow(_CentreGoalSubtask):
    """Lift the cube and throw it into a bucket placed beside the table: a success is its centre near a point 5 cm
    above the bucket's origin for successSteps policy steps; after each success the bucket moves and the cube is
    back on the table. Observation 99 values, actions 23 (as AllegroKuka)."""

    def __init__(self, cfg, rl_device, sim_device, graphics_device_id, headless,
                 virtual_screen_capture=False, force_render=False):
        if "bucket" not in (cfg["env"].get("assets") or {}):
            raise ConfigError("env.assets.bucket is not set: AllegroKukaThrow needs the bucket, give "
                              "assetFileName: mjcf/bucket_allegro_kuka.xml with fixBaseLink: True")
        super().__init__(cfg, rl_device, sim_device, graphics_device_id, headless, virtual_screen_capture,
                         force_render)
        # the bucket's column in mocap_pos; the first draw is the first reset's, after construction
        self.bucket_marker = self.sim.mocap_index(self.sim.asset("bucket").body_names[0])
        self.goal_above_bucket = torch.tensor((0.0, 0.0, BUCKET_GOAL_HEIGHT), device=self.device)

    def _goal_positions(self, mask: torch.Tensor) -> torch.Tensor:
        bucket = sample_bucket_positions(self.num_envs, self.device)
        column = self.bucket_marker
        self.sim.mocap_pos[:, column] = torch.where(mask.unsqueeze(1), bucket, self.sim.mocap_pos[:, column])
        return bucket + self.goal_above_bucket

    @property
    def bucket_pos(self) -> torch.Tensor:
        """(num_envs, 3) the buckets' origins (world frame)."""
        return self.sim.mocap_pos[:, self.bucket_marker]


def sample_bucket_positions(n: int, device: torch.device | str) -> torch.Tensor:
    """(n, 3) IGE's bucket positions: x on a side of the table chosen with equal chance, 0.5-0.9 m from its centre
    line; y uniform in [-1.0, 0.7]; z uniform in [0, 1] (m, world frame)."""
    side = torch.where(torch.rand(n, device=device) * 2.0 - 1.0 > 0.0, 1.0, -1.0)
    x = side * (BUCKET_SIDE_OFFSET + BUCKET_SIDE_SPREAD * torch.rand(n, device=device))
    y = BUCKET_Y_RANGE[0] + (BUCKET_Y_RANGE[1] - BUCKET_Y_RANGE[0]) * torch.rand(n, device=device)
    z = BUCKET_Z_RANGE[0] + (BUCKET_Z_RANGE[1] - BUCKET_Z_RANGE[0]) * torch.rand(n, device=device)
    return torch.stack((x, y, z), dim=-1)
