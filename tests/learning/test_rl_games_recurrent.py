"""rl_games' recurrent policies (``params.network.rnn``, IsaacGymEnvs' LSTM recipes): training, test mode's state
carried per env and zeroed at episode ends, and the exported policy, each checked against rl_games' own network."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import REPO_ROOT
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError

IGE_CFG = REPO_ROOT / "tests" / "data" / "isaacgymenvs_cfg"  # IsaacGymEnvs' own train YAMLs, as they ship

# Network variants: IsaacGymEnvs' AllegroKukaLSTM (the LSTM before the MLP), its ShadowHand LSTM (after the MLP,
# the observation beside its input), and a GRU on separate actor and critic networks with the observation beside
# its output.
VARIANTS = {
    "lstm_before_mlp": ({"name": "lstm", "units": 16, "layers": 1, "before_mlp": True, "layer_norm": True}, False),
    "lstm_after_mlp": ({"name": "lstm", "units": 8, "layers": 2, "before_mlp": False, "concat_input": True,
                        "layer_norm": True}, False),
    "gru_separate": ({"name": "gru", "units": 8, "layers": 1, "concat_output": True}, True),
}


def _runner(rnn: dict, separate: bool, num_envs: int = 4):
    """An rl_games runner for Cartpole's recipe with the given RNN, its input normaliser set off its defaults."""
    from isaacgymenvs_mw.learning.rl_games_runner import RlGamesRunner, RlGamesVecEnv, rl_games_params
    from isaacgymenvs_mw.tasks.build import build_task

    overrides = [f"++train.params.network.rnn.{k}={v}" for k, v in rnn.items()]
    cfg = compose_config(["learner=rl_games", "task=Cartpole", f"num_envs={num_envs}", "sim_device=cpu",
                          "rl_device=cpu", "headless=True", "train.params.network.mlp.units=[16,8]",
                          f"train.params.network.separate={separate}", "++train.params.config.seq_length=4",
                          *overrides])
    task = build_task(cfg)
    runner = RlGamesRunner(RlGamesVecEnv(task), rl_games_params(cfg, task), log_dir=None, device="cpu")
    model = runner.agent.model
    generator = torch.Generator().manual_seed(3)
    with torch.no_grad():
        model.running_mean_std.running_mean.copy_(torch.randn(4, generator=generator))
        model.running_mean_std.running_var.copy_(torch.rand(4, generator=generator) * 4 + 0.1)
        for p in model.parameters():  # away from the initialisers' zeros (rl_games starts mu's bias at 0)
            p.add_(0.1 * torch.randn(p.shape, generator=generator))
    model.eval()
    return runner


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_one_step_recurrent_policy_is_rl_games_own_network_over_a_sequence(variant):
    """Five steps of 3 envs with the state carried: the mean action and the next state equal those of rl_games'
    ``actor_critic`` forward (its normaliser, its sequence handling), fed the same observations and states."""
    from isaacgymenvs_mw.learning.rl_games_runner import _RlGamesRecurrentPolicy

    rnn, separate = VARIANTS[variant]
    runner = _runner(rnn, separate)
    agent = runner.agent
    module = _RlGamesRecurrentPolicy(agent).eval()
    obs = torch.randn(5, 3, 4, generator=torch.Generator().manual_seed(7)) * 2
    ours = module.initial_state(3)
    theirs = tuple(torch.zeros(s.shape[0], 3, s.shape[2]) for s in agent.model.get_default_rnn_state())
    with torch.no_grad():
        for t in range(5):
            mu, _, ours = module.step(obs[t], ours)
            out = agent.model({"is_train": False, "obs": obs[t], "prev_actions": None, "rnn_states": theirs})
            theirs = out["rnn_states"]
            torch.testing.assert_close(mu, out["mus"], rtol=1e-5, atol=1e-6)
            for a, b in zip(ours, theirs):  # the actor's states come first (rl_games: actor's, then critic's)
                torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    assert module.input_names == (["obs", "h_in", "c_in"] if rnn["name"] == "lstm" else ["obs", "h_in"])


def test_test_mode_policy_carries_each_envs_state_and_zeroes_it_when_its_episode_ends():
    """The state after a step is the module's next state; reset(dones) zeroes the envs that are done and only those."""
    from isaacgymenvs_mw.learning.rl_games_runner import RecurrentPolicy, _RlGamesRecurrentPolicy

    runner = _runner(*VARIANTS["lstm_before_mlp"])
    policy = runner.get_inference_policy("cpu")
    assert isinstance(policy, RecurrentPolicy)
    module = _RlGamesRecurrentPolicy(runner.agent).eval()
    obs = torch.randn(2, 4, 4, generator=torch.Generator().manual_seed(1))
    state = module.initial_state(4)
    for t in range(2):
        with torch.no_grad():
            expected, *state = module(obs[t], *state)
        torch.testing.assert_close(policy({"policy": obs[t]}), expected)
    before = tuple(s.clone() for s in policy.state)
    assert all(float(s.abs().min()) > 0 for s in before)  # an LSTM state is never exactly 0 after a step
    policy.reset(torch.tensor([0, 1, 0, 1]))
    for s, b in zip(policy.state, before):
        torch.testing.assert_close(s[:, [0, 2]], b[:, [0, 2]])
        assert torch.count_nonzero(s[:, [1, 3]]) == 0


def test_isaacgymenvs_allegro_kuka_lstm_yaml_trains_evaluates_and_exports_its_state(tmp_path, run_args, capsys):
    """IsaacGymEnvs' AllegroKukaLSTMPPO.yaml (its LSTM of 768 units before the MLP, inheriting AllegroKukaPPO.yaml),
    unchanged, at 4 envs: trains 2 iterations, evaluates in test mode, and exports an ONNX and a TorchScript policy
    that take and return the LSTM's state; both give the actions of test mode's module over 3 steps."""
    import onnxruntime

    from isaacgymenvs_mw.learning.export import read_metadata

    args = ["task=AllegroKuka", "train=AllegroKukaLSTMPPO", "num_envs=4", *run_args]
    summary = run(compose_config([*args, "max_iterations=2"], config_dir=IGE_CFG))
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 16 * 4
    assert "in whole sequences of seq_length 16" in capsys.readouterr().out
    (run_dir,) = (tmp_path / "runs" / "AllegroKukaLSTMPPO").iterdir()
    result = run(compose_config([*args, "test=True", f"checkpoint={run_dir / 'model_2.pt'}",
                                 "task.env.episodeLength_s=0.1"], config_dir=IGE_CFG))
    assert result["episodes"] == 4 and result["test_actions"] == "sampled"

    exported = run_dir / "exported"
    meta = read_metadata(exported / "policy.onnx")
    assert meta["recurrent"] == {"type": "lstm", "state_inputs": ["h_in", "c_in"], "state_outputs": ["h_out", "c_out"],
                                 "state_shape": [1, "batch", 768], "episode_start": "zeros"}
    module = _module_from(run_dir / "model_2.pt", args)
    session = onnxruntime.InferenceSession(str(exported / "policy.onnx"))
    script = torch.jit.load(str(exported / "policy.pt"))
    obs = torch.randn(3, 3, module.obs_shape[0], generator=torch.Generator().manual_seed(0))
    state = ours = scripted = module.initial_state(3)
    with torch.no_grad():
        for t in range(3):
            expected, *ours = module(obs[t], *ours)
            actions, *state = session.run(["actions", "h_out", "c_out"], {
                "obs": obs[t].numpy(), "h_in": np.asarray(state[0]), "c_in": np.asarray(state[1])})
            np.testing.assert_allclose(actions, expected.numpy(), rtol=1e-4, atol=1e-5)
            traced, *scripted = script(obs[t], *scripted)
            torch.testing.assert_close(traced, expected, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(state[0], ours[0].numpy(), rtol=1e-4, atol=1e-5)


def test_isaacgymenvs_shadow_hand_lstm_yaml_trains_and_evaluates(tmp_path, run_args, capsys):
    """IsaacGymEnvs' ShadowHandPPOLSTM.yaml, unchanged: an LSTM after the MLP with the observation beside its input,
    seq_len 4 (taken as seq_length), no max_epochs (rl_games would train without end: max_iterations gives it, and
    without it the run stops with one line); 2 iterations, then test mode on its checkpoint."""
    args = ["task=ShadowHand", "train=ShadowHandPPOLSTM", "num_envs=8", *run_args]
    with pytest.raises(ConfigError, match=r"train.params.config.max_epochs is not set, and rl_games would train "):
        run(compose_config(args, config_dir=IGE_CFG))
    summary = run(compose_config([*args, "max_iterations=2"], config_dir=IGE_CFG))
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 32 * 8
    printed = capsys.readouterr().out
    assert "max_epochs is not set and max_iterations=2 gives it" in printed
    assert "in whole sequences of seq_length 4" in printed
    (run_dir,) = (tmp_path / "runs" / "ShadowHandLSTM").iterdir()
    result = run(compose_config([*args, "test=True", "max_iterations=2", f"checkpoint={run_dir / 'model_2.pt'}",
                                 "task.env.episodeLength_s=0.1"], config_dir=IGE_CFG))
    assert result["episodes"] == 8 and result["test_actions"] == "mean"


def _module_from(checkpoint: Path, args: list[str]):
    from isaacgymenvs_mw.learning.rl_games_runner import RlGamesRunner, RlGamesVecEnv, _RlGamesRecurrentPolicy
    from isaacgymenvs_mw.learning.rl_games_runner import rl_games_params
    from isaacgymenvs_mw.tasks.build import build_task

    cfg = compose_config([*args, "test=True", f"checkpoint={checkpoint}"], config_dir=IGE_CFG)
    task = build_task(cfg)
    runner = RlGamesRunner(RlGamesVecEnv(task), rl_games_params(cfg, task), log_dir=None, device="cpu")
    runner.load(str(checkpoint), map_location="cpu")
    return _RlGamesRecurrentPolicy(runner.agent).eval()


def test_minibatches_are_fitted_in_whole_sequences():
    """With an RNN a minibatch holds whole sequences: the fitted size divides the iteration's samples and is a
    multiple of seq_length (64 samples: 48 -> 32 with sequences of 16, 48 -> 32 without; 8 -> 16 with)."""
    from isaacgymenvs_mw.learning.rl_games_runner import fit_minibatches

    def fitted(size: int, multiple: int) -> int:
        config = {"horizon_length": 16, "minibatch_size": size}
        fit_minibatches(config, 4, announce=False, multiple=multiple)
        return config["minibatch_size"]

    assert fitted(48, 16) == 32 and fitted(48, 1) == 32 and fitted(8, 16) == 16 and fitted(24, 8) == 16
    assert fitted(64, 16) == 64 and fitted(16, 16) == 16 and fitted(8, 1) == 8


def test_seq_len_of_older_rl_games_is_read_as_seq_length():
    """IsaacGymEnvs' ShadowHand LSTM YAMLs write seq_len, which rl_games 1.6 no longer reads: the run's agent gets it as
    seq_length; both keys with different values are refused."""
    from isaacgymenvs_mw.learning.rl_games_runner import rl_games_params
    from isaacgymenvs_mw.learning.train_config import check_before_start
    from isaacgymenvs_mw.tasks.build import build_task

    base = ["learner=rl_games", "task=Cartpole", "num_envs=4", "sim_device=cpu", "rl_device=cpu",
            "++train.params.network.rnn.name=gru", "++train.params.network.rnn.units=4",
            "++train.params.network.rnn.layers=1"]
    cfg = compose_config([*base, "++train.params.config.seq_len=8"])
    params = rl_games_params(cfg, build_task(cfg))
    assert params["config"]["seq_length"] == 8 and "seq_len" not in params["config"]
    with pytest.raises(ConfigError, match=r"seq_len=8 and seq_length=4 disagree"):
        check_before_start(compose_config([*base, "++train.params.config.seq_len=8",
                                           "++train.params.config.seq_length=4"]))
