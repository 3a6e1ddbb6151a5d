"""Rough terrain (AnymalTerrain / Go1Terrain): the generator against its formulas written out here, seeding,
the compiled heightfield and the device height scan against MuJoCo C's mj_ray on the task's own compiled model,
spawning on every terrain type, the curriculum on constructed cases, observation sizes, and bad input.

A tiny terrain (2 levels x 5 columns of 4 m cells, one column per type) keeps the model small on the CPU.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
import torch

import isaacgymenvs_mw
from isaacgymenvs_mw.learning.vecenv import EpisodeStats
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM
from isaacgymenvs_mw.sim.terrain import (TERRAIN_TYPES, column_types, generate_terrain, ground_geoms,
                                         parse_terrain_config)

T = "task.env.terrain."
EQUAL_MIX = {t: 1 / 6 for t in TERRAIN_TYPES}  # with 6 columns: column j is TERRAIN_TYPES[j]
SIXTH = 0.1666666667
WITH_STONES = [T + "numTerrains=6", T + "proportions={smooth_slope:%s,rough_slope:%s,stairs_up:%s,stairs_down:%s,"
               "discrete_obstacles:%s,stepping_stones:%s}" % ((SIXTH,) * 6)]
TINY = [T + "numLevels=2", T + "numTerrains=5", T + "mapLength=4.0", T + "mapWidth=4.0", T + "borderSize=1.0",
        T + "platformSize=2.0", T + "spawnJitter=0.3", T + "maxInitLevel=1",
        T + "proportions={smooth_slope:0.2,rough_slope:0.2,stairs_up:0.2,stairs_down:0.2,discrete_obstacles:0.2}"]
QUIET = ["~task.task.randomization_params.push", "~task.task.randomization_params.observations",
         "task.task.randomization_params.actor_params.rigid_shape_properties.friction.range=[1.0,1.0]",
         "task.task.randomization_params.actor_params.rigid_body_properties.mass.range=[0.0,0.0]",
         "task.env.resetRootVelocityRange=0.0", "task.env.resetDofPosScale=[1.0,1.0]"]  # start standing still
NUM_ENVS = 10  # two per column


def tiny_config(**changes) -> dict:
    raw = dict(type="heightfield", seed=3, numLevels=3, numTerrains=6, mapLength=4.0, mapWidth=4.0, borderSize=1.0,
               platformSize=2.0, proportions=EQUAL_MIX)
    raw.update(changes)
    return raw


def make(robot: str = "AnymalTerrain", overrides=()):
    return isaacgymenvs_mw.make(robot, num_envs=NUM_ENVS, sim_device="cpu", rl_device="cpu", headless=True, seed=0,
                                overrides=[*TINY, *QUIET, *overrides])


@pytest.fixture(scope="module")
def task():
    return make()


# ---------------------------------------------------------------------------------------------------- generator
def expected_height(kind: str, level: int, levels: int, x: float, y: float, size: float = 4.0,
                    platform: float = 2.0) -> float:
    """The docstring formulas of sim/terrain.py at local cell coordinates (x, y), for the deterministic types
    (legged_gym's defaults: slope 0.4 at difficulty 1, steps 0.05 + 0.18 d high and 0.31 m wide)."""
    d = level / levels
    edge = min(size / 2 - abs(x - size / 2), size / 2 - abs(y - size / 2), size / 2 - platform / 2)
    if kind == "smooth_slope":
        return -0.4 * d * edge  # the first half of the slope columns are pits; 1 column of 5 -> a pit
    step = 0.05 + 0.18 * d
    sign = 1.0 if kind == "stairs_up" else -1.0
    return sign * step * math.floor(edge / 0.31 + 1e-9)


def test_heights_follow_the_formulas_at_sampled_points():
    terrain = generate_terrain(parse_terrain_config(tiny_config()))
    assert terrain.column_types == list(TERRAIN_TYPES)
    rng = np.random.default_rng(0)
    hs, border, n = 0.1, 10, 40  # samples: spacing, border, per cell
    for level in range(3):
        for col, kind in enumerate(TERRAIN_TYPES):
            rows, cols = border + level * n, border + col * n
            block = terrain.heights[rows:rows + n, cols:cols + n]
            d = level / 3
            for a, b in rng.integers(0, n, size=(40, 2)):
                x, y, h = a * hs, b * hs, block[a, b]
                on_platform = abs(x - 2.0) <= 1.0 and abs(y - 2.0) <= 1.0
                if kind == "rough_slope":
                    noise = h - (-0.4 * d * min(2 - abs(x - 2), 2 - abs(y - 2), 1.0))
                    assert abs(noise) <= 0.05 + 1e-9 and abs(noise / 0.005 - round(noise / 0.005)) < 1e-6
                elif kind == "stepping_stones":
                    side = 1.575 + d * (0.075 - 1.575)  # legged_gym's 1.5 * (1.05 - d)
                    pitch = side + 0.05 + d * 0.05
                    stone = (x + 1e-9) % pitch < side and (y + 1e-9) % pitch < side
                    assert h == (0.0 if stone or on_platform else -1.0), (level, x, y, h)
                elif kind == "discrete_obstacles":
                    tall = 0.05 + 0.2 * d
                    allowed = [0.0] if on_platform else [0.0, -tall, -tall / 2, tall / 2, tall]
                    assert min(abs(h - v) for v in allowed) < 1e-9, (level, x, y, h)
                else:
                    assert h == pytest.approx(expected_height(kind, level, 3, x, y), abs=1e-9), (kind, level, x, y)
    # The border is flat at 0 and the origins sit on the platform's highest point at the cell's centre.
    assert np.all(terrain.heights[:border] == 0.0) and np.all(terrain.heights[:, -border:] == 0.0)
    np.testing.assert_allclose(terrain.origins[1, 2, :2], (1.5 * 4.0, 2.5 * 4.0))
    platform = terrain.heights[border + n + 10:border + n + 31, border + 2 * n + 10:border + 2 * n + 31]
    assert terrain.origins[1, 2, 2] == pytest.approx(platform.max())


def test_same_seed_same_terrain_other_seed_other_terrain():
    a = generate_terrain(parse_terrain_config(tiny_config(seed=7)))
    b = generate_terrain(parse_terrain_config(tiny_config(seed=7)))
    c = generate_terrain(parse_terrain_config(tiny_config(seed=8)))
    np.testing.assert_array_equal(a.heights, b.heights)
    assert not np.array_equal(a.heights, c.heights)  # rough noise and obstacles are drawn from the seed


def test_default_mix_is_legged_gyms():
    cfg = parse_terrain_config({"type": "heightfield", "numTerrains": 20, "borderSize": 0.0})
    types = generate_terrain(parse_terrain_config({"type": "heightfield", "numTerrains": 20, "numLevels": 1,
                                                   "borderSize": 0.0})).column_types
    counts = {t: types.count(t) for t in TERRAIN_TYPES}
    assert counts == {"smooth_slope": 2, "rough_slope": 2, "stairs_up": 7, "stairs_down": 5, "discrete_obstacles": 4,
                      "stepping_stones": 0}
    many = parse_terrain_config({"type": "heightfield", "numTerrains": 1000, "borderSize": 0.0, "numLevels": 1,
                                 "maxHeightfieldSamples": 10 ** 8})
    assert "stepping_stones" not in column_types(many)  # a zero share is never picked, even by rounding
    assert cfg.proportions["stairs_up"] == 0.35


@pytest.mark.parametrize("raw, words", [
    ({"type": "boxes"}, ["env.terrain.type", "'boxes'", "plane", "heightfield"]),
    (tiny_config(proportions={"stairs_up": 0.5, "stairs_down": 0.3}), ["env.terrain.proportions", "sum to 1"]),
    (tiny_config(proportions={"lava": 1.0}), ["env.terrain.proportions", "lava", "stairs_up", "discrete_obstacles"]),
    (tiny_config(numLevels=100, numTerrains=100), ["env.terrain.maxHeightfieldSamples", "horizontalScale"]),
    (tiny_config(stepHeigth=[0.1, 0.2]), ["env.terrain", "stepHeigth", "stepHeight"]),
    (tiny_config(platformSize=5.0), ["env.terrain.platformSize", "mapLength"]),
])
def test_bad_terrain_config_names_the_key_and_valid_values(raw, words):
    with pytest.raises(ValueError) as err:
        parse_terrain_config(raw)
    for word in words:
        assert word in str(err.value)


def test_bad_terrain_key_fails_before_the_simulator_is_built():
    with pytest.raises(ValueError, match=r"env.terrain.type: 'boxes' is not one of \['plane', 'heightfield'\]"):
        make(overrides=[T + "type=boxes"])
    with pytest.raises(ValueError, match=r"env.terrain.spawnJitter"):
        make(overrides=[T + "spawnJitter=1.5"])


# ------------------------------------------------------------------------------------------- compiled model + scan
def ray_heights(model: mujoco.MjModel, xy: np.ndarray) -> np.ndarray:
    """Surface z under each (x, y) from MuJoCo C's mj_ray, straight down, with the robot lifted out of the way."""
    data = mujoco.MjData(model)
    data.qpos[2] = 100.0
    mujoco.mj_forward(model, data)
    geom = np.zeros(1, dtype=np.int32)
    top = 10.0
    out = []
    for x, y in xy:
        dist = mujoco.mj_ray(model, data, np.array([x, y, top]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geom)
        assert geom[0] in ground_geoms(model)
        out.append(top - dist)
    return np.array(out)


def test_height_lookup_equals_mj_ray_on_the_compiled_model(task):
    m = task.sim.mj_model
    assert int(m.geom_type[task.ground_geom]) == int(mujoco.mjtGeom.mjGEOM_HFIELD)
    rng = np.random.default_rng(1)
    xy = rng.uniform((-0.9, -0.9), (2 * 4.0 + 0.9, 5 * 4.0 + 0.9), size=(300, 2))
    expected = ray_heights(m, xy)
    got = task.ground.height_map(torch.tensor(xy[:, 0], dtype=torch.float),
                                 torch.tensor(xy[:, 1], dtype=torch.float))
    np.testing.assert_allclose(got.numpy(), expected, atol=2e-5)
    # And the compiled heightfield is the generator's map (to float32 storage).
    grid_points = np.array([(a * 0.1 - 1.0, b * 0.1 - 1.0) for a, b in rng.integers(0, 100, size=(50, 2))])
    ab = np.round((grid_points + 1.0) / 0.1).astype(int)
    np.testing.assert_allclose(ray_heights(m, grid_points), task.ground.terrain.heights[ab[:, 0], ab[:, 1]], atol=2e-5)


def sensed_heights(task) -> torch.Tensor:
    """The height_scan sensor refreshed from the current state (the step's sense phase)."""
    task.sim.sense()
    return task.sim.sensor("height_scan")


def test_height_scan_points_turn_with_the_base_and_match_mj_ray(task):
    yaw = np.linspace(-3.0, 3.0, NUM_ENVS)
    quat = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=1)
    pos = np.stack([np.linspace(0.5, 7.5, NUM_ENVS), np.linspace(1.0, 19.0, NUM_ENVS), np.full(NUM_ENVS, 0.7)], 1)
    mask = torch.ones(NUM_ENVS, dtype=torch.bool)
    task.sim.write_state(mask, root_pos=torch.tensor(pos, dtype=torch.float),
                         root_quat=torch.tensor(quat, dtype=torch.float))
    scan = sensed_heights(task).numpy()
    assert scan.shape == (NUM_ENVS, 17 * 11)
    gx, gy = np.meshgrid(np.linspace(-0.8, 0.8, 17), np.linspace(-0.5, 0.5, 11), indexing="ij")
    local = np.stack([gx.ravel(), gy.ravel()], 1)
    for e in range(0, NUM_ENVS, 3):
        c, s = np.cos(yaw[e]), np.sin(yaw[e])
        world = pos[e, :2] + local @ np.array([[c, s], [-s, c]])
        np.testing.assert_allclose(scan[e], ray_heights(task.sim.mj_model, world), atol=2e-5)


def test_observation_and_state_sizes_follow_the_scan(task):
    obs = task.reset()
    assert obs["obs"].shape == (NUM_ENVS, 48 + 187) and obs["states"].shape == (NUM_ENVS, 48 + 187 + 7)
    blind = make(overrides=[T + "measureHeights=False", "+task.env.numObservations=48"])
    obs = blind.reset()
    assert obs["obs"].shape == (NUM_ENVS, 48) and obs["states"].shape == (NUM_ENVS, 55 + 187)
    # The critic's last 187 values are the clipped, scaled base height above each scan point minus 0.5 m.
    expected = (blind.sim.root_pos[:, 2:3] - 0.5 - sensed_heights(blind)).clamp(-1, 1) * 5.0
    np.testing.assert_allclose(obs["states"][:, 55:].numpy(), expected.numpy(), atol=1e-5)
    with pytest.raises(ValueError, match="numObservations=235, but the task observes 48 values"):
        make(overrides=[T + "measureHeights=False", "+task.env.numObservations=235"])  # 235 declared, 48 measured


def test_full_size_map_gives_no_false_deep_contacts_far_from_its_centre():
    """MuJoCo Warp 4.0's heightfield collision loses precision with the distance from the heightfield's centre:
    on legged_gym's 130 m x 210 m map as one heightfield, 5-10 % of small spheres resting more than 20 m from its
    centre got a contact metres deep and flew off. The builder makes one heightfield per cell (and boxes for the
    border), so spheres pressed into the full-size map anywhere move as MuJoCo C moves them."""
    from isaacgymenvs_mw.sim import Simulator
    from isaacgymenvs_mw.sim.ground import terrain_parts as _terrain_parts

    cfg = parse_terrain_config({"type": "heightfield"})  # the shipped size: 10 x 20 cells of 8 m, 25 m border
    terrain = generate_terrain(cfg)
    spec = mujoco.MjSpec()
    spec.option.timestep = 0.005
    for name, shape in _terrain_parts(spec, terrain):
        spec.worldbody.add_geom(name=name, **shape)
    ball = spec.worldbody.add_body(name="ball")
    ball.add_freejoint()
    ball.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.03, 0, 0], mass=0.2)
    model = spec.compile()
    # Each sphere 0-40 mm into a flat place (a foot landing fast at 200 Hz was 47 mm deep): a platform (every cell,
    # at its centre +- 1 m) or the border.
    rng = np.random.default_rng(0)
    n = 300
    cells = rng.integers(0, (cfg.numLevels, cfg.numTerrains), size=(n, 2))
    xyz = terrain.origins[cells[:, 0], cells[:, 1]] + np.c_[rng.uniform(-1.0, 1.0, (n, 2)), np.zeros(n)]
    border = rng.random(n) < 0.2
    xyz[border] = np.c_[rng.uniform(-24.0, -1.0, border.sum()), rng.uniform(-24.0, 184.0, border.sum()),
                        np.zeros(border.sum())]
    xyz[:, 2] += 0.03 - rng.uniform(0.0, 0.04, n)
    sim = Simulator(model, n, "cpu", nconmax=8, njmax=48)
    sim.write_state(torch.ones(n, dtype=torch.bool), root_pos=torch.tensor(xyz, dtype=torch.float))
    speed = torch.zeros(n)
    for _ in range(5):
        sim.simulate()
        speed = torch.maximum(speed, sim.qvel.abs().max(dim=1).values)
    # MuJoCo C from the same states: the fastest any velocity component gets in the same 5 steps.
    reference = np.zeros(n)
    data = mujoco.MjData(model)
    for w in range(n):
        mujoco.mj_resetData(model, data)
        data.qpos[:3] = xyz[w]
        for _ in range(5):
            mujoco.mj_step(model, data)
            reference[w] = max(reference[w], float(np.abs(data.qvel).max()))
    # With one heightfield for the map, a sphere spun off at 1303 rad/s (MuJoCo C's fastest: 43); the two engines'
    # contacts differ in detail, so the bound is on the fastest of all.
    assert torch.isfinite(speed).all()
    assert float(speed.max()) <= 1.5 * reference.max(), (float(speed.max()), reference.max())


def test_the_ground_parts_share_one_friction_draw_per_env():
    """The terrain is many geoms (a heightfield per cell, border boxes) but one surface: randomising the ground's
    friction (cfg/legged/base.yaml selects geoms "ground") gives each env one value on all of them."""
    task = make(overrides=["task.task.randomization_params.actor_params.rigid_shape_properties.friction.range="
                           "[0.5,1.25]"])
    parts = ground_geoms(task.sim.mj_model)
    assert len(parts) == 2 * 5 + 4  # TINY: 2 levels x 5 types, 4 border boxes
    friction = task.sim.model_field("geom_friction")[:, parts, 0]
    assert torch.equal(friction, friction[:, :1].expand_as(friction))
    assert float(friction.min()) >= 0.5 and float(friction.max()) <= 1.25 and len(set(friction[:, 0].tolist())) > 1


# ------------------------------------------------------------------------------------------------------ spawning
@pytest.mark.parametrize("robot", ["AnymalTerrain", "Go1Terrain"])
def test_robots_spawn_on_their_cells_surface_on_every_type(robot):
    task = make(robot, [T + "curriculum=False", *WITH_STONES])
    levels = torch.tensor([0, 1] * 5)
    task.ground.terrain_levels[:] = levels
    task.ground.env_origins[:] = task.ground.terrain_origins[levels, task.ground.terrain_types]
    assert sorted(set(task.ground.terrain_types.tolist())) == [0, 1, 2, 3, 4, 5]  # every type, stepping stones too
    task.reset()
    origins = task.ground.terrain.origins[levels.numpy(), task.ground.terrain_types.numpy()]
    start = task.sim.root_pos.clone().numpy()
    init_z = float(task.cfg["env"]["baseInitState"]["pos"][2])
    np.testing.assert_allclose(start[:, 2], origins[:, 2] + init_z, atol=1e-6)
    assert np.all(np.abs(start[:, :2] - origins[:, :2]) <= 0.3 + 1e-6)
    touching = torch.zeros(NUM_ENVS, len(task.feet), dtype=torch.bool)
    for i in range(40):  # 0.8 s standing under PD with zero actions
        task.step(torch.zeros(NUM_ENVS, 12))
        if i >= 30:  # a light robot's foot may unload for a step while it settles on the rough cells
            touching |= task.contact_force_norm[:, task._feet_idx] > 1.0
    m = task.sim.mj_model
    feet = [task.sim.body_id(b) for b in task.feet]
    radius = {b: max(m.geom_size[g, 0] for g in range(m.ngeom) if m.geom_bodyid[g] == b
                     and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE) for b in feet}
    xpos = task.sim.xpos.numpy()
    for e in range(NUM_ENVS):
        for b in feet:
            x, y, z = xpos[e, b]
            surface = task.ground.height_map(torch.tensor([x]), torch.tensor([y])).item()
            bottom = z - radius[b]
            assert surface - 0.015 <= bottom <= surface + 0.06, (robot, e, b, bottom, surface)
    assert bool(touching.all()), f"a foot is in the air: {touching}"
    assert not bool(task.reset_buf.any())


# ---------------------------------------------------------------------------------------------------- curriculum
def test_curriculum_moves_envs_up_down_and_wraps_past_the_top(task):
    task.reset()  # the first reset only places envs
    torch.manual_seed(0)
    n = NUM_ENVS
    task.ground.curriculum = True
    task.ground.terrain_levels[:] = torch.tensor([0, 1, 1, 0, 1, 0, 1, 1, 0, 1])
    task.ground.env_origins[:] = task.ground.terrain_origins[task.ground.terrain_levels, task.ground.terrain_types]
    # Distances walked from the cell origin (cell 4 m: up beyond 2 m) and commanded speeds (episode 20 s:
    # down below 10 s * |command|).
    walked = torch.tensor([2.1, 2.5, 1.9, 0.1, 1.1, 1.5, 0.0, 0.0, 0.0, 3.0])
    speed = torch.tensor([1.0, 1.0, 1.0, 1.0, 0.1, 0.5, 0.0, 0.0, 0.5, 1.0])
    mask = torch.tensor([True] * 9 + [False])
    pos = task.ground.env_origins.clone()
    pos[:, 0] += walked
    task.sim.write_state(torch.ones(n, dtype=torch.bool), root_pos=pos)
    task.commands[:] = 0.0
    task.commands[:, 1] = speed
    before = task.ground.terrain_levels.clone()
    task.ground.update_curriculum(mask, task.commands, task.max_episode_length_s, task.nonfinite_buf)
    after = task.ground.terrain_levels
    # 0: up 0->1; 1: up past the top (1) -> a random level; 2 (1.9 m < 2 m, < 10 m asked), 3: down (3 clamps
    # at 0); 4: 1.1 m >= 1.0 m asked,
    # stays; 5: 1.5 m < 5 m asked, down; 6, 7: no command, stay; 8: down, clamps at 0; 9: not resetting, unchanged.
    assert after[0] == 1 and 0 <= after[1] < 2
    assert after.tolist()[2:] == [0, 0, 1, 0, 1, 1, 0, int(before[9])]
    np.testing.assert_allclose(task.ground.env_origins.numpy(),
                               task.ground.terrain.origins[after.numpy(), task.ground.terrain_types.numpy()], atol=1e-6)


def test_a_blown_up_world_respawns_on_its_cell_and_keeps_its_level(task):
    """VecTask puts a blown-up world back in the model's initial pose, at the map's corner, far from its cell.
    The task resets it in the same step: on its own cell, and without a curriculum move for that distance."""
    task.reset()
    task.ground.curriculum = True
    for _ in range(2):
        task.step(task.zero_actions())
    bad = 3
    level = int(task.ground.terrain_levels[bad])
    corner = torch.tensor(task.sim.mj_model.qpos0[:2], dtype=torch.float)  # where VecTask's reset puts the base
    # would count as "up"
    assert float(torch.norm(task.ground.env_origins[bad, :2] - corner)) > 0.5 * task.ground.cell_length
    task.sim.qvel[bad, 0] = float("nan")
    _, _, reset, extras = task.step(task.zero_actions())
    assert bool(extras["nonfinite_resets"][bad]) and int(reset[bad]) == 1
    assert int(task.ground.terrain_levels[bad]) == level
    offset = (task.sim.root_pos[bad, :2] - task.ground.env_origins[bad, :2]).abs()
    assert bool((offset <= task.ground.spawn_jitter + 1e-5).all()), offset
    assert int(task.progress_buf[bad]) == 0 and not task.rewards.episode_sums[bad].any()


def test_wrap_past_the_top_draws_every_level():
    task_levels = []
    t = make(overrides=[T + "numLevels=4", T + "maxInitLevel=3"])
    t.reset()
    for _ in range(30):
        t.ground.terrain_levels[:] = 3
        t.ground.env_origins[:] = t.ground.terrain_origins[t.ground.terrain_levels, t.ground.terrain_types]
        pos = t.ground.env_origins.clone()
        pos[:, 0] += 3.0  # > half a cell
        t.sim.write_state(torch.ones(NUM_ENVS, dtype=torch.bool), root_pos=pos)
        t.ground.update_curriculum(torch.ones(NUM_ENVS, dtype=torch.bool), t.commands, t.max_episode_length_s,
                                   t.nonfinite_buf)
        task_levels += t.ground.terrain_levels.tolist()
    assert set(task_levels) == {0, 1, 2, 3}


def test_mean_terrain_level_reaches_the_episode_stats(task):
    task.reset()
    task.ground.terrain_levels[:] = torch.tensor([0, 1] * 5)
    mask = torch.tensor([True, False] * 5)
    task.ground.curriculum = False
    task.reset_idx(mask)
    stats = EpisodeStats(NUM_ENVS, "cpu")
    stats.record(torch.zeros(NUM_ENVS), mask, torch.zeros(NUM_ENVS, dtype=torch.bool),
                 torch.zeros(NUM_ENVS, dtype=torch.bool))
    stats.add_terms(task.metrics.recorded(EPISODE_SUM), group="Episode")
    assert stats.pop()["Episode/terrain_level"] == pytest.approx(0.5)  # mean over all envs, not the 5 resetting


def test_flat_tasks_have_no_terrain():
    flat = isaacgymenvs_mw.make("Anymal", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True, seed=0)
    assert flat.ground.terrain is None and not flat.ground.metrics() and not flat.ground.evaluation_groups()
    assert int(flat.sim.mj_model.geom_type[flat.ground_geom]) == int(mujoco.mjtGeom.mjGEOM_PLANE)


def test_video_frames_the_robot_on_the_terrain(task, tmp_path):
    from isaacgymenvs_mw.sim.video import VideoRecorder
    from test_video import robot_pixels

    task.reset()
    rec = VideoRecorder(task.sim, tmp_path, fps=50, width=160, height=120)
    n, centre = robot_pixels(rec, task.ground_geom)
    # The camera frames the robot (a few percent of the picture near its middle), not the whole terrain.
    assert n > 200, n
    assert np.all(np.abs(centre - np.array([80, 60])) < 30), centre


def test_evaluation_reports_each_terrain_level():
    from isaacgymenvs_mw.learning.evaluation import evaluate

    t = make(overrides=[T + "curriculum=False", "task.env.episodeLength_s=0.5"])
    levels = t.ground.terrain_levels.clone()
    out = evaluate(t, lambda obs: torch.zeros(NUM_ENVS, 12), "cpu")
    per = out["per_terrain_level"]
    assert sorted(per) == sorted(str(v) for v in set(levels.tolist()))
    assert sum(row["episodes"] for row in per.values()) == NUM_ENVS
    for level, row in per.items():
        assert row["episodes"] == int((levels == int(level)).sum())
        assert 0.0 <= row["survival"] <= 1.0 and row["lin_vel_tracking_error"] >= 0.0
    # Standing still for half a second on its platform, nobody falls: every episode ends on the time limit.
    assert all(row["survival"] == 1.0 for row in per.values())


def test_training_logs_the_terrain_level(tmp_path, capsys):
    import json

    from isaacgymenvs_mw.learning.launch import run
    from isaacgymenvs_mw.utils.config import compose_config

    # Short episodes (0.4 s) so that episodes end, and the curriculum moves envs, inside two short iterations.
    cfg = compose_config(["task=AnymalTerrain", f"num_envs={NUM_ENVS}", "max_iterations=2", "sim_device=cpu",
                          "rl_device=cpu", "headless=True", f"runs_dir={tmp_path / 'runs'}",
                          "train.runner.num_steps_per_env=25", "task.env.episodeLength_s=0.4", *TINY])
    summary = run(cfg)
    levels = [h["Episode/terrain_level"] for h in summary["history"]]
    assert len(levels) == 2 and all(0.0 <= v <= 1.0 for v in levels)  # 2 levels: 0 and 1
    assert summary["terrain_level"] is not None and 0.0 <= summary["terrain_level"] <= 1.0
    on_disk = json.loads((next((tmp_path / "runs" / "AnymalTerrain").iterdir()) / "summary.json").read_text())
    assert on_disk["terrain_level"] == summary["terrain_level"]
    assert "terrain_level" in capsys.readouterr().out  # the progress line


def test_terrain_type_plane_keeps_the_flat_ground():
    t = make(overrides=[T + "type=plane", "+task.env.numObservations=48", "+task.env.numStates=55"])
    assert t.ground.terrain is None
    assert int(t.sim.mj_model.geom_type[t.ground_geom]) == int(mujoco.mjtGeom.mjGEOM_PLANE)
    obs = t.reset()
    assert obs["obs"].shape == (NUM_ENVS, 48) and obs["states"].shape == (NUM_ENVS, 55)
