"""AllegroHand: turn a cube in the palm of a Wonik Allegro hand to a goal orientation (IsaacGymEnvs' task).

The scene (``cfg/task/AllegroHand.yaml``): the hand (``env.asset``, 16 position-driven joints) welded palm up at
``env.baseInitState``; the 6.5 cm cube (``env.assets.object``, free) starting above the palm; the goal
(``env.assets.goal``), a copy of the cube as a mocap body that only shows the goal orientation, beside the hand.
The actions, reward, success, episode end and ``consecutive_successes`` are the in-hand tasks' (tasks/in_hand.py),
shared with ShadowHand.

Differences from IsaacGymEnvs, on purpose (besides the in-hand tasks'): the DOF-force observation (``full_state``)
is the drives' torque, which IGE meant to read from force sensors it never enables; IGE's draw for thumb_joint_0,
whose range excludes its default 0, is clamped into the range.
"""

from __future__ import annotations

from isaacgymenvs_mw.tasks.base.observation_terms import ObsTerm
from isaacgymenvs_mw.tasks.in_hand import InHandTask


class AllegroHand(InHandTask):
    """Observation (``env.observationType``): the joints, the cube's and the goal's poses, the rotation from the goal
    to the cube and the last actions; ``full`` adds velocities, ``full_state`` the drive torques.
    ``env.asymmetric_observations`` gives the critic the ``full_state`` observation. Actions (16): joint targets."""

    observation_types = ("full_no_vel", "full", "full_state")

    def _terms_of(self, kind: str) -> list[ObsTerm]:
        return (self._joint_terms(kind) + self._object_terms(kind) + self._goal_terms()
                + [self._action_term()])
