"""One bad world never reaches the learner's weights: non-finite observations and rewards are replaced before the
learner sees them, a non-finite optimiser step is skipped on the device and counted, and a learner whose state still
turns non-finite gets its last finite state back (learning/guard.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from conftest import CPU_ARGS
from isaacgymenvs_mw.learning.guard import LearnerGuard, NoGoodState, learner_tensors
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.tasks.cartpole import Cartpole
from isaacgymenvs_mw.tasks.franka_cube_lift import FrankaCubeLift
from isaacgymenvs_mw.utils.config import compose_config, to_dict


def cartpole_runner(make_cartpole, num_envs: int = 8, overrides: tuple[str, ...] = ()) -> Runner:
    task = make_cartpole(num_envs)
    cfg = compose_config(["task=Cartpole", *CPU_ARGS, *overrides])
    return Runner(RslRlVecEnv(task), rsl_rl_config(to_dict(cfg.train)), log_dir=None, device="cpu")


def snapshot(runner: Runner) -> list[torch.Tensor]:
    return [t.detach().clone() for t in learner_tensors(runner.alg)]


def test_an_update_whose_every_loss_is_nonfinite_changes_nothing_and_counts_each_step(make_cartpole):
    runner = cartpole_runner(make_cartpole)
    runner.learn(1)  # a real rollout and update: Adam has its state now
    alg = runner.alg
    before = snapshot(runner)
    steps_before = [s["step"].clone() for s in alg.optimizer.state.values()]
    # A second rollout, whose returns are all NaN: every mini-batch's value loss is NaN.
    compute_returns = alg.compute_returns

    def nan_returns(obs):
        compute_returns(obs)
        alg.storage.returns.fill_(float("nan"))

    alg.compute_returns = nan_returns
    runner.learn(1)
    expected = alg.num_learning_epochs * alg.num_mini_batches
    assert runner.skipped_steps == expected and runner.history[-1]["skipped_optimizer_steps"] == expected
    after = learner_tensors(alg)
    # Weights, Adam's moments and step counts unchanged (the normaliser saw finite observations: it may move).
    normaliser = {id(b) for m in (alg.actor, alg.critic) for b in m.buffers()}
    for old, new in zip(before, after):
        if id(new) not in normaliser:
            assert torch.equal(old, new)
    assert all(torch.equal(s["step"], old) for s, old in zip(alg.optimizer.state.values(), steps_before))
    assert all(torch.isfinite(t).all() for t in after if t.is_floating_point())


def test_one_nonfinite_sample_skips_only_the_mini_batches_that_hold_it(make_cartpole):
    runner = cartpole_runner(make_cartpole)
    alg = runner.alg
    compute_returns = alg.compute_returns

    def one_nan_return(obs):
        compute_returns(obs)
        alg.storage.returns[3, 5] = float("nan")

    alg.compute_returns = one_nan_return
    runner.learn(2)
    # Each epoch shuffles all samples into its mini-batches once: the NaN sample is in one mini-batch per epoch.
    assert [h["skipped_optimizer_steps"] for h in runner.history] == [alg.num_learning_epochs] * 2
    assert all(math.isfinite(v) for h in runner.history for v in h["losses"].values())
    assert all(torch.isfinite(t).all() for t in learner_tensors(alg) if t.is_floating_point())


def test_guard_restores_the_last_finite_state_in_place():
    net = torch.nn.Linear(3, 2)
    opt = torch.optim.Adam(net.parameters(), lr=0.1)
    net(torch.ones(1, 3)).sum().backward()
    opt.step()
    tensors = lambda: [*net.parameters(), *(v for s in opt.state.values() for v in s.values())]  # noqa: E731
    guard = LearnerGuard(tensors)
    assert guard.check() is True
    good = [t.detach().clone() for t in tensors()]
    weight = net.weight
    with torch.no_grad():
        net.weight[0, 1] = float("nan")
        opt.state[net.bias]["exp_avg_sq"].fill_(float("inf"))
    assert guard.check() is False and guard.restores == 1
    assert net.weight is weight  # the same tensors (a captured update graph keeps reading them), their old values
    assert all(torch.equal(a, b) for a, b in zip(tensors(), good))


def test_guard_without_a_finite_state_in_memory_says_so():
    net = torch.nn.Linear(2, 1)
    with torch.no_grad():
        net.bias.fill_(float("nan"))
    with pytest.raises(NoGoodState):
        LearnerGuard(lambda: list(net.parameters())).check()


def test_runner_falls_back_to_its_last_checkpoint(make_cartpole, tmp_path, capsys):
    runner = cartpole_runner(make_cartpole)
    runner.log_dir = str(tmp_path)
    runner.learn(2)
    saved = torch.load(runner.last_checkpoint, weights_only=False)["actor_state_dict"]
    fresh_guard = LearnerGuard(runner.guard._tensors)  # as if nothing were held in memory
    runner.guard = fresh_guard
    with torch.no_grad():
        next(runner.alg.actor.parameters()).fill_(float("nan"))
    line = runner._keep_learner_finite(3)
    assert line is not None and runner.last_checkpoint in line and fresh_guard.restores == 1
    for key, value in runner.alg.actor.state_dict().items():
        assert torch.equal(value, saved[key]), key


def test_nonfinite_observations_and_rewards_become_zero_and_are_counted(make_cartpole, monkeypatch):
    observations, reward = Cartpole.compute_observations, Cartpole.compute_reward

    def bad_observations(self):
        observations(self)
        self.obs_buf[1, 2] = float("nan")
        self.obs_buf[4, 0] = float("-inf")

    def bad_reward(self):
        reward(self)
        self.rew_buf[2] = float("inf")

    faulty, twin = make_cartpole(6), make_cartpole(6)
    for task in (faulty, twin):
        torch.manual_seed(5)
        task.reset()
    monkeypatch.setattr(Cartpole, "compute_observations", bad_observations)
    monkeypatch.setattr(Cartpole, "compute_reward", bad_reward)
    actions = torch.zeros(6, 1)
    torch.manual_seed(9)
    obs, rew, _, extras = faulty.step(actions)
    monkeypatch.undo()
    torch.manual_seed(9)
    obs_t, rew_t, _, _ = twin.step(actions)
    assert extras["nonfinite_inputs"].tolist() == [False, True, True, False, True, False]
    assert float(faulty.nonfinite_inputs_count) == 3.0  # what the learner's statistics read once per iteration
    assert float(obs["obs"][1, 2]) == 0.0 and float(obs["obs"][4, 0]) == 0.0 and float(rew[2]) == 0.0
    expected = obs_t["obs"].clone()
    expected[1, 2], expected[4, 0] = 0.0, 0.0
    assert torch.equal(obs["obs"], expected)
    assert torch.equal(rew[[0, 1, 3, 4, 5]], rew_t[[0, 1, 3, 4, 5]])


def test_a_blown_up_franka_world_keeps_value_losses_and_weights_finite(tmp_path, monkeypatch):
    """The GPU incident replayed on the CPU: world 0's joint speeds set to inf at env step 40 and to 1e20 at 80."""
    original = FrankaCubeLift.pre_physics_step

    def blow_up(self, actions):
        original(self, actions)
        if self.control_steps in (40, 80):
            self.sim.qvel[0, :7] = float("inf") if self.control_steps == 40 else 1.0e20

    monkeypatch.setattr(FrankaCubeLift, "pre_physics_step", blow_up)
    cfg = compose_config(["task=FrankaCubeLift", "num_envs=8", "max_iterations=3", *CPU_ARGS,
                          f"runs_dir={tmp_path / 'runs'}"])
    summary = run(cfg)
    assert summary["nonfinite_resets"] >= 2  # both injections were seen as blow-ups and reset
    assert all(math.isfinite(h["losses"]["value"]) for h in summary["history"])
    run_dir = Path(summary["run_dir"])
    on_disk = json.loads((run_dir / "summary.json").read_text())
    assert {"skipped_optimizer_steps", "nonfinite_inputs", "learner_restores"} <= set(on_disk)
    state = torch.load(run_dir / "model_3.pt", weights_only=False)
    for group in ("actor_state_dict", "critic_state_dict"):
        assert all(torch.isfinite(v).all() for v in state[group].values() if v.is_floating_point()), group


def test_the_value_normalisers_statistics_are_part_of_the_guarded_state(make_cartpole):
    runner = cartpole_runner(make_cartpole, overrides=("+train.algorithm.normalize_value=True",))
    runner.learn(1)
    statistics = list(runner.alg.value_normalizer.buffers())
    assert statistics and all(any(t is s for t in learner_tensors(runner.alg)) for s in statistics)
    good = [t.clone() for t in statistics]
    with torch.no_grad():
        statistics[0].fill_(float("nan"))
    assert runner.guard.check() is False
    assert all(torch.equal(a, b) for a, b in zip(statistics, good))
