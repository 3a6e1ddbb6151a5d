"""save_best: model_best.pt follows the task's declared success metric where its reward disagrees, the reward where
the task declares no success, and the user's sweep_metric over both; summary.json says which metric and why."""

from __future__ import annotations

import json

import pytest

from isaacgymenvs_mw.learning.best_checkpoint import BestCheckpoint, chosen_by
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.learning.vecenv import EpisodeStats
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, PER_STEP, RUNNING, Metric
from isaacgymenvs_mw.utils.config import compose_config

# Per iteration: the mean episode reward rises throughout, while the rate of episodes that reach the target peaks in
# the middle and falls: a policy that hovers near the target without reaching it earns more and more.
REWARD = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0]
REACHED = [0.0, 1.0, 1.0, 1.0, 0.0, 0.0]
SAVE_INTERVAL = 2


@pytest.fixture
def scripted_episodes(monkeypatch):
    """The iterations' episode statistics, as the env reports them, replaced by REWARD and REACHED (the real ones are
    still read and cleared): a history where reward and success disagree, whatever the policy learns."""
    real_pop = EpisodeStats.pop
    calls = iter(range(len(REWARD)))

    def pop(self):
        out = real_pop(self)
        i = next(calls)
        out.update(episodes=max(out["episodes"], 1.0), mean_episode_reward=REWARD[i], mean_episode_length=5.0,
                   timeout_fraction=1.0)
        out["Episode/reached_target"] = REACHED[i]
        return out

    monkeypatch.setattr(EpisodeStats, "pop", pop)


def trailing_mean_at(values: list[float], iteration: int) -> float:
    """The mean of the last 10 values up to ``iteration`` (1-based), written out for this test."""
    window = values[max(0, iteration - 10):iteration]
    return sum(window) / len(window)


def best_saved_iteration(values: list[float]) -> int:
    """The saved iteration (every SAVE_INTERVAL) of the highest trailing mean; the first of equals."""
    saved = range(SAVE_INTERVAL, len(values) + 1, SAVE_INTERVAL)
    return max(saved, key=lambda it: (trailing_mean_at(values, it), -it))


def train_quadcopter(tmp_path, overrides: list[str]) -> tuple[dict, object]:
    summary = run(compose_config(["task=Quadcopter", "num_envs=2", f"max_iterations={len(REWARD)}",
                                  f"train.runner.save_interval={SAVE_INTERVAL}", "train.runner.num_steps_per_env=2",
                                  "sim_device=cpu", "rl_device=cpu", "headless=True",
                                  f"runs_dir={tmp_path / 'runs'}", *overrides]))  # save_best is on by default
    (run_dir,) = [p for p in (tmp_path / "runs" / "Quadcopter").iterdir() if p.is_dir()]
    return summary, run_dir


@pytest.mark.parametrize("override, key, values, why", [
    ([], "Episode/reached_target", REACHED, "declared success metric"),
    (["sweep_metric=mean_episode_reward"], "mean_episode_reward", REWARD, "user choice"),
])
def test_model_best_follows_the_declared_success_metric_unless_the_user_names_one(tmp_path, scripted_episodes,
                                                                                   override, key, values, why):
    # Reference: the two metrics' best saved checkpoints differ (4 by the target rate, 6 by the reward).
    assert best_saved_iteration(REACHED) == 4 and best_saved_iteration(REWARD) == 6
    expected = best_saved_iteration(values)
    summary, run_dir = train_quadcopter(tmp_path, override)
    assert [r[key] for r in summary["history"]] == values  # the scripted statistics reached the history
    best = summary["best_checkpoint"]
    assert best["metric"] == key and best["chosen_by"] == why and best["iteration"] == expected
    assert best["value"] == pytest.approx(trailing_mean_at(values, expected))
    copy = (run_dir / "model_best.pt").read_bytes()
    assert copy == (run_dir / f"model_{expected}.pt").read_bytes()
    other = best_saved_iteration(REWARD if values is REACHED else REACHED)  # the other metric's best
    assert copy != (run_dir / f"model_{other}.pt").read_bytes()
    written = json.loads((run_dir / "summary.json").read_text())  # what the file says, not only what run() returns
    assert written["best_checkpoint"]["metric"] == key and written["best_checkpoint"]["chosen_by"] == why
    assert written["success_metric"] == "Episode/reached_target"


def test_a_task_without_a_declared_success_is_followed_by_its_reward(tmp_path):
    # A history where the time-out rate (not declared as Cartpole's success) peaks early and the reward late.
    best = BestCheckpoint(tmp_path, "auto", None)
    history = []
    for i, (timeouts, reward) in enumerate([(1.0, 1.0), (0.0, 5.0)], start=1):
        history.append({"iteration": i, "timeout_fraction": timeouts, "mean_episode_reward": reward})
        (tmp_path / f"model_{i}.pt").write_bytes(f"iteration {i}".encode())
        best.consider(history, str(tmp_path / f"model_{i}.pt"))
    assert best.summary()["metric"] == "mean_episode_reward" and best.summary()["chosen_by"] == "episode reward"
    assert (tmp_path / "model_best.pt").read_bytes() == b"iteration 2"


def test_which_tasks_declare_a_success_and_which_follow_their_reward():
    from isaacgymenvs_mw import make
    from isaacgymenvs_mw.learning.vecenv import success_metric_key

    assert success_metric_key(make("Quadcopter", num_envs=1)) == "Episode/reached_target"
    assert success_metric_key(make("BallBalance", num_envs=1)) == "timeout_fraction"  # its goal is to last
    assert success_metric_key(make("Cartpole", num_envs=1)) is None
    assert [chosen_by("auto", "Episode/success"), chosen_by("auto", None), chosen_by("success", None)] == [
        "declared success metric", "episode reward", "user choice"]


def test_a_success_metric_must_be_one_training_or_test_mode_can_rank():
    with pytest.raises(ValueError, match=r"^Metric 'tracking_error': success=True needs a kind of episode_sum, "
                                         r"running or outcome, not per_step$"):
        Metric("tracking_error", PER_STEP, success=True)
    assert Metric("level", EPISODE_SUM, success=True).success and not Metric("x", RUNNING).success
