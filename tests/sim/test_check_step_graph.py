"""benchmarks/diagnostics/check_step_graph.py's twin comparison, on the CPU: its GPU verdicts rest on two helpers, one that gives
the eager twin the shipped twin's whole state before a step and one that lists the task tensors a step left
different. Reference: two eager Cartpoles, one of which is made to forget a tensor its step must update."""

from __future__ import annotations

import sys
from pathlib import Path

import torch

import isaacgymenvs_mw

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks" / "diagnostics"))
import check_step_graph  # noqa: E402  (a script beside the tests, not a package)


def _twins():
    make = lambda: isaacgymenvs_mw.make("Cartpole", num_envs=4, sim_device="cpu", rl_device="cpu", seed=0)  # noqa: E731
    first, second = make(), make()
    first.reset()
    second.reset()
    return first, second


def test_copied_state_makes_the_twins_step_alike():
    shipped, eager = _twins()
    torch.manual_seed(1)
    for _ in range(5):  # drive the shipped twin away from the eager one's state first
        shipped.step(torch.rand(4, shipped.num_actions) * 2 - 1)
    check_step_graph.copy_state(shipped, eager)
    assert torch.equal(eager.sim.qpos, shipped.sim.qpos) and torch.equal(eager.sim.qvel, shipped.sim.qvel)
    assert torch.equal(eager.progress_buf, shipped.progress_buf)
    action = torch.full((4, shipped.num_actions), 0.5)
    worst = check_step_graph.fresh_worst()
    (obs_s, rew_s, _, _), (obs_e, rew_e, _, _) = shipped.step(action), eager.step(action)
    check_step_graph.compare_state(shipped, eager, worst)
    assert torch.equal(obs_s["obs"], obs_e["obs"]) and torch.equal(rew_s, rew_e)
    assert worst["state_mismatches"] == [] and worst["physics"] == 0.0


def test_a_tensor_the_step_left_alone_is_named():
    shipped, eager = _twins()
    check_step_graph.copy_state(shipped, eager)
    action = torch.zeros(4, shipped.num_actions)
    kept = shipped.progress_buf.clone()
    shipped.step(action)
    shipped.progress_buf.copy_(kept)  # as a captured replay that lost the clock's update would
    eager.step(action)
    worst = check_step_graph.fresh_worst()
    check_step_graph.compare_state(shipped, eager, worst)
    assert worst["state_mismatches"] == ["episode.progress_buf"]
    assert worst["state"] == 1.0


def test_every_twin_draws_the_same_numbers_and_the_stream_moves_on_once():
    torch.manual_seed(3)
    first, following = torch.rand(3), torch.rand(3)  # the generator's sequence, drawn plainly
    torch.manual_seed(3)
    draws = check_step_graph.RandomStream("cpu").run(*(lambda: torch.rand(3) for _ in range(3)))
    assert all(torch.equal(draw, first) for draw in draws)
    assert torch.equal(torch.rand(3), following)


def test_two_eager_twins_from_one_state_differ_by_nothing_on_the_cpu():
    # --floor: the second eager twin measures what one step differs by without any graph; on the CPU that is nothing
    shipped, eager = _twins()
    floor_twin = _twins()[0]
    torch.manual_seed(2)
    for _ in range(3):
        shipped.step(torch.rand(4, shipped.num_actions) * 2 - 1)
    action = torch.full((4, shipped.num_actions), -0.4)
    floor = check_step_graph.fresh_worst()
    for _ in range(3):
        check_step_graph.copy_state(shipped, eager)
        check_step_graph.copy_state(shipped, floor_twin)
        _, result_eager, result_floor = check_step_graph.RandomStream("cpu").run(
            lambda: shipped.step(action), lambda: eager.step(action), lambda: floor_twin.step(action))
        check_step_graph.compare_step(eager, floor_twin, result_eager, result_floor, floor)
    assert floor == check_step_graph.fresh_worst()
