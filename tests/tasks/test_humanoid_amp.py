"""HumanoidAMP (issue 73): builds, steps, and starts its episodes from the motion it imitates."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy
import pytest
import torch

import isaacgymenvs_mw
from isaacgymenvs_mw.tasks.amp.observations import dof_to_obs, humanoid_observation, tan_norm, xyz_euler_to_quat
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.rotations import quat_about_axis, quat_mul, quat_rotate, yaw_from_quat

ASSET = Path(__file__).resolve().parents[2] / "assets" / "mjcf" / "amp_humanoid.xml"

N = 3


@pytest.fixture(scope="module")
def task():
    t = isaacgymenvs_mw.make(task="HumanoidAMP", num_envs=N, sim_device="cpu", rl_device="cpu", headless=True)
    t.reset()
    return t


def _same_rotation(a, b):
    return (torch.sum(a * b, dim=-1).abs() > 1 - 1e-5).all()


def test_sizes(task):
    assert task.num_obs == 105 and task.num_actions == 28  # IGE's NUM_OBS and NUM_ACTIONS
    assert task.amp_obs.shape == (N, 210) and task.fetch_amp_obs_demo(5).shape == (5, 210)


def test_reset_pose_is_the_sampled_reference_pose(task):
    lib, all_envs = task.motion_lib, torch.ones(N, dtype=torch.bool)
    rng = torch.get_rng_state()
    task.reset_envs(all_envs)
    torch.set_rng_state(rng)
    ids = lib.sample_motions(N)
    times = lib.sample_times(ids)
    s = lib.state(ids, times)
    sim = task.sim
    torch.testing.assert_close(sim.root_pos, s.root_pos)
    assert _same_rotation(sim.root_quat, s.root_rot)
    torch.testing.assert_close(sim.dof_pos, s.dof_pos)
    torch.testing.assert_close(sim.dof_vel, s.dof_vel)
    torch.testing.assert_close(sim.root_lin_vel, s.root_vel)
    torch.testing.assert_close(quat_rotate(sim.root_quat, sim.root_ang_vel), s.root_ang_vel, atol=1e-5, rtol=1e-5)
    # MuJoCo's kinematics of the written state puts the key bodies where the motion's skeleton has them, up to the
    # difference between the library's lerped key positions and the slerped joints between two frames (mm)
    torch.testing.assert_close(sim.xpos[:, task.key_ids], s.key_pos, atol=1e-2, rtol=0)
    # the AMP history: now, then the motion one policy step earlier
    past = lib.state(ids, times - task.control_dt)
    want = humanoid_observation(past.root_pos, past.root_rot, past.root_vel, past.root_ang_vel, past.dof_pos,
                                past.dof_vel, past.key_pos, task.group_sizes, task.local_root_obs)
    torch.testing.assert_close(task._amp_hist[:, 1], want, atol=1e-5, rtol=1e-5)


def test_a_demo_is_what_the_policy_side_observes_of_the_same_motion_times(task):
    """fetch_amp_obs_demo and a reference start draw the same motion times from the same random state; the demo
    (from the motion library) then equals the AMP history the task builds from the simulator's state (MuJoCo's
    kinematics of the written pose for now, the motion one policy step earlier before it): same columns, newest
    first, one policy step apart."""
    all_envs = torch.ones(N, dtype=torch.bool)
    rng = torch.get_rng_state()
    task.reset_envs(all_envs)
    torch.set_rng_state(rng)
    demo = task.fetch_amp_obs_demo(N).view(N, 2, 105)
    hist = task._amp_hist
    keys = slice(105 - 12, 105)  # key body positions: the library lerps them, MuJoCo places them (mm apart)
    torch.testing.assert_close(demo[..., :keys.start], hist[..., :keys.start], atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(demo[..., keys], hist[..., keys], atol=1e-2, rtol=0)
    # the two steps differ (a running clip moves within 1/30 s): the spacing is not zero
    assert (demo[:, 0] - demo[:, 1]).abs().amax() > 1e-2


def test_steps_reward_and_amp_transition(task):
    task.reset_envs(torch.ones(N, dtype=torch.bool))
    before = task._amp_hist[:, 0].clone()
    obs, rew, reset, _ = task.step(torch.zeros(N, 28))
    assert torch.equal(rew, torch.ones(N))  # IGE's task reward
    assert torch.isfinite(obs["obs"]).all()
    kept = ~reset.bool()
    # the step's transition: the state before the step, then after it
    torch.testing.assert_close(task.amp_obs[kept, 105:], before[kept])
    torch.testing.assert_close(task.amp_obs[kept, :105], obs["obs"][kept])
    # the PD targets are IGE's offset + scale x action; zero action: the middle of each range
    torch.testing.assert_close(task.sim.ctrl, task.pd_offset.expand(N, -1))


def test_fall_ends_the_episode(task):
    task.reset_envs(torch.ones(N, dtype=torch.bool))
    sim = task.sim
    lying = torch.tensor([0.7071068, 0.7071068, 0.0, 0.0]).expand(N, 4)  # on its side (90 deg about x), low
    sim.write_state(torch.ones(N, dtype=torch.bool), root_pos=torch.tensor([0.0, 0.0, 0.2]).expand(N, 3),
                    root_quat=lying, root_lin_vel=torch.zeros(N, 3), root_ang_vel=torch.zeros(N, 3),
                    dof_pos=task.default_dof_pos.expand(N, -1), dof_vel=torch.zeros(N, 28))
    ended = torch.zeros(N, dtype=torch.bool)
    for _ in range(6):
        _, _, reset, extras = task.step(torch.zeros(N, 28))
        ended |= reset.bool() & ~extras["time_outs"].bool()
    assert ended.all()


def test_a_default_start_touches_nothing_and_standing_on_it_does_not_end_the_episode():
    """The Default start pose, checked in MuJoCo C: no contact in the model (no body in another); held by its PD
    targets, the humanoid standing there is not ended by the fall rule in its first 10 steps."""
    env = isaacgymenvs_mw.make(task="HumanoidAMP", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True,
                               overrides=["task.env.stateInit=Default"])
    model = mujoco.MjModel.from_xml_path(str(ASSET))
    data = mujoco.MjData(model)
    data.qpos[:7] = [0.0, 0.0, 0.89, 1.0, 0.0, 0.0, 0.0]
    data.qpos[7:] = env.default_dof_pos.cpu().numpy()
    mujoco.mj_forward(model, data)
    assert data.ncon == 0
    env.reset()
    hold = ((env.default_dof_pos - env.pd_offset) / env.pd_scale).expand(2, -1)
    for _ in range(10):
        _, _, reset, _ = env.step(hold)
        assert not reset.any()


def test_the_reference_motion_touches_nothing_but_its_feet(task):
    """The fall rule needs a contact of a body other than the feet. Played kinematically in MuJoCo C (mj_forward on
    the task's compiled model, ground included) at 120 Hz, no pose of the clip has one: no self-contact, no shin,
    hand or thigh pressing on the ground with more than the rule's 0.1 N. The rule's other half (a body other than
    the feet below 0.5 m) holds in most frames (the shins' origins, the knees, run as low as 0.34 m), so one such
    contact would end the episode."""
    model = task.sim.mj_model
    data = mujoco.MjData(model)
    lib = task.motion_lib
    times = torch.arange(0.0, float(lib.lengths[0]), 1.0 / 120.0)
    s = lib.state(torch.zeros(times.shape[0], dtype=torch.long), times)
    feet = {model.body(name).id for name in task.cfg["env"]["contactBodies"]}
    low_frames = 0
    for k in range(times.shape[0]):
        data.qpos[:3], data.qpos[3:7], data.qpos[7:] = s.root_pos[k], s.root_rot[k], s.dof_pos[k]
        mujoco.mj_forward(model, data)
        force = numpy.zeros(6)
        bodies = set()
        for i, c in enumerate(data.contact[:data.ncon]):
            mujoco.mj_contactForce(model, data, i, force)
            if abs(force[0]) > 0.1:  # the rule's 0.1 N (a grazing shin, 0 mm deep, pushes with 0 N)
                bodies |= {int(model.geom_bodyid[g]) for g in c.geom}
        assert bodies <= feet | {0}, f"t={times[k]:.3f} s: {[model.body(b).name for b in bodies - feet - {0}]}"
        others = [b for b in range(1, model.nbody) if b not in feet]
        low_frames += bool((data.xpos[others, 2] < task.termination_height).any())
    assert low_frames > times.shape[0] // 2


def test_bad_state_init_names_the_key():
    with pytest.raises(ConfigError, match=r"env\.stateInit"):
        isaacgymenvs_mw.make(task="HumanoidAMP", num_envs=1, sim_device="cpu", rl_device="cpu", headless=True,
                             overrides=["task.env.stateInit=Sometimes"])


# The humanoid's joints in dof order (assets/mjcf/amp_humanoid.xml): 3 hinges x-y-z, or one (elbows, knees).
GROUP_SIZES = [3, 3, 3, 1, 3, 1, 3, 1, 3, 3, 1, 3]


def _axis(n: int, i: int) -> torch.Tensor:
    v = torch.zeros(n, 3)
    v[:, i] = 1.0
    return v


def _reference_joint_quat(a: torch.Tensor) -> torch.Tensor:
    """Rx(a0) Ry(a1) Rz(a2) as the full Hamilton products of the three axis rotations."""
    return quat_mul(quat_mul(quat_about_axis(a[:, 0], 0), quat_about_axis(a[:, 1], 1)), quat_about_axis(a[:, 2], 2))


def _reference_dof_obs(dof_pos: torch.Tensor, sizes: list[int]) -> torch.Tensor:
    """One joint at a time: the rotated x and z axes of each 3-hinge joint, the angle of a 1-hinge one."""
    n, cols, i = dof_pos.shape[0], [], 0
    for size in sizes:
        if size == 3:
            q = _reference_joint_quat(dof_pos[:, i:i + 3])
            cols += [quat_rotate(q, _axis(n, 0)), quat_rotate(q, _axis(n, 2))]
        else:
            cols.append(dof_pos[:, i:i + 1])
        i += size
    return torch.cat(cols, dim=-1)


def _random_angles(n: int, cols: int, gen: torch.Generator) -> torch.Tensor:
    a = (torch.rand(n, cols, generator=gen) - 0.5) * 4 * torch.pi
    a[: n // 8] = 0.0  # a joint at rest: the products' zero terms meet exact zeros
    a[n // 8: n // 4] = torch.pi
    return a


@pytest.mark.parametrize("n", [1, 5, 64])
def test_batched_joint_rotations_equal_the_products_one_joint_at_a_time(n):
    """The written-out Rx Ry Rz, the batched tan_norm and the batched dof_to_obs round as the full quaternion
    products of one joint at a time do (the dropped terms are products with exact zeros): equal, not close."""
    gen = torch.Generator().manual_seed(n)
    angles = _random_angles(n, 3, gen)
    assert torch.equal(xyz_euler_to_quat(angles), _reference_joint_quat(angles))
    q = torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=-1)
    assert torch.equal(tan_norm(q), torch.cat((quat_rotate(q, _axis(n, 0)), quat_rotate(q, _axis(n, 2))), dim=-1))
    for sizes in (GROUP_SIZES, [1, 3, 1], [1, 1]):
        dof_pos = _random_angles(n, sum(sizes), gen)
        assert torch.equal(dof_to_obs(dof_pos, sizes), _reference_dof_obs(dof_pos, sizes))


@pytest.mark.parametrize("local_root_obs", [False, True])
def test_humanoid_observation_equals_its_columns_computed_one_by_one(local_root_obs):
    n, k = 6, 4
    gen = torch.Generator().manual_seed(1)
    root_pos, root_vel, ang_vel = (torch.randn(n, 3, generator=gen) for _ in range(3))
    root_rot = torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=-1)
    dof_pos, dof_vel = _random_angles(n, 28, gen), torch.randn(n, 28, generator=gen)
    key_pos = torch.randn(n, k, 3, generator=gen)
    heading = quat_about_axis(-yaw_from_quat(root_rot), 2)
    rot = quat_mul(heading, root_rot) if local_root_obs else root_rot
    keys = [quat_rotate(heading, key_pos[:, j] - root_pos) for j in range(k)]
    want = torch.cat([root_pos[:, 2:3], quat_rotate(rot, _axis(n, 0)), quat_rotate(rot, _axis(n, 2)),
                      quat_rotate(heading, root_vel), quat_rotate(heading, ang_vel),
                      _reference_dof_obs(dof_pos, GROUP_SIZES), dof_vel, *keys], dim=-1)
    got = humanoid_observation(root_pos, root_rot, root_vel, ang_vel, dof_pos, dof_vel, key_pos, GROUP_SIZES,
                               local_root_obs)
    assert got.shape == (n, 105)
    assert torch.equal(got, want)
