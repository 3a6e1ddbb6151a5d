"""Independent reference for the in-hand tasks' reward (AllegroHand, ShadowHand): IsaacGymEnvs' compute_hand_reward
for one env in plain Python, and the check of a task's reward against it on constructed cube states. Nothing here
imports isaacgymenvs_mw."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import torch


def reference_reward(obj_pos, obj_quat, goal_pos, goal_quat, actions, tol=0.1, fall=0.24, fall_penalty=0.0):
    """IsaacGymEnvs' compute_hand_reward for one env, in plain Python (xyzw there, wxyz here; the formula is the
    same on the vector part of the relative quaternion), with the constants of AllegroHand.yaml and ShadowHand.yaml
    (the same)."""
    goal_dist = math.sqrt(sum((p - g) ** 2 for p, g in zip(obj_pos, goal_pos)))
    rel = np.zeros(4)
    conj = np.array(goal_quat) * [1, -1, -1, -1]
    mujoco.mju_mulQuat(rel, np.array(obj_quat), conj)
    rot_dist = 2.0 * math.asin(min(math.sqrt(sum(v * v for v in rel[1:])), 1.0))
    reward = goal_dist * -10.0 + 1.0 / (abs(rot_dist) + 0.1) + sum(a * a for a in actions) * -0.0002
    reached = abs(rot_dist) <= tol
    if reached:
        reward += 250.0
    if goal_dist >= fall:
        reward += fall_penalty
    return reward, reached, goal_dist >= fall


def place_cube(env, pos, quat) -> None:
    """Put every world's cube at ``pos`` (N, 3) and ``quat`` (N, 4, w x y z), at rest, poses refreshed."""
    n = env.num_envs
    mask = torch.ones(n, dtype=torch.bool)
    zero = torch.zeros(n, 3)
    env.sim.write_state(mask, root_pos=torch.tensor(pos, dtype=torch.float32),
                        root_quat=torch.tensor(quat, dtype=torch.float32), root_lin_vel=zero, root_ang_vel=zero,
                        asset="object", refresh=True)


def assert_reward_is_the_reference(env, pos, quat, actions, fall_penalty: float, reward_scale: float = 1.0) -> None:
    """The task's reward with the cube placed at (pos, quat) and the given last actions equals ``reward_scale`` x
    the reference formula (1: a task YAML holds IsaacGymEnvs' reward unscaled; the learner recipe scales it)."""
    place_cube(env, pos, quat)
    env.actions.copy_(torch.tensor(actions, dtype=torch.float32))
    env.refresh_state()
    env.compute_reward()
    ref = [reference_reward(p, q, g, gq, a, fall_penalty=fall_penalty)[0] for p, q, g, gq, a in
           zip(pos, quat, env.goal_pos.numpy(), env.goal_quat.numpy(), env.actions.numpy())]
    np.testing.assert_allclose(env.rew_buf.numpy(), reward_scale * np.array(ref), rtol=1e-4)
