"""Independent references for the Cartpole tests: IsaacGymEnvs' reward/reset in numpy, MuJoCo C stepping.

Nothing here imports isaacgymenvs_mw: the numbers the tests compare against come from these formulas and from
``mujoco.mj_step`` on the task's compiled host model.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

CART_JOINT = "slider_to_cart"  # joint names of assets/urdf/cartpole.urdf
POLE_JOINT = "cart_to_pole"


def cartpole_reward_reference(cart_pos, cart_vel, pole_angle, pole_vel, reset_dist, progress, max_episode_length):
    """IsaacGymEnvs Cartpole, float64: reward 1 - θ² - 0.01|ẋ| - 0.005|θ̇| (or -2 on failure), reset, failed."""
    x = np.asarray(cart_pos, dtype=np.float64)
    xd = np.asarray(cart_vel, dtype=np.float64)
    th = np.asarray(pole_angle, dtype=np.float64)
    thd = np.asarray(pole_vel, dtype=np.float64)
    progress = np.asarray(progress)
    failed = (np.abs(x) > reset_dist) | (np.abs(th) > math.pi / 2)
    reward = 1.0 - th * th - 0.01 * np.abs(xd) - 0.005 * np.abs(thd)
    reward = np.where(failed, -2.0, reward)
    reset = failed | (progress >= max_episode_length - 1)
    return reward, reset, failed


def joint_addresses(model: mujoco.MjModel) -> tuple[int, int, int, int]:
    """(cart qpos adr, pole qpos adr, cart dof adr, pole dof adr), looked up by joint name in the MjModel."""
    out = []
    for name in (CART_JOINT, POLE_JOINT):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        assert jid >= 0, f"joint {name} not in model"
        out.append(int(model.jnt_qposadr[jid]))
    for name in (CART_JOINT, POLE_JOINT):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        out.append(int(model.jnt_dofadr[jid]))
    return tuple(out)


def mj_data_from(model: mujoco.MjModel, qpos, qvel) -> mujoco.MjData:
    d = mujoco.MjData(model)
    d.qpos[:] = np.asarray(qpos, dtype=np.float64)
    d.qvel[:] = np.asarray(qvel, dtype=np.float64)
    return d


def mj_step_from(model: mujoco.MjModel, qpos, qvel, ctrl, nsteps: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """State after ``nsteps`` mujoco.mj_step calls from (qpos, qvel) with constant ctrl (MuJoCo C, float64)."""
    d = mj_data_from(model, qpos, qvel)
    d.ctrl[:] = np.asarray(ctrl, dtype=np.float64)
    for _ in range(nsteps):
        mujoco.mj_step(model, d)
    return d.qpos.copy(), d.qvel.copy()


def mj_step_batch(model, qpos, qvel, ctrl, nsteps: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """mj_step_from for each row of (num_envs, ...) arrays."""
    results = [mj_step_from(model, qpos[i], qvel[i], ctrl[i], nsteps) for i in range(len(qpos))]
    return np.stack([r[0] for r in results]), np.stack([r[1] for r in results])
