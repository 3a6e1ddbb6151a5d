"""FrankaCubeStack's staged reward, the default (issue 58): the reward function against a plain-Python formula written
here, on random and hand-built states (the stages pay in order: stacked and released > stacked but held > lifted >
grasped > reached); the success on placed cubes in the simulator (A on B, gripper open, A at rest); an episode that
ends stacked, counted as a success with its furthest stage; the one-line error of an unknown reward kind; a scripted
pick-and-place (osc control) that earns every stage in order and stacks; and a short CPU training run that logs the
success rate."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from isaacgymenvs_mw import make
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, OUTCOME
from isaacgymenvs_mw.tasks.franka_cube_stack import staged_stack_reward
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError

TABLE_TOP = -0.1  # assets/mjcf/table.xml
Q0 = np.array([0.0, 0.1963, 0.0, -2.6180, 0.0, 2.9416, 0.7854, 0.04, 0.04])  # IGE's arm pose, the gripper open


SHIPPED_LEVELS = (0.0, 1.0, 3.0, 4.0, 6.0, 8.0)  # cfg/task/FrankaCubeStack.yaml, env.reward.stageLevels
LIFT_HEAVY_LEVELS = (0.0, 1.0, 3.0, 4.5, 6.0, 9.0)  # another valid set: the lift pays more than the grasp


def reference_staged(a, b, g, opening, v, w, levels=SHIPPED_LEVELS):
    """The staged reward of one env, as docs/config.md states it: (reward, stage name)."""
    reach, grasp, carry, place_level, release, stacked = levels

    def norm(x):
        return math.sqrt(sum(c * c for c in x))

    place = [b[0], b[1], b[2] + 0.06]  # A's centre resting on B: (0.05 + 0.07) / 2 above B's
    off_xy = norm([a[0] - place[0], a[1] - place[1]])
    rise_over_place = a[2] - place[2]
    held = norm([a[i] - g[i] for i in range(3)]) < 0.03 and opening < 0.03
    on_b = off_xy < 0.02 and abs(rise_over_place) <= 0.01
    if on_b and opening >= 0.035 and norm(v) < 0.01 and norm(w) < 0.5:
        return stacked / stacked, "stacked"
    if on_b:
        opened = min(max((opening - 0.025) / 0.015, 0.0), 1.0)
        return (release + (opened + 1.0 - math.tanh(10.0 * norm(v) + norm(w))) / 2.0) / stacked, "release"
    if held and rise_over_place > 0.01 and off_xy < 0.02:
        return (place_level + 1.0 - math.tanh(5.0 * norm([place[i] - a[i] for i in range(3)]))) / stacked, "place"
    if held and rise_over_place > 0.01:
        hover = [place[0], place[1], place[2] + 0.03]
        return (carry + 1.0 - math.tanh(5.0 * norm([hover[i] - a[i] for i in range(3)]))) / stacked, "carry"
    if held:
        rest = TABLE_TOP + 0.025
        rise = (a[2] - rest) / (place[2] + 0.01 - rest)
        return (grasp + min(max(rise, 0.0), 1.0)) / stacked, "grasp"
    return (reach + 1.0 - math.tanh(5.0 * norm([g[i] - a[i] for i in range(3)]))) / stacked, "reach"


STAGE_NAMES = ["reach", "grasp", "carry", "place", "release", "stacked"]


def staged(a, b, g, opening, v, w, levels=SHIPPED_LEVELS):
    t = lambda x: torch.as_tensor(np.asarray(x), dtype=torch.float64)
    reward, stage = staged_stack_reward(t(a), t(b), t(g), t(opening), t(v), t(w), levels)
    return reward.numpy(), [STAGE_NAMES[i] for i in stage.tolist()]


@pytest.mark.parametrize("levels", [SHIPPED_LEVELS, LIFT_HEAVY_LEVELS])
def test_staged_reward_equals_the_reference_formula_in_every_stage(levels):
    rng = np.random.default_rng(3)
    n, k = 1800, 300
    b = np.column_stack([0.45 + rng.uniform(-0.25, 0.25, n), rng.uniform(-0.25, 0.25, n), np.full(n, -0.065)])
    place = b + [0.0, 0.0, 0.06]
    a = b + [0.2, 0.0, -0.01] + rng.normal(0.0, 0.02, (n, 3))  # on the table beside B
    a[k:2 * k, 2] = rng.uniform(TABLE_TOP + 0.025, 0.1, k)             # lifted, anywhere in height
    a[2 * k:3 * k] = place[2 * k:3 * k] + rng.normal(0.0, 0.03, (k, 3))  # near its place: over B, on B or off
    a[3 * k:4 * k] = place[3 * k:4 * k] + np.column_stack([rng.uniform(-0.015, 0.015, (k, 2)),
                                                           rng.uniform(0.0, 0.1, k)])  # above its place
    a[4 * k:] = place[4 * k:] + rng.uniform(-0.012, 0.012, (n - 4 * k, 3)) * [2.0, 2.0, 1.0]  # on B or nearly
    g = a + rng.normal(0.0, 0.02, (n, 3)) * rng.choice([0.3, 3.0], (n, 1))  # near A or not
    opening = rng.choice([0.0, 0.025, 0.03, 0.035, 0.04], n) + rng.uniform(-0.002, 0.002, n)
    v = rng.normal(0.0, 0.01, (n, 3)) * rng.choice([0.1, 1.0], (n, 1))
    w = rng.normal(0.0, 0.4, (n, 3)) * rng.choice([0.1, 1.0], (n, 1))
    reward, stage = staged(a, b, g, opening, v, w, levels)
    expected = [reference_staged(*row, levels) for row in zip(a, b, g, opening, v, w)]
    assert stage == [s for _, s in expected]
    np.testing.assert_allclose(reward, [r for r, _ in expected], atol=1e-12)
    counts = {name: stage.count(name) for name in STAGE_NAMES}
    assert min(counts.values()) >= 20, counts  # every stage is exercised
    assert reward.min() >= 0.0 and reward.max() <= 1.0
    assert np.all((reward == 1.0) == (np.array(stage) == "stacked"))  # only a stack pays the most


def test_stages_pay_in_order_on_hand_built_states():
    b = [0.45, -0.1, TABLE_TOP + 0.035]
    on_table = [0.45, 0.1, TABLE_TOP + 0.025]
    lifted = [0.45, 0.1, TABLE_TOP + 0.15]
    on_b = [0.45, -0.1, TABLE_TOP + 0.095]
    still, moving = [0.0, 0.0, 0.0], [0.03, 0.0, 0.0]
    states = {  # name: A, grasp point, each finger's opening, A's velocity
        "reached": (on_table, on_table, 0.04, still),          # the open gripper around A
        "grasped": (on_table, on_table, 0.025, still),         # closed on it
        "lifted": (lifted, lifted, 0.025, still),              # held 12.5 cm above the table, away from B
        "stacked, held": (on_b, on_b, 0.025, still),
        "stacked, released, moving": (on_b, on_b, 0.04, moving),
        "stacked, released": (on_b, on_b, 0.04, still),
    }
    a, g, opening, v = (np.array([s[i] for s in states.values()]) for i in range(4))
    reward, stage = staged(a, np.tile(b, (len(states), 1)), g, opening, v, np.zeros_like(v))
    assert stage == ["reach", "grasp", "carry", "release", "release", "stacked"]
    # Levels 1 apart (reach 0, grasp 1 in the shipped set) make a fully reached A pay what a grasp with no progress
    # pays; from the grasp on, each state pays more than the one before.
    assert list(reward) == sorted(reward) and len(set(reward[1:])) == len(reward) - 1, dict(zip(states, reward))
    assert reward[0] == pytest.approx(SHIPPED_LEVELS[1] / SHIPPED_LEVELS[-1])  # the reach's most: its progress is 1
    assert reward[-1] == 1.0 and reward[-2] < 7.0 / 8.0


@pytest.fixture(scope="module")
def env():
    return make("FrankaCubeStack", num_envs=3, sim_device="cpu", rl_device="cpu", headless=True, seed=0)


def place(env, a, b, q, lin_vel=None):
    """Write cubes A and B (yaw 0; A's linear velocity ``lin_vel``, else at rest) and the arm's joints ``q`` (N, 9)
    into every env, then refresh the state the reward reads."""
    n = env.num_envs
    mask = torch.ones(n, dtype=torch.bool)
    quat, zero = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1), torch.zeros(n, 3)
    vel_a = zero if lin_vel is None else torch.tensor(lin_vel, dtype=torch.float32)
    for name, pos, vel in (("cubeA", a, vel_a), ("cubeB", b, zero)):
        env.sim.write_state(mask, root_pos=torch.tensor(pos, dtype=torch.float32), root_quat=quat,
                            root_lin_vel=vel, root_ang_vel=zero, asset=name, refresh=False)
    env.arm.reset(mask, torch.tensor(q, dtype=torch.float32))
    env.sim.refresh_kinematics()
    env.refresh_state()


def test_success_needs_a_on_b_the_gripper_open_and_a_at_rest(env):
    from test_franka_grasp import ik

    b = np.array([0.45, 0.0, TABLE_TOP + 0.035])
    on_b = b + [0.0, 0.0, 0.06]
    m = env.sim.mj_model
    holding = np.concatenate([ik(m, m.site("grasp").id, on_b, Q0[:7]), [0.025, 0.025]])  # grasp point at A
    place(env, np.tile(on_b, (3, 1)), np.tile(b, (3, 1)), np.stack([Q0, Q0, holding]),
          lin_vel=[[0, 0, 0], [0.05, 0, 0], [0, 0, 0]])  # env 1: A sliding at 5 cm/s
    assert env.check_success().tolist() == [True, False, False]
    env.compute_reward()
    assert env.rew_buf[0].item() == 1.0
    assert 6.0 / 8.0 <= env.rew_buf[1].item() < 7.0 / 8.0 and 6.0 / 8.0 <= env.rew_buf[2].item() < 7.0 / 8.0


def test_an_episode_ends_stacked_and_reports_success_and_its_furthest_stage(env):
    env.reset()
    b = np.array([0.45, 0.0, TABLE_TOP + 0.035])
    a = np.stack([b + [0, 0, 0.06], b + [0, 0.2, -0.01], b + [0, -0.2, -0.01]])  # env 0 on B, 1-2 on the table
    place(env, a, np.tile(b, (3, 1)), np.tile(Q0, (3, 1)))
    open_still = torch.tensor([[0.0] * 7 + [1.0]] * 3)  # hold the arm, gripper open
    for _ in range(20):  # A, written just touching B, sinks into the soft contact and settles (6 steps measured)
        _, rew, done, _ = env.step(open_still)
        if done[0]:
            break
    assert done.tolist() == [1, 0, 0]
    assert rew[0].item() == 1.0 and rew[1].item() < 1.0 / 8.0  # env 1: reaching, the gripper far from A
    assert env.metrics.recorded(OUTCOME)["success"].tolist() == [1.0, 0.0, 0.0]
    ended = env.metrics.recorded(EPISODE_SUM)
    assert ended["success"].item() == 1.0 and ended["furthest_stage"].item() == 5.0  # STAGES.index("stacked")


def test_an_unknown_reward_kind_is_one_line_naming_the_key_and_the_kinds():
    with pytest.raises(ConfigError, match=r"^task\.env\.reward\.kind='dense' is invalid: choose one of "
                                          r"\['staged', 'isaacgymenvs'\]$"):
        make("FrankaCubeStack", num_envs=1, sim_device="cpu", rl_device="cpu", headless=True,
             overrides=["task.env.reward.kind=dense"])


def reward_inputs(env) -> list[list]:
    """What staged_stack_reward reads from the task, as lists (one row per env): A, B, grasp point, finger opening,
    A's linear and angular velocity."""
    return [t.tolist() for t in (env.cube_a.root_pos, env.cube_b.root_pos, env.arm.grasp_pos(), env.sim.dof_pos[:, 7],
                                 env.cube_a.root_lin_vel, env.cube_a.root_ang_vel)]


def test_stage_levels_of_the_yaml_set_what_each_stage_pays():
    levels = "[" + ",".join(str(v) for v in LIFT_HEAVY_LEVELS) + "]"
    env = make("FrankaCubeStack", num_envs=3, sim_device="cpu", rl_device="cpu", headless=True, seed=0,
               overrides=[f"task.env.reward.stageLevels={levels}"])
    env.reset()
    b = np.array([0.45, 0.0, TABLE_TOP + 0.035])
    a = np.stack([b + [0, 0, 0.06], b + [0, 0.2, -0.01], b + [0.03, 0, 0.06]])  # on B; on the table; off B's top
    place(env, a, np.tile(b, (3, 1)), np.tile(Q0, (3, 1)), lin_vel=[[0, 0, 0], [0, 0, 0], [0.05, 0, 0]])
    env.compute_reward()
    state = reward_inputs(env)
    expected = [reference_staged(*row, LIFT_HEAVY_LEVELS) for row in zip(*state)]
    assert [s for _, s in expected] == ["stacked", "reach", "reach"]
    np.testing.assert_allclose(env.rew_buf.tolist(), [r for r, _ in expected], atol=1e-6)
    shipped = [reference_staged(*row)[0] for row in zip(*state)]
    assert abs(env.rew_buf[1].item() - shipped[1]) > 1e-3  # reaching pays (0 + progress) / 9 here, not / 8


@pytest.mark.parametrize("levels", ["[0,2,3,4,6]", "[0,2,2.5,4,6,8]", "[-1,2,3,4,6,8]", "[0,2,3,4,6,x]", "8"])
def test_bad_stage_levels_are_one_line_naming_the_key(levels):
    with pytest.raises(ConfigError, match=r"^task\.env\.reward\.stageLevels=.* is invalid: give 6 numbers, one per "
                                          r"stage \['reach', .*'stacked'\], the first >= 0 and each at least 1 above "
                                          r"the one before \(a stage pays its number \+ 0 \.\.\. 1\)$"):
        make("FrankaCubeStack", num_envs=1, sim_device="cpu", rl_device="cpu", headless=True,
             overrides=[f"task.env.reward.stageLevels={levels}"])


def test_a_yaml_without_stage_levels_is_one_line_naming_the_key():
    with pytest.raises(ConfigError, match=r"^FrankaCubeStack: the task YAML's env section lacks "
                                          r"\['reward\.stageLevels'\]$"):
        make("FrankaCubeStack", num_envs=1, sim_device="cpu", rl_device="cpu", headless=True,
             overrides=["~task.env.reward.stageLevels"])


def test_training_a_few_iterations_logs_the_success_rate_and_furthest_stage(tmp_path, run_args):
    cfg = compose_config(["task=FrankaCubeStack", "num_envs=4", "max_iterations=3", "task.env.episodeLength_s=0.1",
                          "train.runner.num_steps_per_env=8", *run_args])
    summary = run(cfg)
    assert summary["iterations"] == 3
    assert summary["success"] == 0.0  # 6-step episodes of a new policy: none stacked
    assert 0.0 <= summary["furthest_stage"] < 5.0  # the mean over the episodes that ended
    assert 0.0 <= summary["mean_episode_reward"] <= 6.0  # at most 1 per step, 6 steps


def grasp_rotation_error(axes: torch.Tensor) -> torch.Tensor:
    """The small-angle rotation (3,) that turns the grasp frame ``axes`` (columns x, y, z) to the top-down grasp
    (approach axis down, fingers opening along world y), each axis' cross product with its goal, halved."""
    goal = torch.tensor([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]).T
    return 0.5 * torch.linalg.cross(axes.T, goal.T).sum(dim=0)


def scripted_stack(env, pick: bool) -> tuple[bool, str, float, list[str]]:
    """An osc script (the grasp point or cube A steered to a waypoint, the hand held top-down) that, with ``pick``,
    picks A from the table first, then carries it over B, sets it down and lets go. Every step's reward must equal the
    reference formula on the simulator's state as the task read it. Returns whether the episode ended, the last step's
    stage and reward, and the stages in the order first reached. (As the task read it: the poses, body and site, are
    those of the last physics step's start, as MuJoCo leaves them; the step's reset refreshes them before the
    observation, and by then the grasp point has moved on by up to 7 mm in this script's fastest moves.)"""
    a, b = env.cube_a.root_pos[0], env.cube_b.root_pos[0]  # live views of the simulator's state
    grasp = env.arm.grasp_pos()[0]
    place_on_b = lambda: b + torch.tensor([0.0, 0.0, 0.06])  # A's centre resting on B

    def steer(point: torch.Tensor, waypoint: torch.Tensor, grip: float) -> torch.Tensor:
        action = torch.zeros(1, 7)
        action[0, :3] = torch.clamp(20.0 * (waypoint - point), -1.0, 1.0)  # full command 5 cm away (0.1 m at 1)
        action[0, 3:6] = torch.clamp(4.0 * grasp_rotation_error(env.arm.grasp_axes()[0]), -1.0, 1.0)
        action[0, 6] = grip
        return action

    # (what is steered, its waypoint, gripper, done when, at most steps); waypoints are read each step
    picking = [(lambda: grasp, lambda: a + torch.tensor([0.0, 0.0, 0.08]), 1.0,
                lambda: torch.linalg.norm(grasp - a - torch.tensor([0.0, 0.0, 0.08])) < 0.01, 100),
               (lambda: grasp, lambda: a, 1.0, lambda: torch.linalg.norm(grasp - a) < 0.012, 80),
               (lambda: grasp, lambda: a, -1.0, lambda: False, 15)]                     # close on A
    placing = [(lambda: a, lambda: place_on_b() + torch.tensor([0.0, 0.0, 0.05]), -1.0,
                lambda: torch.linalg.norm((a - place_on_b())[:2]) < 0.006 and a[2] > place_on_b()[2] + 0.03, 150),
               (lambda: a, lambda: place_on_b() + torch.tensor([0.0, 0.0, -0.01]), -1.0,
                lambda: abs(float(a[2] - place_on_b()[2])) < 0.005, 80),               # set A down on B
               (lambda: grasp, lambda: grasp.clone(), 1.0, lambda: False, 60)]         # let go, hold still
    read = {}  # the state the reward is computed from, as refresh_state finds it
    task_refresh = env.refresh_state

    def refresh_state() -> None:
        read["state"] = [column[0] for column in reward_inputs(env)]
        task_refresh()

    env.refresh_state = refresh_state
    first_reached, stage, rew = [], None, None
    for point, waypoint, grip, finished, most in (picking if pick else []) + placing:
        for _ in range(most):
            _, rew, reset, _ = env.step(steer(point(), waypoint(), grip))
            expected, stage = reference_staged(*read["state"])
            assert rew[0].item() == pytest.approx(expected, abs=1e-6), stage
            if stage not in first_reached:
                first_reached.append(stage)
            if reset[0]:
                return True, stage, rew[0].item(), first_reached
            if finished():
                break
    return False, stage, rew[0].item(), first_reached


def test_a_scripted_pick_and_place_passes_every_stage_in_order_and_stacks():
    """The staged reward can be earned to the end (scripted_stack from A on the table): the stages are first reached
    in their order, and the episode ends a success."""
    env = make("FrankaCubeStack", num_envs=1, sim_device="cpu", rl_device="cpu", headless=True, seed=0,
               overrides=["task.env.controlType=osc", "task.env.frankaDofNoise=0.0",
                          "task.env.startRotationNoise=0.0", "task.env.graspedResetFraction=0"])  # A on the table
    env.reset()
    done, stage, reward, first_reached = scripted_stack(env, pick=True)
    assert done and stage == "stacked" and reward == 1.0  # the stacked step pays the most and ends the episode
    assert first_reached == STAGE_NAMES
    assert env.metrics.recorded(OUTCOME)["success"].tolist() == [1.0]
