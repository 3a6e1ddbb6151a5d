"""Every shipped task behaves as it did when this recording was made (issue 31: the episode contract, observations
from their layout and scenes of assets moved code, not behaviour).

For each task: 2 worlds on the CPU, seed 0; ``reset()``, 50 env steps of zero actions, then 50 of seeded uniform
random actions in [-1, 1]. Recorded per step: the policy observation, the critic state (when the task has one), the
reward, the reset and time-out flags, and the episode sums the task reports (``extras["episode_terms"]`` and its
declared EPISODE_SUM metrics, ``env.metrics``). The recording was made before the refactor, from the code of the commit that added this file (the legged tasks'
again when ``reset()`` began to run the task's ``after_reset``, issue 70: their command timer draws its random numbers
there too, which shifts every later draw; nothing else changed, as the test then passing against the old recording up
to that commit shows):

    python tests/workflow/test_behaviour_recording.py --record [Task ...]

Comparison: bitwise for flags, and within 1e-6 (absolute, plus the same relative) for values, since a refactor may
legitimately change the order of floating-point operations (a sum of named terms in a loop, say).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM

REPO_ROOT = Path(__file__).resolve().parents[2]
if str(REPO_ROOT) not in sys.path:  # `examples` (the tutorial's Pendulum) is importable from the repository root
    sys.path.insert(0, str(REPO_ROOT))
DATA = Path(__file__).resolve().parents[1] / "data" / "behaviour"
TASKS = ["Cartpole", "Anymal", "AnymalTerrain", "Go1", "Go1Terrain", "G1", "G1Terrain", "Ant", "Humanoid", "Pendulum",
         # recorded later (issue 45), from commit 44ba848, before the refactor of observations and the episode clock
         "CartpoleCamera", "CartpoleCameraDepth", "FrankaCabinet", "FrankaCubeStack", "FrankaCubeLift",
         "FrankaCubeLiftDepth", "AllegroHand",
         # recorded when the task was added (issue 47)
         "Quadcopter", "BallBalance"]
NUM_ENVS, STEPS, SEED = 2, 50, 0
# Quantities a task reports since its recording was made, which the recording cannot hold: not compared here (their
# own tests check them). Quadcopter: its success rate in training (issue 60), an episode sum beside the physics.
ADDED_SINCE_RECORDING = {"Quadcopter": {"episode_metrics/reached_target"}}
# The terrain tasks build a whole map for any number of worlds: a small one keeps the test fast.
SMALL_MAP = ["task.env.terrain.numLevels=3", "task.env.terrain.numTerrains=2", "task.env.terrain.maxInitLevel=2"]


# Episodes short enough to end inside the 100 recorded steps, so that time-outs and resets are recorded too (the
# locomotion tasks do not fall in 100 steps of these actions). The values are what matters: if a key is renamed,
# give the same length under the new name.
SHORT_EPISODES = {"legged": ["task.env.episodeLength_s=0.6"], "Ant": ["task.env.episodeLength_s=0.4998"],
                  "Humanoid": ["task.env.episodeLength_s=0.4995"], "Cartpole": ["task.env.episodeLength_s=0.664"],
                  "Pendulum": ["task.env.episodeLength_s=0.8"], "CartpoleCamera": ["task.env.episodeLength_s=0.664"],
                  "CartpoleCameraDepth": ["task.env.episodeLength_s=0.664"],
                  # 40 policy steps of 1/60 s (the Panda), 20 of 1/30 s (the Allegro hand)
                  **{name: ["task.env.episodeLength_s=0.67"] for name in ("FrankaCabinet", "FrankaCubeStack",
                                                                          "FrankaCubeLift", "FrankaCubeLiftDepth",
                                                                          "AllegroHand")},
                  "Quadcopter": ["task.env.episodeLength_s=0.4"],  # 40 policy steps of 0.01 s
                  "BallBalance": ["task.env.episodeLength_s=0.4"]}  # 40 policy steps of 0.01 s


# The recording's defaults that later defaults replaced: FrankaCubeStack's reward became the staged one (issue 58), and
# a share of its resets start with cube A in the hand and its control became osc (issue 68); BallBalance's ball is
# damped as IsaacGym damps it (issue 69).
FORMER_DEFAULTS = {"FrankaCubeStack": ["task.env.reward.kind=isaacgymenvs", "task.env.graspedResetFraction=0",
                                       "task.env.controlType=joint_pos"],
                   "BallBalance": ["task.env.assets.ball.angularDamping=0"]}
# Where the recorded reward's factor moved from the task (env.rewardScale) to the learner recipe (issue 70): the
# recording holds the reward the learner sees, the task's times the recipe's reward_scale.
RECIPE_SCALED = ("Ant", "Humanoid", "FrankaCabinet", "AllegroHand")


def _learner_reward_scale(task: str) -> float:
    from isaacgymenvs_mw.learning.train_config import recipe_reward_scale
    from isaacgymenvs_mw.utils.config import compose_config, to_dict

    return recipe_reward_scale(to_dict(compose_config([f"task={task}"]).train)) if task in RECIPE_SCALED else 1.0


def _make(task: str):
    from isaacgymenvs_mw import make

    overrides = SMALL_MAP if task.endswith("Terrain") else []
    overrides = [*overrides, *SHORT_EPISODES.get(task, SHORT_EPISODES["legged"]), *FORMER_DEFAULTS.get(task, [])]
    if task == "Pendulum":
        overrides = [*overrides, "task_module=examples.pendulum_task"]
    return make(task, num_envs=NUM_ENVS, sim_device="cpu", rl_device="cpu", seed=SEED, overrides=overrides)


def run_task(task: str) -> dict[str, np.ndarray]:
    env = _make(task)
    reward_scale = _learner_reward_scale(task)
    gen = torch.Generator().manual_seed(SEED)
    actions = [torch.zeros(NUM_ENVS, env.num_actions)] * STEPS
    actions += [torch.rand(NUM_ENVS, env.num_actions, generator=gen) * 2 - 1 for _ in range(STEPS)]
    rows: dict[str, list[np.ndarray]] = {}

    def add(name: str, value) -> None:
        rows.setdefault(name, []).append(torch.as_tensor(value).detach().cpu().numpy().copy())

    obs = env.reset()
    add("reset_obs", obs["obs"])
    for action in actions:
        obs, rew, reset, extras = env.step(action)
        add("obs", obs["obs"])
        if "states" in obs:
            add("states", obs["states"])
        if "camera" in obs:
            add("camera", obs["camera"])
        add("rew", rew * reward_scale if reward_scale != 1.0 else rew)
        add("reset", reset)
        add("time_outs", extras["time_outs"])
        # The task's episode sums, under the names the recording gave them (the declared metrics' were then
        # extras["episode_metrics"]).
        for group, sums in (("episode_terms", extras.get("episode_terms", {})),
                            ("episode_metrics", env.metrics.recorded(EPISODE_SUM))):
            for name, value in sums.items():
                add(f"{group}/{name}", value)
    env.close()
    return {name: np.stack(values) for name, values in rows.items()}


def record(tasks: list[str]) -> None:
    DATA.mkdir(parents=True, exist_ok=True)
    for task in tasks:
        np.savez_compressed(DATA / f"{task}.npz", **run_task(task))
        print(f"recorded {task}")


@pytest.mark.parametrize("task", TASKS)
def test_task_behaves_as_recorded(task):
    expected = dict(np.load(DATA / f"{task}.npz"))
    got = run_task(task)
    added = ADDED_SINCE_RECORDING.get(task, set())
    assert added.isdisjoint(expected) and added <= set(got), added  # recorded since, or no longer reported: update
    got = {name: value for name, value in got.items() if name not in added}
    assert sorted(got) == sorted(expected), "the recorded quantities differ (names of episode terms, states)"
    for name, want in expected.items():
        have = got[name]
        assert have.shape == want.shape, (name, have.shape, want.shape)
        if name in ("reset", "time_outs"):
            np.testing.assert_array_equal(have, want, err_msg=f"{task}: {name}")
        else:
            np.testing.assert_allclose(have, want, rtol=1e-6, atol=1e-6, err_msg=f"{task}: {name}")


if __name__ == "__main__":
    if "--record" in sys.argv:  # --record [Task ...]: those tasks only (default: all)
        record([name for name in sys.argv[sys.argv.index("--record") + 1:] if not name.startswith("-")] or TASKS)
