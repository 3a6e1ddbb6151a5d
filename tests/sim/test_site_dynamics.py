"""sim/dynamics.py: the mass matrix and a site's Jacobian per world, read from MuJoCo Warp's step data in torch,
against MuJoCo C's mj_fullM and mj_jacSite on the same states (the Panda of FrankaCubeStack: 7 hinges, 2 slides,
and two free cubes whose dofs are left out)."""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from isaacgymenvs_mw import make
from isaacgymenvs_mw.sim.dynamics import SiteDynamics


def test_mass_matrix_and_site_jacobian_equal_mujoco_c():
    env = make("FrankaCubeStack", num_envs=3, sim_device="cpu", rl_device="cpu", seed=0)
    sim = env.sim
    rng = np.random.default_rng(3)
    q = sim.dof_pos.clone()
    lo, hi = env.arm.dof_lower.numpy(), env.arm.dof_upper.numpy()
    q[:] = torch.as_tensor(rng.uniform(lo, hi, size=(3, 9)), dtype=torch.float32)
    sim.write_state(torch.ones(3, dtype=torch.bool), dof_pos=q, refresh=False)
    sim.forward()
    site = sim.site_id("grasp")
    dofs = list(range(9))
    dyn = SiteDynamics(sim, site, dofs)
    M, J = dyn.mass_matrix().numpy(), dyn.jacobian().numpy()

    m = sim.mj_model
    d = mujoco.MjData(m)
    for w in range(3):
        d.qpos[:] = sim.qpos[w].numpy()
        mujoco.mj_forward(m, d)
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)
        jacp, jacr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        mujoco.mj_jacSite(m, d, jacp, jacr, site)
        np.testing.assert_allclose(M[w], full[np.ix_(dofs, dofs)], rtol=1e-4, atol=1e-6)
        np.testing.assert_allclose(J[w], np.vstack((jacp, jacr))[:, dofs], atol=1e-5)
        # the arm's joints move the site; the fingers (children of the hand, where the site is) do not
        assert np.abs(J[w][:, :7]).max() > 0.1 and not J[w][:, 7:].any()
