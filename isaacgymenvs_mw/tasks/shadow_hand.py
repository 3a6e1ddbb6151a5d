"""ShadowHand: turn a cube in the palm of a Shadow Dexterous Hand to a goal orientation (IsaacGymEnvs' task, and
with ``cfg/task/ShadowHandOpenAI_FF.yaml`` its OpenAI feed-forward variant).

The scene (``cfg/task/ShadowHand.yaml``): the hand (``env.asset``: ``assets/mjcf/shadow_hand.xml``, 24 joints, 20
position servos, each finger's distal joint J1 coupled to its middle joint J2) welded palm up; the 5 cm cube
(``env.assets.object``, free) starting above the palm; the goal marker (``env.assets.goal``) beside the hand. The
actions (20, IGE's order), reward, success, episode end and ``consecutive_successes`` are the in-hand tasks'
(tasks/in_hand.py), shared with AllegroHand.

Observation types (``env.observationType``), IGE's layouts and sizes:
- ``openai`` (42): fingertip positions, the cube's position, the rotation from the goal to the cube, the actions
  (OpenAI's "Learning Dexterous In-Hand Manipulation", table 2);
- ``full_no_vel`` (77): joints over their ranges, cube and goal poses, that rotation, fingertip positions, actions;
- ``full`` (157): with joint and cube velocities and the fingertip states (pose and velocity) for the positions;
- ``full_state`` (211): with the joint forces and the fingertips' force-torque sensors.
The fingertips are the frames of the distal bodies ``ffdistal`` ... ``thdistal`` (IGE's fingertip bodies, whose
origin is the distal joint), read from the last physics step's kinematics: one physics step (1/120 s) older than the
joint and cube state (IGE refreshes them after the step).

Differences from IsaacGymEnvs, on purpose (besides the in-hand tasks'): the hand model is this project's (Shadow's
published figures; the distal coupling is an equality J1 = J2, IGE's a tendon with a limit); the fingertip force
sensors are MuJoCo's force and torque sensors on the distal frames (the force the phalanx receives through its joint,
in its frame).
"""

from __future__ import annotations

import torch

from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.in_hand import FORCE_OBS_SCALE, InHandTask
from isaacgymenvs_mw.utils.errors import ConfigError

# IGE's fingertip bodies (OpenAI's robot0:ffdistal ...), in its order; each has a site of its name on its frame
# carrying the sensors <name>_force and <name>_torque (assets/mjcf/shadow_hand.xml).
FINGERTIPS = ("ffdistal", "mfdistal", "rfdistal", "lfdistal", "thdistal")


class ShadowHand(InHandTask):
    """Observation: ``env.observationType`` (module docstring); ``env.asymmetric_observations`` gives the critic the
    ``full_state`` observation. Actions (20): servo targets over each servo's range."""

    observation_types = ("openai", "full_no_vel", "full", "full_state")

    def bind_hand(self) -> None:
        sim = self.sim
        missing = [name for name in FINGERTIPS if name not in sim.body_names]
        if missing:
            raise ConfigError(f"env.asset.assetFileName={self.cfg['env']['asset']['assetFileName']!r}: the hand has "
                              f"no fingertip bodies {missing}; ShadowHand observes {list(FINGERTIPS)}")
        self.fingertip_ids = sim.body_ids(list(FINGERTIPS))
        # Each fingertip's force then torque sensor (N, 3 each), fingertip by fingertip.
        self.fingertip_sensors = [sim.sensor(f"{name}_{kind}", key="env.asset.assetFileName")
                                  for name in FINGERTIPS for kind in ("force", "torque")]

    def _terms_of(self, kind: str) -> list[ObsTerm]:
        n_tips = len(FINGERTIPS)
        tip_pos = ObsTerm("fingertip_pos", 3 * n_tips, compute=self._fingertip_pos)       # m, world frame
        if kind == "openai":
            return [tip_pos, ObsTerm("object_pos", 3, compute=lambda: self.cube.root_pos),  # m, world frame
                    ObsTerm("object_to_goal_quat", 4, compute=self._object_to_goal_quat),   # object x goal^-1
                    self._action_term()]
        tips = [tip_pos]
        if kind != "full_no_vel":
            # pose (w, x, y, z) and world-frame velocity of each distal frame, 13 per fingertip (IGE's body state)
            tips = [ObsTerm("fingertip_state", 13 * n_tips, compute=self._fingertip_state)]
        if kind == "full_state":
            tips.append(ObsTerm("fingertip_force_torque", 6 * n_tips, FORCE_OBS_SCALE,  # N, N m: force then torque
                                compute=lambda: torch.cat(self.fingertip_sensors, dim=1)))
        return (self._joint_terms(kind) + self._object_terms(kind) + self._goal_terms() + tips
                + [self._action_term()])

    def _fingertip_pos(self) -> torch.Tensor:
        return self.sim.xpos[:, self.fingertip_ids].reshape(self.num_envs, -1)

    def _fingertip_state(self) -> torch.Tensor:
        return self.sim.body_states(self.fingertip_ids).reshape(self.num_envs, -1)
