"""IsaacGymEnvs' public VecTask surface on this project's VecTask (issue 58, item 2).

The names below are the public attributes and methods of IsaacGymEnvs' ``Env`` and ``VecTask`` classes, read from
isaac-sim/IsaacGymEnvs, isaacgymenvs/tasks/base/vec_task.py (commit 225bb06), plus ``get_number_of_agents()``, which
rl_games' IsaacGymEnvs wrapper (isaacgymenvs/utils/rlgames_utils.py, RLGPUEnv) asks the env. Each is either present
here with IsaacGymEnvs' meaning (checked on built tasks against sizes known independently: IsaacGymEnvs' Cartpole has
4 observations and 1 action, its AllegroHand 50 (full_no_vel) observations, an 88-value full_state and 16 actions), or
named in docs/porting.md as having no meaning on MuJoCo Warp.
"""

from __future__ import annotations

import re

import gymnasium as gym
import numpy as np
import pytest
import torch

from conftest import REPO_ROOT

# IsaacGymEnvs' Env (attributes set in __init__, properties, methods)
IGE_ENV_NAMES = [
    "device_type", "device_id", "device", "rl_device", "headless", "graphics_device_id", "num_environments",
    "num_agents", "num_observations", "num_states", "obs_space", "state_space", "num_actions", "control_freq_inv",
    "act_space", "clip_obs", "clip_actions", "total_train_env_frames", "control_steps", "render_fps",
    "last_frame_time", "record_frames", "record_frames_dir", "allocate_buffers", "step", "reset", "reset_idx",
    "observation_space", "action_space", "num_envs", "num_acts", "num_obs", "set_train_info", "get_env_state",
    "set_env_state",
]
# IsaacGymEnvs' VecTask (beyond Env)
IGE_VECTASK_NAMES = [
    "metadata", "virtual_screen_capture", "virtual_display", "force_render", "sim_params", "physics_engine", "dt",
    "gym", "first_randomization", "original_props", "dr_randomizations", "actor_params_generator",
    "extern_actor_params", "last_step", "last_rand_step", "sim_initialized", "sim", "set_viewer",
    "enable_viewer_sync", "viewer", "obs_buf", "states_buf", "rew_buf", "reset_buf", "timeout_buf", "progress_buf",
    "randomize_buf", "extras", "create_sim", "get_state", "pre_physics_step", "post_physics_step", "zero_actions",
    "reset_done", "render", "get_actor_params_info", "apply_randomizations", "obs_dict", "max_episode_length",
]
CLIENT_NAMES = ["get_number_of_agents"]  # rl_games' RLGPUEnv.get_number_of_agents() calls env.get_number_of_agents()

METHODS = {"allocate_buffers", "step", "reset", "reset_idx", "set_train_info", "get_env_state", "set_env_state",
           "create_sim", "get_state", "pre_physics_step", "post_physics_step", "zero_actions", "reset_done", "render",
           "get_number_of_agents"}
N = 4


def porting_absent_names() -> set[str]:
    """The names docs/porting.md's section on IsaacGymEnvs' VecTask surface lists as having no meaning here."""
    text = (REPO_ROOT / "docs" / "porting.md").read_text()
    section = text.split("### IsaacGymEnvs' VecTask names", 1)[1].split("\n#", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| ") and "no meaning" in line]
    return {name for row in rows for name in re.findall(r"`(\w+)`", row.split("|")[1])}


@pytest.fixture(scope="module")
def cartpole():
    import isaacgymenvs_mw
    return isaacgymenvs_mw.make("Cartpole", num_envs=N, sim_device="cpu", rl_device="cpu", headless=True)


def test_every_ige_name_is_here_or_documented_as_meaningless(cartpole):
    names = IGE_ENV_NAMES + IGE_VECTASK_NAMES + CLIENT_NAMES
    absent = porting_absent_names()
    assert absent, "docs/porting.md lists no IsaacGymEnvs name without a meaning here"
    assert absent <= set(names), f"porting.md names what IsaacGymEnvs' VecTask lacks: {absent - set(names)}"
    for name in names:
        if name in absent:
            assert not hasattr(cartpole, name), f"{name} exists, yet porting.md says it has no meaning here"
        else:
            assert hasattr(cartpole, name), f"IsaacGymEnvs' VecTask.{name} is missing and not in porting.md"
    for name in METHODS - absent:
        assert callable(getattr(cartpole, name)), name


def test_sizes_spaces_and_settings_of_cartpole(cartpole):
    t = cartpole
    assert t.num_environments == t.num_envs == N
    assert t.num_agents == t.get_number_of_agents() == 1
    assert t.num_observations == t.num_obs == 4 and t.num_actions == t.num_acts == 1 and t.num_states == 0
    for space, shape in ((t.obs_space, (4,)), (t.observation_space, (4,)), (t.state_space, (0,)),
                         (t.act_space, (1,)), (t.action_space, (1,))):
        assert isinstance(space, gym.spaces.Box) and space.shape == shape
    assert np.all(t.obs_space.low == -np.inf) and np.all(t.obs_space.high == np.inf)
    assert np.all(t.act_space.low == -1.0) and np.all(t.act_space.high == 1.0)
    # Cartpole.yaml: clipObservations 5, clipActions 1, dt 0.0166, controlFrequencyInv 1, 8.3 s = 500 steps
    assert (t.clip_obs, t.clip_actions, t.control_freq_inv) == (5.0, 1.0, 1)
    assert t.dt == pytest.approx(0.0166) and t.max_episode_length == 500
    assert (t.device, t.rl_device, t.sim_device, t.device_type, t.device_id) == ("cpu", "cpu", "cpu", "cpu", 0)
    assert t.headless is True and t.graphics_device_id == 0
    assert t.virtual_screen_capture is False and t.force_render is False and t.sim_initialized is True
    assert t.metadata["render.modes"] == t.metadata["render_modes"] == ["human", "rgb_array"]
    assert t.metadata["video.frames_per_second"] == t.metadata["render_fps"] == 24


def test_buffers_and_the_step_cycle(cartpole):
    t = cartpole
    obs_dict = t.reset()
    assert obs_dict is t.obs_dict and obs_dict["obs"].shape == (N, 4) and "states" not in obs_dict
    for name, shape, dtype in (("obs_buf", (N, 4), torch.float32), ("states_buf", (N, 0), torch.float32),
                               ("rew_buf", (N,), torch.float32), ("reset_buf", (N,), torch.long),
                               ("timeout_buf", (N,), torch.long), ("progress_buf", (N,), torch.long),
                               ("randomize_buf", (N,), torch.long)):
        buf = getattr(t, name)
        assert isinstance(buf, torch.Tensor) and tuple(buf.shape) == shape and buf.dtype == dtype, name
    assert t.get_state().shape == (N, 0)
    actions = t.zero_actions()
    assert actions.shape == (N, 1) and actions.dtype == torch.float32 and not actions.any()
    steps, frames, since = t.control_steps, t.total_train_env_frames, t.randomize_buf.clone()
    out = t.step(actions)
    assert len(out) == 4 and out[0]["obs"].shape == (N, 4) and out[1].shape == (N,) and isinstance(out[3], dict)
    assert isinstance(t.extras, dict) and "time_outs" in t.extras
    assert t.control_steps == steps + 1 and t.total_train_env_frames == frames + N
    assert torch.equal(t.randomize_buf, since + 1)  # no env reset in one step from a fresh reset
    obs, done = t.reset_done()
    assert obs["obs"].shape == (N, 4) and done.dtype == torch.long and done.dim() == 1
    t.set_train_info(7 * N)
    assert t.total_train_env_frames == 7 * N  # the frame count the learner sends, as IsaacGymEnvs stores it
    assert t.get_env_state() is None


def test_randomize_buf_restarts_where_an_env_resets_and_is_not_counted_twice(cartpole):
    t = cartpole
    t.reset()
    t.step(t.zero_actions())
    t.reset_envs(torch.tensor([1, 3]))
    assert t.randomize_buf[[1, 3]].tolist() == [0, 0] and bool((t.randomize_buf[[0, 2]] > 0).all())
    with pytest.raises(AttributeError, match=r"randomize_buf is counted by VecTask"):
        t.randomize_buf += 1


def test_an_asymmetric_critic_reads_state_space():
    import isaacgymenvs_mw
    t = isaacgymenvs_mw.make("AllegroHand", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True,
                             overrides=["task.env.asymmetric_observations=True",
                                        "task.env.observationType=full_no_vel"])
    assert (t.num_obs, t.num_states, t.num_actions) == (50, 88, 16)
    assert isinstance(t.state_space, gym.spaces.Box) and t.state_space.shape == (88,)
    assert t.obs_space.shape == (50,) and t.act_space.shape == (16,)
    out = t.reset()
    assert out["states"].shape == (2, *t.state_space.shape) and t.get_state().shape == (2, 88)
    assert t.states_buf.shape == (2, 88)
