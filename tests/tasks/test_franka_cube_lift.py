"""FrankaCubeLift and FrankaCubeLiftDepth (issue 33): the reward terms and the success test against a formula written
here in plain Python, on constructed positions; reset draws (on the table, within the noise); a scripted grasp and
lift in joint_pos on the CPU that ends an episode as a success; the depth task's observation groups (the actor's flat
group without the cube, the critic's with it, the camera's shape); the depth image seeing the cube where a pinhole
model written here puts it; one training iteration plus test mode for both tasks; one-line errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import tensorboard_scalars
from isaacgymenvs_mw import make as make_task
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.tasks.base.metrics import OUTCOME
from isaacgymenvs_mw.tasks.franka_cube_lift import cube_lift_terms, sample_cube
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError

TABLE_TOP = -0.1  # assets/mjcf/table.xml
REST_Z = TABLE_TOP + 0.025  # the 5 cm cube's centre on the table
LIFT = 0.1  # cfg/task/FrankaCubeLift.yaml liftHeight
SCALES = {"dist": 0.1, "grasp": 0.25, "lift_height": 1.0, "lift": 1.5}  # the YAML's reward scales
Q0 = np.array([0.0, 0.1963, 0.0, -2.6180, 0.0, 2.9416, 0.7854, 0.035, 0.035])  # IGE's start pose


def make(task: str = "FrankaCubeLift", num_envs: int = 2, overrides: tuple[str, ...] = ()):
    return make_task(task, num_envs=num_envs, sim_device="cpu", rl_device="cpu", headless=True,
                     overrides=list(overrides))


def reference(cube, grasp, tip_l, tip_r, opening, lift=LIFT):
    """Reward, success and terms of one env, in plain Python."""
    def dist(a, b):
        return math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b)))

    approach = 1.0 - math.tanh(10.0 * (dist(cube, grasp) + dist(cube, tip_l) + dist(cube, tip_r)) / 3.0)
    held = 1.0 if dist(cube, grasp) < 0.03 and opening < 0.03 else 0.0
    rise = cube[2] - REST_Z
    lift_height = held * min(max(rise / lift, 0.0), 1.0)
    lifted = 1.0 if rise >= lift else 0.0
    terms = {"dist": approach, "held": held, "lift_height": lift_height, "lifted": lifted}
    reward = (SCALES["dist"] * approach + SCALES["grasp"] * held + SCALES["lift_height"] * lift_height
              + SCALES["lift"] * lifted)
    return reward, bool(held and lifted), terms


def constructed_cases():
    """(name, cube, grasp, finger opening): the situations the terms tell apart."""
    c = np.array([0.5, 0.1, REST_Z])
    up = c + [0, 0, 0.12]
    half = c + [0, 0, 0.05]
    return [("resting, hand away", c, c + [0.0, 0.0, 0.2], 0.04),
            ("resting, held", c, c + [0.0, 0.0, 0.005], 0.02),
            ("held half way up", half, half + [0.01, 0.0, 0.0], 0.024),
            ("held and lifted", up, up + [0.0, 0.01, 0.0], 0.024),
            ("held just below the target", c + [0, 0, 0.099], c + [0, 0, 0.099], 0.024),
            ("lifted, gripper open", up, up, 0.04),
            ("lifted, hand 5 cm away", up, up + [0.05, 0.0, 0.0], 0.02),
            ("knocked off the table", c + [0, 0, -0.5], c, 0.0)]


def test_terms_and_reward_equal_the_plain_python_formula():
    rng = np.random.default_rng(3)
    cases = constructed_cases()
    n_random = 300
    cube = np.column_stack([rng.uniform(0.2, 0.7, n_random), rng.uniform(-0.25, 0.25, n_random),
                            REST_Z + rng.choice([0.0, 1.0], n_random) * rng.uniform(0.0, 0.2, n_random)])
    grasp = cube + rng.normal(0.0, 0.015, (n_random, 3))
    cube = np.vstack([cube, [c[1] for c in cases]])
    grasp = np.vstack([grasp, [c[2] for c in cases]])
    opening = np.concatenate([rng.uniform(0.0, 0.04, n_random), [c[3] for c in cases]])
    n = len(cube)
    # fingertips about 4 cm to either side of the grasp point, varied
    tip_l = grasp + [0.0, 0.04, 0.0] + rng.normal(0.0, 0.01, (n, 3))
    tip_r = grasp - [0.0, 0.04, 0.0] + rng.normal(0.0, 0.01, (n, 3))
    t = lambda x: torch.tensor(x, dtype=torch.float64)
    got = cube_lift_terms(t(cube), t(grasp), t(tip_l), t(tip_r), t(opening), LIFT)
    ref = [reference(*v) for v in zip(cube, grasp, tip_l, tip_r, opening)]
    for key in ("dist", "held", "lift_height", "lifted"):
        np.testing.assert_allclose(got[key].numpy(), [r[2][key] for r in ref], atol=1e-12, err_msg=key)
    assert got["success"].tolist() == [r[1] for r in ref]
    named = dict(zip([c[0] for c in cases], got["success"][n_random:].tolist()))
    assert named == {"resting, hand away": False, "resting, held": False, "held half way up": False,
                     "held and lifted": True, "held just below the target": False, "lifted, gripper open": False,
                     "lifted, hand 5 cm away": False, "knocked off the table": False}
    assert 10 < got["success"].sum() < n - 10  # both outcomes among the random draws too


def test_the_task_sums_its_scaled_terms_and_succeeds_on_held_and_lifted():
    cases = constructed_cases()
    env = make(num_envs=len(cases))
    t = lambda x: torch.tensor(np.array(x), dtype=torch.float32)
    cube, grasp, opening = t([c[1] for c in cases]), t([c[2] for c in cases]), t([c[3] for c in cases])
    tip_l, tip_r = grasp + t([0.0, 0.04, 0.0]), grasp - t([0.0, 0.04, 0.0])
    env.terms = cube_lift_terms(cube, grasp, tip_l, tip_r, opening, env.env_numbers["liftHeight"])
    env.compute_reward()
    ref = [reference(*v) for v in zip(cube.double().numpy(), grasp.double().numpy(), tip_l.double().numpy(),
                                      tip_r.double().numpy(), opening.double().numpy())]
    np.testing.assert_allclose(env.rew_buf.numpy(), [r[0] for r in ref], atol=1e-5)
    assert env.check_success().tolist() == [r[1] for r in ref] and sum(r[1] for r in ref) == 1


def test_resets_put_the_cube_on_the_table_within_the_documented_ranges():
    env = make(num_envs=16)
    for _ in range(3):
        env.reset()
        pos, quat = env.cube.root_pos.numpy(), env.cube.root_quat.numpy()
        assert np.all(np.abs(pos[:, :2] - [0.45, 0.0]) <= 0.25 + 1e-6)
        np.testing.assert_allclose(pos[:, 2], REST_Z, atol=1e-6)  # resting on the table top
        yaw = 2.0 * np.arctan2(quat[:, 3], quat[:, 0])
        assert np.all(np.abs(yaw) <= 0.785 + 1e-6)
        np.testing.assert_allclose(quat[:, 1:3], 0.0, atol=1e-7)  # yaw only
        np.testing.assert_array_equal(env.cube.root_lin_vel.numpy(), 0.0)
        q = env.sim.dof_pos.numpy()
        assert np.all(np.abs(q[:, :7] - Q0[:7]) <= 0.25 + 1e-6)
    # many draws: uniform over the square (each quarter about a quarter) and the full yaw range used
    pos, quat = sample_cube(20000, torch.tensor([0.45, 0.0]), 0.25, 0.785)
    quarter = ((pos[:, 0] > 0.45).int() * 2 + (pos[:, 1] > 0).int()).bincount(minlength=4) / 20000
    assert torch.all((quarter - 0.25).abs() < 0.03)
    yaw = 2 * torch.atan2(quat[:, 3], quat[:, 0])
    assert yaw.abs().max() > 0.78 and torch.all(yaw.abs() <= 0.785 + 1e-6)


def test_a_scripted_grasp_and_lift_ends_the_episode_as_a_success():
    from test_franka_grasp import (
        ik,  # damped least squares on MuJoCo C, fingers down (yaw 0)
    )

    env = make(num_envs=2, overrides=("task.env.frankaDofNoise=0.0",))
    env.reset()
    cube = np.array([[0.5, 0.05, REST_Z], [0.42, -0.08, REST_Z]])
    mask = torch.ones(2, dtype=torch.bool)
    zero = torch.zeros(2, 3)
    env.sim.write_state(mask, root_pos=torch.tensor(cube, dtype=torch.float32),
                        root_quat=torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2), root_lin_vel=zero, root_ang_vel=zero,
                        asset="cubeA", refresh=True)
    m = env.sim.mj_model
    site = m.site("grasp").id
    plan = []  # (arm joint goals (2, 7), gripper action, policy steps)
    around = np.stack([ik(m, site, c, Q0[:7]) for c in cube])
    plan.append((around, 1.0, 50))  # down around the cube, open
    plan.append((around, -1.0, 20))  # close
    plan.append((np.stack([ik(m, site, c + [0, 0, 0.15], a) for c, a in zip(cube, around)]), -1.0, 60))  # up
    step = env.control.arm_step
    succeeded = torch.zeros(2, dtype=torch.bool)
    highest = np.zeros(2)
    for goal, grip, steps in plan:
        goal = torch.tensor(goal, dtype=torch.float32)
        for _ in range(steps):
            arm = torch.clamp((goal - env.arm.targets[:, :7]) / step, -1.0, 1.0)
            action = torch.cat((arm, torch.full((2, 1), grip)), dim=1)
            rise = env.cube.root_pos[:, 2].numpy() - REST_Z
            _, _, done, _extras = env.step(action)
            highest = np.maximum(highest, rise)
            new = env.metrics.recorded(OUTCOME)["success"].bool() if done.any() else torch.zeros(2, dtype=torch.bool)
            assert torch.equal(new, done.bool() & ~succeeded)  # the only episodes ending are successes
            succeeded |= new
        if succeeded.all():
            break
    assert succeeded.any(), f"no world lifted its cube {LIFT} m: highest rise {highest}"
    assert highest[succeeded.numpy()].max() > LIFT - 0.02


# ------------------------------------------------------------------------------------- depth
def camera_frame(pos, target):
    """World axes of a camera at ``pos`` looking at ``target`` (its -z), world +z up in the image (its +y)."""
    back = np.asarray(pos) - np.asarray(target)
    z = back / np.linalg.norm(back)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    return x, np.cross(z, x), z


def test_depth_task_groups_hide_the_cube_from_the_actor_only():
    env = make("FrankaCubeLiftDepth", num_envs=2)
    obs = env.reset()
    assert env.observations.obs_layout.names == ["dof_pos", "dof_vel", "dof_targets", "grasp_pos"]
    assert env.observations.state_layout.names == ["cube_pos", "cube_quat", "cube_to_grasp"]
    groups = RslRlVecEnv(env).get_observations()
    assert groups["policy"].shape == (2, 29) and groups["critic"].shape == (2, 10)
    assert groups["camera"].shape == (2, 1, 64, 64) and groups["camera"].dtype == torch.uint8
    assert torch.equal(obs["states"][:, :3], env.cube.root_pos)  # the critic's state starts with the cube
    state_task = make("FrankaCubeLift", num_envs=2)
    assert state_task.num_obs == 39 and state_task.observations.obs_layout.names[-3:] == ["cube_pos", "cube_quat", "cube_to_grasp"]


# World 0 has the cube at A_POS, world 1 at B_POS: each one's pixels that see its cube see the table in the other.
A_POS, B_POS = np.array([0.65, -0.2, REST_Z]), np.array([0.62, 0.18, REST_Z])


def two_placed_cubes(task: str):
    """A camera task with the cube at A_POS in world 0 and B_POS in world 1; returns it and the camera's YAML."""
    env = make(task, num_envs=2, overrides=("task.env.frankaDofNoise=0.0",))
    env.reset()
    mask = torch.ones(2, dtype=torch.bool)
    zero = torch.zeros(2, 3)
    env.sim.write_state(mask, root_pos=torch.tensor(np.stack([A_POS, B_POS]), dtype=torch.float32),
                        root_quat=torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2), root_lin_vel=zero, root_ang_vel=zero,
                        asset="cubeA", refresh=True)
    return env, env.cfg["env"]["cameras"]["overhead"]


def pixel_of(cam, point) -> tuple[int, int]:
    """(row, col) of the pixel through which a pinhole camera with the YAML's pose and fovy sees ``point``."""
    pos = np.array(cam["pos"])
    x, y, z = camera_frame(pos, np.array(cam["lookAt"]))
    width, height, tan = cam["width"], cam["height"], math.tan(math.radians(cam["fovy"]) / 2)
    rel = np.asarray(point) - pos
    along = -rel @ z
    col = int(np.rint((rel @ x) / along / tan * height / 2 + width / 2 - 0.5))
    row = int(np.rint(height / 2 - (rel @ y) / along / tan * height / 2 - 0.5))
    return row, col


def test_the_depth_image_sees_the_cube_where_a_pinhole_camera_puts_it():
    env, cam = two_placed_cubes("FrankaCubeLiftDepth")
    pos = np.array(cam["pos"])
    width, height, tan = cam["width"], cam["height"], math.tan(math.radians(cam["fovy"]) / 2)
    x, y, z = camera_frame(pos, np.array(cam["lookAt"]))
    a, b = A_POS, B_POS
    env.sim.render_cameras()
    depth = env.sim.sensor("overhead", output="depth")[:, 0].numpy()
    for world, centre in ((0, a), (1, b)):
        top = centre + [0.0, 0.0, 0.025]
        row, col = pixel_of(cam, top)
        # the ray through that pixel's centre: where it meets the cube's top face and the table top
        u = (col + 0.5 - width / 2) / (height / 2) * tan
        v = (height / 2 - row - 0.5) / (height / 2) * tan
        ray = u * x + v * y - z  # planar depth 1 along it
        on_top = pos + ray * (top[2] - pos[2]) / ray[2]
        assert np.all(np.abs(on_top[:2] - centre[:2]) < 0.025)  # it does hit the top face
        cube_depth = (top[2] - pos[2]) / ray[2]
        table_depth = (TABLE_TOP - pos[2]) / ray[2]
        other = 1 - world
        assert depth[world, row, col] == pytest.approx(cube_depth, abs=3e-3)
        assert depth[other, row, col] == pytest.approx(table_depth, abs=3e-3)
        assert 0.04 < table_depth - cube_depth < 0.1  # the cube's 5 cm, seen at a slant
        # the cube covers several pixels around it, nearer than the table by at least 1 cm
        window = (slice(row - 3, row + 4), slice(col - 3, col + 4))
        assert (depth[world][window] < depth[other][window] - 0.01).sum() >= 9
    # what the policy gets after a step is that step's render in bytes: 0 at the camera, 255 at depthFar
    obs, _, _, _ = env.step(torch.zeros(2, 8))
    expected = torch.round(env.sim.sensor("overhead", output="depth") * 255 / cam["depthFar"]).to(torch.uint8)
    assert torch.equal(obs["camera"], expected)


# ------------------------------------------------------------------------------------- training and errors
@pytest.mark.parametrize("task", ["FrankaCubeLift", "FrankaCubeLiftDepth", "FrankaCubeLiftRGB"])
def test_one_training_iteration_then_test_mode(tmp_path, run_args, task):
    short = ["task.env.episodeLength_s=0.1"]
    cfg = compose_config([f"task={task}", "num_envs=2", "max_iterations=1", "train.runner.num_steps_per_env=8",
                          *short, *run_args])
    if task != "FrankaCubeLift":
        assert list(cfg.train.runner.obs_groups.actor) == ["camera", "policy"]
        assert list(cfg.train.runner.obs_groups.critic) == ["policy", "critic"]
    summary = run(cfg)
    assert summary["iterations"] == 1 and summary["success"] == 0.0  # 6-step episodes cannot lift the cube
    losses, logged = summary["history"][0]["losses"], tensorboard_scalars(Path(summary["run_dir"]))
    if task == "FrankaCubeLift":
        assert "aux" not in losses and "Loss/aux" not in logged
    else:  # the pixel recipes train the image features to predict the cube's state too (actor.aux_target)
        assert math.isfinite(losses["aux"]) and losses["aux"] > 0.0
        assert logged["Loss/aux"] == [(0, pytest.approx(losses["aux"], rel=1e-6))]
    (checkpoint,) = (tmp_path / "runs" / task).glob("*/model_1.pt")
    result = run(compose_config([f"task={task}", "num_envs=2", "test=True", f"checkpoint={checkpoint}", *short,
                                 *run_args]))
    assert result["episodes"] == 2 and result["success"] == 0.0


@pytest.mark.parametrize("override, message", [
    ("task.env.liftHeight=0", r"^task\.env\.liftHeight=0 is invalid: give a number > 0\.0$"),
    ("task.env.liftHeight=-0.1", r"^task\.env\.liftHeight=-0\.1 is invalid: give a number > 0\.0$"),
    ("task.env.controlType=osc",
     r"^task\.env\.controlType='osc' is invalid: FrankaCubeLift supports only 'joint_pos'$"),
    ("task.env.startPositionNoise=-1", r"^task\.env\.startPositionNoise=-1 is invalid: give a number >= 0\.0$"),
])
def test_bad_values_are_one_line_errors_naming_the_key(override, message):
    with pytest.raises(ConfigError, match=message):
        make(num_envs=1, overrides=(override,))


def test_the_rgb_image_shows_the_red_cube_where_a_pinhole_camera_puts_it():
    """FrankaCubeLiftRGB: the pixel through which a pinhole camera sees the cube's top centre is the cube's dark red
    (red above green and blue) in the world that has the cube there, the brown table in the other."""
    env, cam = two_placed_cubes("FrankaCubeLiftRGB")
    assert env.observations.obs_layout.names == ["dof_pos", "dof_vel", "dof_targets", "grasp_pos"]
    obs, _, _, _ = env.step(torch.zeros(2, 8))
    image = obs["camera"].int()
    assert image.shape == (2, 3, 64, 64) and obs["camera"].dtype == torch.uint8
    for world, centre in ((0, A_POS), (1, B_POS)):
        row, col = pixel_of(cam, centre + [0.0, 0.0, 0.025])
        red, green, blue = image[world, :, row, col].tolist()
        assert red > green + 20 and red > blue + 20, (world, red, green, blue)  # rgba 0.6 0.1 0.1, lit
        other = image[1 - world, :, row, col].tolist()
        assert other != [red, green, blue] and other[0] - other[2] < red - blue  # the table: less red than the cube
