"""The second learner, rl_games (IsaacGymEnvs' own): training, test mode, export, IsaacGymEnvs' train YAMLs, stops
and errors, through the same run folder and summary as rsl-rl-lib's runs."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import REPO_ROOT, signal_at_line
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.utils.config import compose_config
from isaacgymenvs_mw.utils.errors import ConfigError

IGE_CFG = REPO_ROOT / "tests" / "data" / "isaacgymenvs_cfg"  # IsaacGymEnvs' own train YAMLs, as they ship


def _run_dir(runs: Path, experiment: str) -> Path:
    (run_dir,) = [p for p in (runs / experiment).iterdir() if p.is_dir()]
    return run_dir


def test_cartpole_learns_with_rl_games_and_test_mode_evaluates_its_checkpoint(tmp_path, run_args):
    runs = tmp_path / "runs"
    summary = run(compose_config(["learner=rl_games", "task=Cartpole", "num_envs=64", "max_iterations=30", *run_args]))
    history = summary["history"]
    first = next(r["mean_episode_reward"] for r in history if r.get("mean_episode_reward") is not None)
    # The pole falls within ~20 steps under the untrained policy; rl_games' PPO keeps it up far longer.
    assert summary["mean_episode_length"] > 100 and summary["mean_episode_reward"] > 3 * first, (first, summary)
    run_dir = _run_dir(runs, "Cartpole")
    on_disk = json.loads((run_dir / "summary.json").read_text())
    # The same summary keys as an rsl_rl run's (tests/learning/test_training.py reads them too).
    rsl = run(compose_config(["task=Cartpole", "num_envs=8", "max_iterations=1", "experiment=rsl", *run_args]))
    assert set(on_disk) == set(rsl)
    assert on_disk["iterations"] == 30 and on_disk["env_steps"] == 30 * 16 * 64
    checkpoint = torch.load(run_dir / "model_30.pt", map_location="cpu", weights_only=False)
    assert checkpoint["learner"] == "rl_games" and checkpoint["iteration"] == 30 and "model" in checkpoint
    assert (run_dir / "model_best.pt").is_file() and on_disk["best_checkpoint"]["iteration"] >= 20  # save_best_after
    assert any(p.name.startswith("events.out.tfevents") for p in run_dir.iterdir())

    result = run(compose_config(["learner=rl_games", "task=Cartpole", "num_envs=32", "test=True",
                                 f"checkpoint={run_dir / 'model_30.pt'}", *run_args]))
    assert result["episodes"] == 32 and result["mean_episode_length"] > 150
    assert json.loads((run_dir / "eval.json").read_text())["mean_episode_length"] == result["mean_episode_length"]

    # The exported ONNX policy gives the action test mode's policy gives (rl_games' own model is the reference).
    import onnxruntime

    session = onnxruntime.InferenceSession(str(run_dir / "exported" / "policy.onnx"))
    obs = np.random.default_rng(0).normal(size=(5, 4)).astype(np.float32) * 3
    exported = session.run(["actions"], {"obs": obs})[0]
    agent = _agent_from(run_dir / "model_30.pt")
    with torch.no_grad():
        mus = agent.model({"is_train": False, "obs": torch.from_numpy(obs), "prev_actions": None})["mus"]
    assert np.allclose(exported, mus.clamp(-1, 1).numpy(), atol=1e-5)


def _agent_from(checkpoint: Path):
    """rl_games' A2CAgent for Cartpole's rl_games recipe with the checkpoint's weights, in eval mode."""
    from isaacgymenvs_mw.learning.rl_games_runner import RlGamesRunner, RlGamesVecEnv, rl_games_params
    from isaacgymenvs_mw.tasks.build import build_task

    cfg = compose_config(["learner=rl_games", "task=Cartpole", "num_envs=4", "sim_device=cpu", "rl_device=cpu",
                          "headless=True"])
    task = build_task(cfg)
    runner = RlGamesRunner(RlGamesVecEnv(task), rl_games_params(cfg, task), log_dir=None, device="cpu")
    runner.load(str(checkpoint), map_location="cpu")
    runner.agent.model.eval()
    return runner.agent


def test_isaacgymenvs_own_train_yaml_runs_unchanged_from_a_config_dir(tmp_path, run_args):
    """IsaacGymEnvs' AntPPO.yaml as it ships, named as IsaacGymEnvs names it: the folder given as --config-dir is
    searched before cfg/, whose own AntPPO.yaml (rsl-rl-lib's) it replaces."""
    cfg = compose_config(["task=Ant", "train=AntPPO", "num_envs=4", "max_iterations=2",
                          "train.params.config.minibatch_size=32", *run_args], config_dir=IGE_CFG)
    assert cfg.train.params.config.num_actors == 4 and cfg.train.params.config.max_epochs == 2
    summary = run(cfg)
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 16 * 4
    assert (_run_dir(tmp_path / "runs", "Ant") / "model_2.pt").is_file()


def test_a_rl_games_run_stopped_by_sigterm_keeps_its_checkpoint_and_summary(tmp_path):
    runs = tmp_path / "runs"
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), "learner=rl_games", "task=Cartpole", "num_envs=16",
           "max_iterations=100000", "headless=True", "sim_device=cpu", "rl_device=cpu", f"runs_dir={runs}"]
    status, out = signal_at_line(cmd, tmp_path, "[it     3/", signal.SIGTERM, timeout=300)
    assert status == 128 + signal.SIGTERM, out[-3000:]
    run_dir = _run_dir(runs, "Cartpole")
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["signal"] == "SIGTERM"
    interrupted = Path(summary["interrupted_checkpoint"])
    assert interrupted.is_file() and interrupted.name.endswith("_interrupted.pt")
    state = torch.load(interrupted, map_location="cpu", weights_only=False)
    assert state["learner"] == "rl_games" and state["iteration"] >= 3
    assert "Traceback" not in out


@pytest.mark.parametrize(("override", "message"), [
    ("+train.params.config.self_play=True", "train.params.config.self_play=True is not supported with "
                                            "learner=rl_games: self-play needs several agents per env"),
    ("+train.params.config.minibatch_sise=8", "train.params.config.minibatch_sise: not an rl_games key"),
    ("train.params.algo.name=sac", "train.params.algo.name='sac' is not supported with learner=rl_games"),
    ("+train.params.config.schedule_type=sometimes", "train.params.config.schedule_type='sometimes' is not "
                                                    "supported"),
    ("+train.params.network.cnn.type=conv2d", "train.params.network.cnn is not supported"),
    ("+train.params.network.rnn.name=transformer", "train.params.network.rnn.name='transformer' is not supported"),
    ("+train.params.network.rnn={name:lstm,units:8,layers:1,size:3}", "train.params.network.rnn.size: not an rl_games"),
    ("+train.params.network.rnn={name:lstm,units:0,layers:1}", "train.params.network.rnn.units=0 is invalid"),
    ("+train.params.network.rnn={name:lstm,units:8,layers:1} ++train.params.config.seq_length=5",
     "train.params.config.seq_length=5 is invalid with horizon_length=16"),
])
def test_rl_games_keys_this_project_cannot_honour_fail_naming_the_key(override, message):
    from isaacgymenvs_mw.learning.train_config import check_before_start

    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)").replace("+", r"\+")):
        check_before_start(compose_config(["learner=rl_games", *override.split(), "sim_device=cpu", "rl_device=cpu"]))


def test_learner_and_train_yaml_must_agree_and_checkpoints_name_their_learner(tmp_path):
    def train_py(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, str(REPO_ROOT / "train.py"), *args, "headless=True",
                               "sim_device=cpu", "rl_device=cpu"], cwd=tmp_path, capture_output=True, text=True,
                              timeout=300)

    proc = train_py("learner=rl_games", "train=CartpolePPO")
    assert proc.returncode == 2 and proc.stderr.strip().startswith(
        "[train] error: learner=rl_games, but the train YAML is rsl-rl-lib's"), proc.stderr
    proc = train_py("learner=keras")
    assert proc.returncode == 2 and "learner='keras' is invalid: choose one of ['rsl_rl', 'rl_games']" in proc.stderr
    rl_games_checkpoint = tmp_path / "model_7.pt"
    torch.save({"model": {}, "epoch": 7, "learner": "rl_games"}, rl_games_checkpoint)
    proc = train_py("test=True", f"checkpoint={rl_games_checkpoint}")
    assert proc.returncode == 2 and "it was written by learner=rl_games" in proc.stderr, proc.stderr


def test_the_test_mode_policy_is_rl_games_deterministic_action():
    """_RlGamesPolicy writes rl_games' input normaliser and action mapping out; rl_games' own model is the reference,
    with normaliser statistics far from the identity."""
    from isaacgymenvs_mw.learning.rl_games_runner import RlGamesRunner, RlGamesVecEnv, rl_games_params
    from isaacgymenvs_mw.tasks.build import build_task

    cfg = compose_config(["learner=rl_games", "task=Cartpole", "num_envs=4", "sim_device=cpu", "rl_device=cpu",
                          "headless=True"])
    task = build_task(cfg)
    runner = RlGamesRunner(RlGamesVecEnv(task), rl_games_params(cfg, task), log_dir=None, device="cpu")
    model = runner.agent.model
    with torch.no_grad():
        model.running_mean_std.running_mean.copy_(torch.tensor([0.5, -1.0, 2.0, 0.1], dtype=torch.float64))
        model.running_mean_std.running_var.copy_(torch.tensor([4.0, 0.25, 9.0, 0.01], dtype=torch.float64))
        for p in model.a2c_network.parameters():
            p.add_(torch.randn_like(p))  # actions beyond [-1, 1] too, to see the clamp
    model.eval()
    obs = torch.randn(64, 4) * 4
    policy = runner.get_inference_policy("cpu")
    from tensordict import TensorDict

    ours = policy(TensorDict({"policy": obs}, batch_size=[64]))
    with torch.no_grad():
        mus = model({"is_train": False, "obs": obs.clone(), "prev_actions": None})["mus"]
    assert (mus.abs() > 1).any()
    assert torch.allclose(ours, mus.clamp(-1, 1), atol=1e-6)


# reward_shaper.scale_value of IsaacGymEnvs' <Task>PPO.yaml (isaac-sim/IsaacGymEnvs isaacgymenvs/cfg/train): the factor
# on IGE's reward that its rl_games learned from.
IGE_REWARD_SCALE = {"AllegroHand": 0.01, "ShadowHand": 0.01, "Ant": 0.01, "Cartpole": 0.1, "FrankaCubeStack": 1.0,
                    "Trifinger": 0.01, "AllegroKuka": 0.01}


@pytest.mark.parametrize("task", sorted(IGE_REWARD_SCALE))
def test_shipped_rl_games_recipes_scale_the_reward_once_as_isaacgymenvs(task):
    """The learner's reward is the task's x reward_shaper.scale_value, and no task YAML scales it (issue 70: a task YAML
    that did, with IsaacGymEnvs' own train YAML, scaled IGE's 0.01 twice, 1e-4 in all, and nothing was learnt)."""
    cfg = compose_config(["learner=rl_games", f"task={task}", "sim_device=cpu", "rl_device=cpu"])
    assert "rewardScale" not in cfg.task.env
    task_scale = 1.0
    shaper = cfg.train.params.config.get("reward_shaper") or {}
    assert task_scale * float(shaper.get("scale_value", 1.0)) == pytest.approx(IGE_REWARD_SCALE[task])


@pytest.mark.parametrize("task, train, scale", [("Cartpole", "CartpolePPO", 0.1), ("Ant", "AntPPO", 0.01)])
def test_isaacgymenvs_train_yamls_train_with_few_envs_and_evaluate_scaling_the_reward_once(tmp_path, run_args, task,
                                                                                            train, scale, capsys):
    """IsaacGymEnvs' CartpolePPO.yaml and AntPPO.yaml, unchanged, at num_envs=64 (their minibatch_size is for
    thousands of envs: rl_games refuses one that does not divide the iteration's samples, so one line says which is
    used), then test mode on the checkpoint; the learner's reward is the task's (IsaacGymEnvs' formula, unscaled) x
    the YAML's scale_value, once."""
    args = [f"task={task}", f"train={train}", "num_envs=64", *run_args]
    summary = run(compose_config([*args, "max_iterations=2"], config_dir=IGE_CFG))
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 16 * 64
    printed = capsys.readouterr().out
    assert "minibatch_size=" in printed and "using 1024" in printed
    run_dir = _run_dir(tmp_path / "runs", task)
    result = run(compose_config([*args, "test=True", f"checkpoint={run_dir / 'model_2.pt'}"], config_dir=IGE_CFG))
    assert result["episodes"] == 64

    from isaacgymenvs_mw.learning.rl_games_runner import RlGamesRunner, RlGamesVecEnv, rl_games_params
    from isaacgymenvs_mw.learning.train_config import recipe_reward_scale
    from isaacgymenvs_mw.tasks.build import build_task
    from isaacgymenvs_mw.utils.config import to_dict

    cfg = compose_config([*args, "num_envs=8"], config_dir=IGE_CFG)
    assert "rewardScale" not in cfg.task.env and recipe_reward_scale(to_dict(cfg.train)) == scale
    task_ = build_task(cfg)
    runner = RlGamesRunner(RlGamesVecEnv(task_, scale), rl_games_params(cfg, task_), log_dir=None, device="cpu")
    task_.reset()
    _, rew, _, _ = task_.step(torch.rand(8, task_.num_actions) * 2 - 1)
    if task == "Cartpole":  # IsaacGymEnvs' formula on the state the step ended in
        from cartpole_reference import cartpole_reward_reference

        dof_pos, dof_vel = task_.sim.dof_pos.numpy(), task_.sim.dof_vel.numpy()
        ref, _, _ = cartpole_reward_reference(dof_pos[:, 0], dof_vel[:, 0], dof_pos[:, 1], dof_vel[:, 1],
                                              cfg.task.env.resetDist, task_.progress_buf.numpy(),
                                              task_.max_episode_length)
        np.testing.assert_allclose(rew.numpy(), ref, rtol=1e-5, atol=1e-6)
    shaped = runner.agent.rewards_shaper(rew)
    torch.testing.assert_close(shaped, rew * scale)


def test_rl_games_ranks_without_a_writer_build_their_runner(monkeypatch):
    """Under torchrun rl_games gives ranks above 0 no SummaryWriter (``agent.writer`` None); such a rank's runner
    builds and logs nothing (it once called ``writer.close()`` on None and torchrun killed the job)."""
    from rl_games.algos_torch import a2c_continuous

    from isaacgymenvs_mw.learning.rl_games_runner import RlGamesRunner, RlGamesVecEnv, _NoWriter, rl_games_params
    from isaacgymenvs_mw.tasks.build import build_task

    built = a2c_continuous.A2CAgent.__init__

    def as_rank_1(self, *args, **kwargs):
        built(self, *args, **kwargs)
        self.writer.close()
        self.writer = None  # what rl_games leaves on a rank above 0

    monkeypatch.setattr(a2c_continuous.A2CAgent, "__init__", as_rank_1)
    cfg = compose_config(["learner=rl_games", "task=Cartpole", "num_envs=4", "sim_device=cpu", "rl_device=cpu",
                          "headless=True"])
    task = build_task(cfg)
    runner = RlGamesRunner(RlGamesVecEnv(task), rl_games_params(cfg, task), log_dir=None, device="cpu")
    assert isinstance(runner.agent.writer, _NoWriter)


def test_learner_rl_games_without_rl_games_installed_is_one_line(monkeypatch):
    from isaacgymenvs_mw.learning.train_config import check_before_start

    monkeypatch.setitem(sys.modules, "rl_games", None)  # what importlib sees when the package is absent
    cfg = compose_config(["learner=rl_games", "task=Cartpole", "sim_device=cpu", "rl_device=cpu"])
    with pytest.raises(ConfigError, match=r'^learner=rl_games .* not installed: pip install -e "\.\[rl-games\]"'):
        check_before_start(cfg)


def test_isaacgymenvs_trifinger_yaml_trains_its_central_value_critic_on_the_privileged_state(tmp_path, run_args):
    """IsaacGymEnvs' TrifingerPPO.yaml, unchanged (its top-level asymmetric_obs and lr_schedule: constant included):
    the central value network reads the task's 113-value critic state, its own optimiser trains it (its weights move),
    the checkpoint keeps it, and test mode evaluates the policy."""
    args = ["task=Trifinger", "train=TrifingerPPO", "num_envs=8", *run_args]
    summary = run(compose_config([*args, "max_iterations=2", "train.params.config.save_frequency=1"],
                                 config_dir=IGE_CFG))
    assert summary["iterations"] == 2
    run_dir = _run_dir(tmp_path / "runs", "Trifinger")
    first, second = (torch.load(run_dir / f"model_{i}.pt", weights_only=False) for i in (1, 2))
    layers = [k for k, v in second["assymetric_vf_nets"].items() if k.endswith(".weight") and v.dim() == 2]
    assert second["assymetric_vf_nets"][layers[0]].shape[1] == 113  # 41 observed + 72 privileged values
    assert [second["assymetric_vf_nets"][k].shape[0] for k in layers] == [512, 512, 256, 128, 1]
    assert not torch.equal(first["assymetric_vf_nets"][layers[0]], second["assymetric_vf_nets"][layers[0]])
    result = run(compose_config([*args, "test=True", f"checkpoint={run_dir / 'model_2.pt'}",
                                 "task.env.episodeLength_s=0.1"], config_dir=IGE_CFG))
    assert result["episodes"] == 8


def test_shipped_rl_games_trifinger_recipe_is_isaacgymenvs_own():
    """learner=rl_games task=Trifinger composes to IsaacGymEnvs' TrifingerPPO.yaml: every PPO and central value setting
    the same, minibatches per env instead of num_actors (the same size), and only bookkeeping keys apart."""
    from isaacgymenvs_mw.utils.config import to_dict

    ours = to_dict(compose_config(["learner=rl_games", "task=Trifinger"]).train)
    ige = to_dict(compose_config(["task=Trifinger", "train=TrifingerPPO"], config_dir=IGE_CFG).train)
    assert ours["asymmetric_obs"] is ige["asymmetric_obs"] is True
    assert ours["params"]["network"] == ige["params"]["network"]
    bookkeeping = {"full_experiment_name", "score_to_win", "print_stats", "seq_len", "value_bootstrap", "player",
                   "minibatch_size", "minibatch_size_per_env", "central_value_config", "multi_gpu"}
    mine, theirs = ours["params"]["config"], ige["params"]["config"]
    assert {k: v for k, v in mine.items() if k not in bookkeeping} == \
        {k: v for k, v in theirs.items() if k not in bookkeeping}
    assert mine["minibatch_size_per_env"] * 16384 == theirs["minibatch_size"]  # num_actors at the default envs
    cv_mine, cv_theirs = mine["central_value_config"], theirs["central_value_config"]
    assert cv_mine.pop("minibatch_size_per_env") * 16384 == cv_theirs.pop("minibatch_size")
    assert cv_mine == cv_theirs


@pytest.mark.parametrize("recipe", ["AllegroKukaPPO", "AllegroKukaLSTMPPO"])
def test_shipped_rl_games_allegro_kuka_recipes_are_isaacgymenvs_own(recipe):
    """learner=rl_games task=AllegroKuka (and train=rl_games/AllegroKukaLSTMPPO, which inherits it) compose to
    IsaacGymEnvs' AllegroKukaPPO.yaml (AllegroKukaLSTMPPO.yaml): the same network and every setting the same, only
    rl_games' bookkeeping (its summaries' throttle, score_to_win, printing) left out."""
    from isaacgymenvs_mw.learning.train_config import check_before_start
    from isaacgymenvs_mw.utils.config import to_dict

    cfg = compose_config(["learner=rl_games", "task=AllegroKuka", f"train=rl_games/{recipe}", "sim_device=cpu",
                          "rl_device=cpu"])
    check_before_start(cfg)
    ours = to_dict(cfg.train)
    ige = to_dict(compose_config(["task=AllegroKuka", f"train={recipe}"], config_dir=IGE_CFG).train)
    assert ours["params"]["network"] == ige["params"]["network"]
    assert ("rnn" in ours["params"]["network"]) is (recipe == "AllegroKukaLSTMPPO")
    bookkeeping = {"score_to_win", "print_stats", "defer_summaries_sec", "summaries_interval_sec_min",
                   "summaries_interval_sec_max", "player"}
    mine, theirs = ours["params"]["config"], ige["params"]["config"]
    assert {k: v for k, v in mine.items() if k not in bookkeeping} == \
        {k: v for k, v in theirs.items() if k not in bookkeeping}
    assert mine["player"]["deterministic"] is theirs["player"]["deterministic"] is False


def test_asymmetric_obs_of_an_rl_games_yaml_is_checked_against_the_task(tmp_path, run_args):
    base = ["learner=rl_games", "task=Trifinger", "num_envs=2", "max_iterations=1", *run_args]
    with pytest.raises(ConfigError, match=r"train\.asymmetric_obs=True, but task Trifinger gives its critic no state"):
        run(compose_config([*base, "task.env.asymmetric_obs=False"]))
    with pytest.raises(ConfigError, match=r"train\.asymmetric_obs='yes' is invalid: give True or False"):
        run(compose_config([*base, "train.asymmetric_obs=yes"]))


def test_isaacgymenvs_allegro_kuka_yaml_runs_unchanged_and_its_player_samples(tmp_path, run_args, capsys):
    """IsaacGymEnvs' AllegroKukaPPO.yaml, unchanged: its summaries keys interpolate the pbt run key, its max_epochs is
    a number (100000) that the command line's max_iterations replaces with one line, and its player
    (deterministic: False) makes test mode sample the policy's actions, which eval.json says."""
    args = ["task=AllegroKuka", "train=AllegroKukaPPO", "num_envs=4", *run_args]
    summary = run(compose_config([*args, "max_iterations=2"], config_dir=IGE_CFG))
    assert summary["iterations"] == 2
    assert ("train.params.config.max_epochs=100000, which does not read it, and max_iterations=2 gives it"
            in capsys.readouterr().out)
    run_dir = _run_dir(tmp_path / "runs", "AllegroKukaPPO")
    result = run(compose_config([*args, "test=True", f"checkpoint={run_dir / 'model_2.pt'}",
                                 "task.env.episodeLength_s=0.1"], config_dir=IGE_CFG))
    assert result["episodes"] == 4 and result["test_actions"] == "sampled"
    with pytest.raises(ConfigError, match=r"pbt=True is not supported"):
        run(compose_config([*args, "pbt=True"], config_dir=IGE_CFG))


def test_isaacgymenvs_shadow_hand_yaml_runs_unchanged_and_scales_the_reward_once(tmp_path, run_args, capsys):
    """IsaacGymEnvs' ShadowHandPPO.yaml, unchanged, at 16 envs: its 32768-sample minibatch is fitted to an iteration's
    128 samples with one line, it trains 2 iterations of its horizon 8, its reward_shaper scales the task's unscaled
    reward by 0.01 once, and its deterministic player makes test mode take the mean action."""
    from isaacgymenvs_mw.learning.train_config import recipe_reward_scale
    from isaacgymenvs_mw.utils.config import to_dict

    args = ["task=ShadowHand", "train=ShadowHandPPO", "num_envs=16", *run_args]
    cfg = compose_config([*args, "max_iterations=2"], config_dir=IGE_CFG)
    assert "rewardScale" not in cfg.task.env and recipe_reward_scale(to_dict(cfg.train)) == 0.01
    summary = run(cfg)
    assert summary["iterations"] == 2 and summary["env_steps"] == 2 * 8 * 16
    assert "minibatch_size=32768" in capsys.readouterr().out
    run_dir = _run_dir(tmp_path / "runs", "ShadowHand")
    result = run(compose_config([*args, "test=True", f"checkpoint={run_dir / 'model_2.pt'}",
                                 "task.env.episodeLength_s=0.1"], config_dir=IGE_CFG))
    assert result["episodes"] == 16 and result["test_actions"] == "mean"


def test_sampled_test_mode_actions_are_rl_games_player_draws():
    """player.deterministic=False: the test-mode action is rl_games' own mean plus its own sigma times a standard
    normal draw, clamped to [-1, 1] (the same draw made here from the same seed); True keeps the mean."""
    from tensordict import TensorDict

    from isaacgymenvs_mw.learning.rl_games_runner import RlGamesRunner, RlGamesVecEnv, rl_games_params
    from isaacgymenvs_mw.tasks.build import build_task

    cfg = compose_config(["learner=rl_games", "task=Cartpole", "num_envs=4", "sim_device=cpu", "rl_device=cpu",
                          "headless=True", "++train.params.config.player.deterministic=False"])
    task = build_task(cfg)
    runner = RlGamesRunner(RlGamesVecEnv(task), rl_games_params(cfg, task), log_dir=None, device="cpu")
    assert runner.test_actions == "sampled"
    model = runner.agent.model
    with torch.no_grad():
        model.a2c_network.sigma.fill_(-0.5)  # log std: std 0.61
    model.eval()
    obs = torch.randn(256, 4)
    policy = runner.get_inference_policy("cpu")
    torch.manual_seed(3)
    ours = policy(TensorDict({"policy": obs}, batch_size=[256]))
    with torch.no_grad():
        out = model({"is_train": False, "obs": obs.clone(), "prev_actions": None})
    torch.manual_seed(3)
    draw = torch.randn_like(out["mus"])
    torch.testing.assert_close(out["sigmas"], torch.full_like(out["sigmas"], math.exp(-0.5)))
    torch.testing.assert_close(ours, (out["mus"] + out["sigmas"] * draw).clamp(-1, 1))
    assert not torch.allclose(ours, out["mus"].clamp(-1, 1), atol=1e-3)
