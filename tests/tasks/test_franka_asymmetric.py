"""env.asymmetric_observations on the Franka cube tasks (issue 44): the critic reads the policy's observation and what
the simulator knows (joint speeds, cube velocities, fingertips relative to cube A, whether it is held). Sizes derived
from the terms; velocities against MuJoCo C's qvel of each cube's free joint; the held flag against a formula written
here; off changes nothing; one training iteration with it on; a bad value is a one-line error."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

from isaacgymenvs_mw import make as make_task
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.tasks.franka import fingertips
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError

# privileged sizes: joint speeds 9 (FrankaCubeLift observes them already), per cube 3 + 3, fingertips 6, held 1
EXTRA = {"FrankaCubeStack": 9 + 2 * 6 + 6 + 1, "FrankaCubeLift": 6 + 6 + 1}
CUBES = {"FrankaCubeStack": {"cube_a": "cubeA", "cube_b": "cubeB"}, "FrankaCubeLift": {"cube": "cubeA"}}


def make(task: str, on: bool, num_envs: int = 2):
    return make_task(task, num_envs=num_envs, sim_device="cpu", rl_device="cpu", headless=True,
                     overrides=[f"task.env.asymmetric_observations={on}"])


def free_joint_velocity(model: mujoco.MjModel, qvel: np.ndarray, asset: str) -> np.ndarray:
    """The 6 qvel entries of the free joint of scene asset ``asset`` (its bodies are named ``<asset>/...``), by
    MuJoCo C's addressing."""
    (joint,) = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE
                and mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, model.jnt_bodyid[j]).startswith(asset + "/")]
    start = model.jnt_dofadr[joint]
    return qvel[start:start + 6]


@pytest.mark.parametrize("task", ["FrankaCubeStack", "FrankaCubeLift"])
def test_the_critic_state_is_the_observation_and_the_simulators_knowledge(task):
    env = make(task, on=True)
    assert env.num_states == env.num_obs + EXTRA[task]
    env.reset()
    generator = torch.Generator().manual_seed(3)
    for _ in range(12):  # moving: the arm swings and the cubes settle, so velocities are not all zero
        obs, *_ = env.step(torch.rand(2, env.num_actions, generator=generator) * 2 - 1)
    layout = env.observations.state_layout
    assert torch.equal(obs["states"][:, :env.num_obs], obs["obs"])  # the policy's observation first, as it is
    # Distinct speeds in every dof (cubes at rest would read 0 from any column), then the state computed again.
    env.sim.qvel.copy_(torch.arange(env.sim.qvel.numel(), dtype=torch.float32).view_as(env.sim.qvel) * 0.01 + 0.1)
    env.compute_observations()
    states = env.states_buf
    qvel = env.sim.qvel.numpy()
    for world in range(2):
        for name, body in CUBES[task].items():
            want = free_joint_velocity(env.sim.mj_model, qvel[world], body)
            np.testing.assert_allclose(states[world, layout.slices[f"{name}_lin_vel"]].numpy(), want[:3], atol=1e-6)
            np.testing.assert_allclose(states[world, layout.slices[f"{name}_ang_vel"]].numpy(), want[3:], atol=1e-6)
    cube = env.sim.asset("cubeA").root_pos
    left, right = fingertips(env.arm)
    np.testing.assert_allclose(states[:, layout.slices["fingertips_to_cube"]].numpy(),
                               torch.cat((left - cube, right - cube), dim=1).numpy(), atol=1e-6)
    grasp, opening = env.arm.grasp_pos(), env.sim.dof_pos[:, 7]
    for world in range(2):
        near = math.dist(cube[world].tolist(), grasp[world].tolist()) < 0.03
        assert float(states[world, layout.slices["held"]]) == float(near and float(opening[world]) < 0.03)


@pytest.mark.parametrize("task", ["FrankaCubeStack", "FrankaCubeLift"])
def test_off_the_critic_reads_the_policys_observation(task):
    env = make(task, on=False)
    assert env.num_states == 0
    vec = RslRlVecEnv(env)
    obs = vec.get_observations()
    assert torch.equal(obs["critic"], obs["policy"])  # the train YAML's critic group [critic] falls back to it


def test_one_training_iteration_with_an_asymmetric_critic(tmp_path):
    cfg = compose_config(["task=FrankaCubeStack", "num_envs=2", "max_iterations=1", "train.runner.num_steps_per_env=8",
                          "task.env.asymmetric_observations=True", "sim_device=cpu", "rl_device=cpu", "headless=True",
                          "train.algorithm.share_trunk=False",  # the shipped trunk is shared: its value reads the policy's input
                          f"runs_dir={tmp_path / 'runs'}"])
    summary = run(cfg)
    assert summary["iterations"] == 1
    (checkpoint,) = (tmp_path / "runs" / "FrankaCubeStack").glob("*/model_1.pt")
    critic = torch.load(checkpoint, weights_only=False)["critic_state_dict"]
    first = [v for k, v in critic.items() if k.endswith(".weight")][0]
    assert first.shape[1] == 19 + EXTRA["FrankaCubeStack"]  # osc's 19-value observation (IGE's) + the privileged state


def test_a_bad_value_is_a_one_line_error_naming_the_key():
    with pytest.raises(ConfigError, match=r"env\.asymmetric_observations='maybe' is invalid"):
        make("FrankaCubeLift", on="maybe")
