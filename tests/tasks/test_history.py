"""Observation history (env.history): the shift buffer on constructed sequences, its reset, the stacked layout a
task returns, and the errors for bad YAML. Expected values are written out by hand from the documented layout
[obs_t | sel(obs_t-1) | ... | sel(obs_t-k+1)]; the integration tests compare against the same task run without
history (its observations are the frames)."""

from __future__ import annotations

import pytest
import torch

import isaacgymenvs_mw
from isaacgymenvs_mw.tasks.base.history import HistorySpec, ObsHistory, parse_history
from isaacgymenvs_mw.tasks.base.observation_terms import ObsLayout, ObsTerm

LAYOUT = ObsLayout([ObsTerm("a", 2), ObsTerm("b", 1), ObsTerm("c", 3)])


def frame(step: int, env: int, size: int = 6) -> torch.Tensor:
    """A recognisable frame: column j of env e at step t holds 100 t + 10 e + j."""
    return torch.tensor([100.0 * step + 10.0 * env + j for j in range(size)])


def frames(step: int, num_envs: int = 3) -> torch.Tensor:
    return torch.stack([frame(step, e) for e in range(num_envs)])


def test_whole_vector_history_shifts_newest_first():
    hist = ObsHistory(HistorySpec("env.history.policy", 3), 6, None, num_envs=3, device="cpu")
    assert hist.size == 6 * 3
    none = torch.zeros(3, dtype=torch.bool)
    hist.reset(frames(0), torch.ones(3, dtype=torch.bool))
    hist.push(frames(1), none)
    out = hist.push(frames(2), none)
    for e in range(3):
        expected = torch.cat([frame(2, e), frame(1, e), frame(0, e)])
        assert torch.equal(out[e], expected)
    out = hist.push(frames(3), none)
    assert torch.equal(out[1], torch.cat([frame(3, 1), frame(2, 1), frame(1, 1)]))  # frame 0 dropped out


def test_selected_terms_keep_the_current_frame_whole():
    spec = HistorySpec("env.history.policy", 2, ("c", "a"))
    hist = ObsHistory(spec, 6, LAYOUT, num_envs=3, device="cpu")
    assert hist.size == 6 + 5  # frame + (c: 3, a: 2) of the previous frame
    hist.reset(frames(0), torch.ones(3, dtype=torch.bool))
    out = hist.push(frames(1), torch.zeros(3, dtype=torch.bool))
    prev = frame(0, 2)
    assert torch.equal(out[2], torch.cat([frame(1, 2), prev[3:6], prev[0:2]]))  # in the order the YAML lists


def test_reset_env_forgets_its_past_and_others_keep_theirs():
    hist = ObsHistory(HistorySpec("env.history.policy", 3), 6, None, num_envs=3, device="cpu")
    hist.reset(frames(0), torch.ones(3, dtype=torch.bool))
    hist.push(frames(1), torch.zeros(3, dtype=torch.bool))
    out = hist.push(frames(2), torch.tensor([False, True, False]))
    assert torch.equal(out[1], torch.cat([frame(2, 1)] * 3))  # new episode: every past frame is its first one
    assert torch.equal(out[0], torch.cat([frame(2, 0), frame(1, 0), frame(0, 0)]))
    out = hist.push(frames(3), torch.zeros(3, dtype=torch.bool))
    assert torch.equal(out[1], torch.cat([frame(3, 1), frame(2, 1), frame(2, 1)]))
    # reset() without a step (VecTask.reset / reset_done) refills only the masked envs
    out = hist.reset(frames(9), torch.tensor([True, False, False]))
    assert torch.equal(out[0], torch.cat([frame(9, 0)] * 3))
    assert torch.equal(out[2], torch.cat([frame(9, 2), frame(2, 2), frame(1, 2)]))


@pytest.mark.parametrize("section, message", [
    ({"policy": {"length": 0}}, "env.history.policy.length=0"),
    ({"policy": {"length": 2.5}}, "env.history.policy.length=2.5"),
    ({"critic": {"length": -1}}, "env.history.critic.length=-1"),
    ({"actor": {"length": 2}}, "env.history: unknown group(s) ['actor']"),
    ({"policy": {"length": 2, "frames": 3}}, "env.history.policy: unknown key(s) ['frames']"),
    ({"policy": {"length": 2, "terms": "dof_pos"}}, "env.history.policy.terms='dof_pos'"),
    ({"policy": {"length": 2, "terms": []}}, "env.history.policy.terms=[]"),
])
def test_bad_history_sections_name_the_key(section, message):
    with pytest.raises(ValueError) as err:
        parse_history({"history": section})
    assert message in str(err.value)


def test_length_one_is_no_history():
    assert parse_history({"history": {"policy": {"length": 1}}}) == {}
    assert parse_history({}) == {}


def test_unknown_term_names_the_key_and_lists_the_terms():
    with pytest.raises(ValueError, match=r"env\.history\.policy\.terms: unknown observation term\(s\) \['z'\]"):
        ObsHistory(HistorySpec("env.history.policy", 2, ("a", "z")), 6, LAYOUT, 3, "cpu")


# ------------------------------------------------------------------------------------------- in a task (Cartpole)
def make(history: str | None, num_envs: int = 4):
    overrides = [f"+task.env.history={history}"] if history else []
    return isaacgymenvs_mw.make("Cartpole", num_envs=num_envs, sim_device="cpu", rl_device="cpu", seed=3,
                                overrides=overrides)


def rollout(task, steps: int = 60) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """(obs, done) of a reset and ``steps`` steps from seed 5; env 0 pushes its cart off the rail and resets."""
    torch.manual_seed(5)
    out = [(task.reset()["obs"], torch.ones(task.num_envs, dtype=torch.long))]
    actions = torch.zeros(task.num_envs, 1)
    actions[0] = 1.0
    for _ in range(steps):
        obs, _, done, _ = task.step(actions)
        out.append((obs["obs"].clone(), done.clone()))
    return out


def test_cartpole_stacks_its_frames_and_refills_on_reset():
    stacked = make("{policy:{length:3}}")
    assert stacked.observation_space.shape == (12,) and stacked.num_obs == 4
    plain, with_history = rollout(make(None)), rollout(stacked)
    episode: list[list[torch.Tensor]] = [[] for _ in range(4)]  # each env's frames since its episode began
    resets = 0
    for (obs, done), (got, done_h) in zip(plain, with_history):
        assert torch.equal(done, done_h)
        for e in range(4):
            if done[e]:
                resets += 1
                episode[e] = [obs[e]]  # the frame returned with reset_buf set is the new episode's first
            else:
                episode[e].append(obs[e])
            past = episode[e]
            # missing frames of a young episode are its first frame
            expected = torch.cat([obs[e], past[max(len(past) - 2, 0)], past[max(len(past) - 3, 0)]])
            assert torch.equal(got[e], expected), (e, len(past))
    assert resets >= 4 + 1  # the initial reset of every env, and env 0 at least once more


def test_terms_must_be_terms_of_the_layout():
    with pytest.raises(ValueError, match=r"env\.history\.policy\.terms: unknown observation term\(s\) \['x'\]; terms: "
                                         r"\['cart_pos', 'cart_vel', 'pole_angle', 'pole_vel'\]"):
        make("{policy:{length:2,terms:[x]}}").reset()


def test_critic_history_needs_states():
    with pytest.raises(ValueError, match=r"task\.env\.history\.critic needs task\.env\.numStates > 0"):
        make("{critic:{length:2}}")
