"""AllegroHand (issue 69): a cube started as IsaacGymEnvs starts it (its reset draws) rests on the hand held at its
reset pose, and the per-step reward of such a resting cube at IGE's random goal orientations, from a formula written
here, is not negative on average and equals the task's.

Zero absolute actions are not this case: they set mid-range targets, the fingers curl 0.72 rad per flexion joint
and throw the cube, which falls in most envs with IGE's own collision meshes too (docs/porting.md, AllegroHand)."""

from __future__ import annotations

import numpy as np
import torch

from isaacgymenvs_mw import make
from isaacgymenvs_mw.tasks.in_hand import random_rotation

CPU = {"sim_device": "cpu", "rl_device": "cpu", "headless": True}
N_ENVS, REST_STEPS = 8, 150  # 5 s of 30 Hz policy steps


def quat_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (rad) of the rotation between unit (w, x, y, z) quaternions, per row: 2 acos |<a, b>|."""
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=1)), 0.0, 1.0))


def test_a_cube_started_as_ige_rests_on_the_held_hand_and_its_reward_is_not_negative():
    # Relative control with zero actions keeps every servo at the reset pose IGE draws (0.2 x a point of each range).
    env = make("AllegroHand", num_envs=N_ENVS, seed=0, **CPU,
               overrides=["task.env.useRelativeControl=True", "task.env.episodeLength_s=100"])
    env.reset()
    zero = torch.zeros(N_ENVS, 16)
    fell = torch.zeros(N_ENVS, dtype=torch.bool)
    for _ in range(REST_STEPS):
        _, _, done, _ = env.step(zero)
        fell |= done.bool()  # a fall ends the episode (no time-out in 100 s)
    # The stated fraction: at least 6 of 8 rest (measured on the CPU, 8 of 64 cubes fall from the held hand in
    # 150 steps; with IGE's own collision meshes in MuJoCo C, 7 of 64: a cube landing near an edge slides off).
    assert int(fell.sum()) <= 2
    rest = ~fell.numpy()
    pos = env.cube.root_pos.numpy()[rest]
    goal_pos = env.goal_pos.numpy()[rest]
    assert float(np.linalg.norm(env.cube.root_lin_vel.numpy()[rest], axis=1).max()) < 0.01  # at rest
    # On the fingers, above IGE's goal position (the start 4 cm lower) and near it (a cube leaning on a curled
    # finger rests higher); the palm, where a thrown cube lands, is about 11 cm from it.
    dist = np.linalg.norm(pos - goal_pos, axis=1)
    assert bool((pos[:, 2] > goal_pos[:, 2]).all()) and float(dist.max()) < 0.08

    torch.manual_seed(1)
    rewards = []
    for _ in range(25):
        goal = random_rotation(N_ENVS, "cpu")
        env.goal_quat.copy_(goal)
        _, rew, _, _ = env.step(zero)
        cube_pos, cube_quat = env.cube.root_pos.numpy()[rest], env.cube.root_quat.numpy()[rest]
        rot = quat_angle(cube_quat, goal.numpy()[rest])
        # IGE's compute_hand_reward at zero actions: -10 d + 1 / (rot + 0.1) (+ 250 on a success)
        plain = -10.0 * np.linalg.norm(cube_pos - goal_pos, axis=1) + 1.0 / (rot + 0.1)
        np.testing.assert_allclose(rew.numpy()[rest], plain + 250.0 * (rot <= 0.1), rtol=1e-5, atol=1e-5)
        rewards.append(plain)
    assert float(np.mean(rewards)) >= 0.0
