"""Observation layouts: sizes derived from named terms, checked against the YAML, noise per column."""

import pytest
import torch

from isaacgymenvs_mw.tasks.base.observation_terms import ObsLayout, ObsTerm


def test_layout_sizes_slices_and_noise_follow_the_terms():
    layout = ObsLayout([ObsTerm("a", 3, noise=0.1), ObsTerm("b", 1), ObsTerm("c", 2, scale=0.5, noise=2.0)])
    assert layout.size == 6 and layout.names == ["a", "b", "c"]
    assert layout.slices["c"] == slice(4, 6)
    assert layout.noise_scale("cpu").tolist() == pytest.approx([0.1, 0.1, 0.1, 0.0, 2.0, 2.0])
    assert layout.columns(["c", "a"], "key").tolist() == [4, 5, 0, 1, 2]
    assert [d["start"] for d in layout.describe()] == [0, 3, 4]


def test_layout_errors_name_the_key_and_the_terms():
    layout = ObsLayout([ObsTerm("a", 3), ObsTerm("b", 1)])
    with pytest.raises(ValueError, match=r"env.numObservations=5.*a 3 \+ b 1.*numObservations: 4"):
        layout.check(5, "env.numObservations")
    with pytest.raises(ValueError, match=r"env.history.terms.*\['z'\]"):
        layout.columns(["z"], "env.history.terms")
    with pytest.raises(ValueError, match="more than once"):
        ObsLayout([ObsTerm("a", 1), ObsTerm("a", 2)])


@pytest.mark.parametrize("robot", ["Anymal", "Go1"])
def test_legged_layout_matches_what_the_task_writes(robot):
    import isaacgymenvs_mw

    task = isaacgymenvs_mw.make(robot, num_envs=2, sim_device="cpu", rl_device="cpu")
    obs = task.reset()
    assert task.observations.obs_layout.size == obs["obs"].shape[1] == 48
    assert task.observations.state_layout.size == obs["states"].shape[1] == 55
    # The critic's copy of the policy terms is noiseless; the policy's joint velocities carry the YAML's noise.
    assert float(task.observations.state_layout.noise_scale("cpu").abs().sum()) == 0.0
    noise = task.observations.obs_layout.noise_scale("cpu")
    assert float(noise[task.observations.obs_layout.slices["dof_vel"]][0]) == pytest.approx(1.5 * 0.05)
    with pytest.raises(ValueError, match="env.numStates=54"):
        isaacgymenvs_mw.make(robot, num_envs=2, sim_device="cpu", rl_device="cpu",
                             overrides=["+task.env.numStates=54"])
    assert torch.isfinite(obs["obs"]).all()
