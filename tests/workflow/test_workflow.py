"""User workflows around a training run: exporting a policy, resuming, NaN/inf recovery, contact-overflow warnings,
bad run keys, checkpoint/task mismatch and the viewer fallback on a machine without a display.

Runs are launched in-process the way train.py launches them (``launch.run(compose_config([...]))``), on the CPU,
inside tmp_path. Expected values come from outside the code under test: the checkpoint's own tensors evaluated in
numpy, onnxruntime, MuJoCo C's host model (qpos0), a twin task stepped without the fault, counts derived from the
train YAML, and torch's view of how many GPUs this machine has.
"""

from __future__ import annotations

import datetime as _dt
import json
import re
import shutil
import sys
import types
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict

import isaacgymenvs_mw
from conftest import CPU_ARGS, REPO_ROOT
from isaacgymenvs_mw.learning import launch
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.learning.runner import Runner, rsl_rl_config
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.tasks import isaacgym_task_map
from isaacgymenvs_mw.tasks.cartpole import Cartpole
from isaacgymenvs_mw.utils.config import compose_config, to_dict
from isaacgymenvs_mw.utils.device import check_device_pair

N = 16  # envs of the short training runs
NORMALIZER_EPS = 1e-2  # rsl_rl EmpiricalNormalization: (x - mean) / (std + eps), eps default 1e-2


def cartpole_args(runs: Path, *extra: str) -> list[str]:
    return ["task=Cartpole", f"num_envs={N}", *CPU_ARGS, f"runs_dir={runs}", *extra]


def run_dirs(runs: Path, experiment: str = "Cartpole") -> set[Path]:
    root = runs / experiment
    return {p for p in root.iterdir() if p.is_dir()} if root.is_dir() else set()


def load_ckpt(path: Path) -> dict:
    return torch.load(path, map_location="cpu", weights_only=False)


@pytest.fixture(scope="module")
def trained_cartpole(tmp_path_factory) -> Path:
    """model_2.pt of a 2-iteration, 16-env Cartpole training run."""
    runs = tmp_path_factory.mktemp("trained") / "runs"
    summary = run(compose_config(cartpole_args(runs, "max_iterations=2")))
    ckpt = Path(summary["run_dir"]) / "model_2.pt"
    assert ckpt.is_file()
    return ckpt


# ----------------------------------------------------------------------------------------------------- 1. export
def reference_actions(actor: dict, obs: np.ndarray) -> np.ndarray:
    """The deterministic action of the checkpoint's actor, in float64 numpy from its state dict.

    Layout (cfg/train/CartpolePPO.yaml actor): obs normaliser, Linear-ELU-Linear-ELU-Linear, Gaussian mean = output.
    """
    a = {k: v.double().numpy() for k, v in actor.items()}
    x = (obs.astype(np.float64) - a["obs_normalizer._mean"]) / (a["obs_normalizer._std"] + NORMALIZER_EPS)
    layers = sorted({int(k.split(".")[1]) for k in a if k.startswith("mlp.") and k.endswith(".weight")})
    for i, layer in enumerate(layers):
        x = x @ a[f"mlp.{layer}.weight"].T + a[f"mlp.{layer}.bias"]
        if i < len(layers) - 1:
            x = np.where(x > 0, x, np.expm1(x))  # ELU(alpha=1)
    return x


def test_test_mode_exports_onnx_and_torchscript_matching_the_policy(trained_cartpole, tmp_path, make_cartpole,
                                                                    monkeypatch):
    import onnxruntime as ort  # a test dependency (not skipped when missing: the export would go unchecked)
    ckpt = trained_cartpole
    out_dir = ckpt.parent / "exported"
    shutil.rmtree(out_dir, ignore_errors=True)
    seen = {}
    original_evaluate = launch.evaluate

    def spy_evaluate(task, *args, **kwargs):
        seen["schedule_steps"] = float(task.randomizer.step_count)
        seen["env_steps"] = task.env_steps.clone()
        return original_evaluate(task, *args, **kwargs)

    monkeypatch.setattr(launch, "evaluate", spy_evaluate)
    run(compose_config(cartpole_args(tmp_path / "runs", "test=True", f"checkpoint={ckpt}")))
    # Test mode evaluates under the schedules' state at the checkpoint, not at their start.
    trained = load_ckpt(ckpt)["iter"] * int(compose_config(cartpole_args(tmp_path)).train.runner.num_steps_per_env)
    assert trained > 0 and seen["schedule_steps"] == trained
    # The documented counter of the run's env steps (all envs) reads the same: the checkpoint's, not 0.
    assert seen["env_steps"].dtype == torch.int64 and int(seen["env_steps"]) == trained * N
    onnx_path, jit_path = out_dir / "policy.onnx", out_dir / "policy.pt"
    assert onnx_path.is_file() and jit_path.is_file()

    state = load_ckpt(ckpt)
    actor = state["actor_state_dict"]
    mean, std = actor["obs_normalizer._mean"].squeeze(0), actor["obs_normalizer._std"].squeeze(0)
    # The normaliser has learned something: an export that dropped it would give different actions.
    assert int(actor["obs_normalizer.count"]) > 0
    assert not torch.allclose(std, torch.ones_like(std), atol=1e-2)

    # 7 rows: the mean, a few std away, far outside anything seen in training, random, zeros.
    gen = torch.Generator().manual_seed(1)
    obs = torch.stack([
        mean, mean + 3 * std, mean - 5 * std,
        mean + 100 * std, torch.tensor([40.0, -60.0, 25.0, -80.0]),
        torch.randn(4, generator=gen) * 2, torch.zeros(4),
    ]).float()
    assert obs.shape == (7, 4)
    expected = reference_actions(actor, obs.numpy())
    assert expected.shape == (7, 1)
    assert np.ptp(expected) > 1e-3  # the rows give distinct actions: a constant output would not pass

    # The policy as rsl_rl runs it, from the checkpoint loaded into a fresh runner.
    cfg = compose_config(["task=Cartpole", *CPU_ARGS])
    train_cfg = rsl_rl_config(to_dict(cfg.train))
    train_cfg.pop("experiment_name", None)
    train_cfg.pop("max_iterations")
    runner = Runner(RslRlVecEnv(make_cartpole(8)), train_cfg, log_dir=None, device="cpu")
    runner.load(str(ckpt), map_location="cpu")
    policy = runner.get_inference_policy(device="cpu")
    with torch.inference_mode():
        torch_actions = policy(TensorDict({"policy": obs, "critic": obs}, batch_size=[7])).numpy()
    np.testing.assert_allclose(torch_actions, expected, rtol=1e-5, atol=1e-6)

    sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    (inp,), (outp,) = sess.get_inputs(), sess.get_outputs()
    assert inp.name == "obs" and outp.name == "actions"
    assert not isinstance(inp.shape[0], int)  # dynamic batch axis
    onnx_actions = sess.run(["actions"], {"obs": obs.numpy()})[0]
    assert onnx_actions.shape == (7, 1)
    np.testing.assert_allclose(onnx_actions, expected, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(onnx_actions, torch_actions, rtol=1e-5, atol=1e-6)
    # one row at a time gives the same as the batch
    np.testing.assert_allclose(sess.run(["actions"], {"obs": obs[4:5].numpy()})[0], onnx_actions[4:5],
                               rtol=1e-5, atol=1e-6)

    jit = torch.jit.load(str(jit_path), map_location="cpu")
    with torch.no_grad():
        jit_actions = jit(obs).numpy()
    np.testing.assert_allclose(jit_actions, expected, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(jit_actions, torch_actions, rtol=1e-5, atol=1e-6)


# ----------------------------------------------------------------------------------------------------- 2. resume
def fixed_clock(monkeypatch, *stamps: _dt.datetime) -> None:
    """launch.run names run dirs after datetime.now(); hand it these times, one per run."""
    times = iter(stamps)
    fake_datetime = types.SimpleNamespace(now=lambda *a, **k: next(times))
    monkeypatch.setattr(launch, "datetime", types.SimpleNamespace(datetime=fake_datetime))


def test_resume_continues_from_checkpoint_in_a_new_run_dir(tmp_path, monkeypatch):
    runs = tmp_path / "runs"
    # Two distinct stamps: this test is about resuming (same-second run dirs: the test below).
    fixed_clock(monkeypatch, _dt.datetime(2030, 1, 1, 12, 0, 0), _dt.datetime(2030, 1, 1, 12, 0, 1))
    cfg = compose_config(cartpole_args(runs, "max_iterations=3"))
    steps = int(cfg.train.runner.num_steps_per_env)
    updates_per_it = int(cfg.train.algorithm.num_learning_epochs) * int(cfg.train.algorithm.num_mini_batches)
    first = run(cfg)
    first_dir = Path(first["run_dir"])
    ckpt3 = first_dir / "model_3.pt"
    state3 = load_ckpt(ckpt3)

    # What the resumed runner holds when its learn() starts.
    at_start = {}
    original_learn = Runner.learn

    def spy_learn(self, *args, **kwargs):
        saved = self.alg.save()
        at_start.update(actor={k: v.clone() for k, v in saved["actor_state_dict"].items()},
                        critic={k: v.clone() for k, v in saved["critic_state_dict"].items()},
                        iteration=self.current_learning_iteration,
                        schedule_steps=float(self.env.task.randomizer.step_count),
                        env_steps=int(self.env.task.env_steps))
        return original_learn(self, *args, **kwargs)

    monkeypatch.setattr(Runner, "learn", spy_learn)
    # max_iterations on resume is the total, as in IsaacGymEnvs: from iteration 3 to 5 is 2 more
    second = run(compose_config(cartpole_args(runs, "max_iterations=5", f"checkpoint={ckpt3}")))
    second_dir = Path(second["run_dir"])

    assert run_dirs(runs) == {first_dir, second_dir} and second_dir != first_dir
    # Same layout as a fresh run: config.yaml, summary.json, the final checkpoint, TensorBoard events.
    def layout(d: Path) -> list[str]:
        return sorted("events" if p.name.startswith("events.out.tfevents") else re.sub(r"\d+", "N", p.name)
                      for p in d.iterdir())

    # (model_best.pt: save_best, on by default)
    assert layout(second_dir) == layout(first_dir) == ["config.yaml", "events", "model_N.pt", "model_best.pt",
                                                       "summary.json"]
    assert (second_dir / "model_5.pt").is_file() and not (second_dir / "model_3.pt").exists()
    summary = json.loads((second_dir / "summary.json").read_text())
    assert summary["final_iteration"] == 5 and summary["iterations"] == 2
    # The env-step count goes on from the checkpoint's (recorded in it), as the iterations do.
    assert state3["infos"]["env_steps"] == 3 * steps * N
    assert summary["env_steps"] == 5 * steps * N
    assert [(h["iteration"], h["env_steps"]) for h in summary["history"]] == [(4, 4 * steps * N), (5, 5 * steps * N)]
    assert summary["env_steps_per_s"] == pytest.approx(2 * steps * N / summary["train_time_s"])  # this run's steps
    saved_cfg = (second_dir / "config.yaml").read_text()
    assert str(ckpt3) in saved_cfg

    # The resumed run started from the checkpoint's weights and iteration, and its randomisation schedules and
    # penalty curriculum from the checkpoint's env steps per env (3 iterations of `steps`), not from 0.
    assert at_start["iteration"] == 3
    assert at_start["schedule_steps"] == 3 * steps
    assert at_start["env_steps"] == 3 * steps * N  # VecTask.env_steps: the run's env steps over all envs
    for part in ("actor", "critic"):
        for key, value in state3[f"{part}_state_dict"].items():
            assert torch.equal(at_start[part][key], value), (part, key)

    state5 = load_ckpt(second_dir / "model_5.pt")
    assert state3["iter"] == 3 and state5["iter"] == 5 and state5["infos"]["env_steps"] == 5 * steps * N
    # It went on from there rather than restarting: the normaliser kept counting, the optimiser kept stepping.
    count3, count5 = (int(s["actor_state_dict"]["obs_normalizer.count"]) for s in (state3, state5))
    assert count3 == 3 * steps * N and count5 == 5 * steps * N
    adam3, adam5 = state3["optimizer_state_dict"]["state"][0], state5["optimizer_state_dict"]["state"][0]
    assert float(adam3["step"]) == 3 * updates_per_it and float(adam5["step"]) == 5 * updates_per_it
    # ... and it trained: weights moved from 3 to 5.
    assert not torch.equal(state3["actor_state_dict"]["mlp.0.weight"], state5["actor_state_dict"]["mlp.0.weight"])


def test_runs_started_in_the_same_second_get_separate_run_dirs(tmp_path, monkeypatch):
    """Back-to-back runs (a resume right after training, a seed sweep launched by a script) must not share a dir.

    The run dir is named after a timestamp with one-second resolution and created with exist_ok=True, so two runs
    that start within the same second write into one directory: the second overwrites config.yaml, summary.json and
    same-numbered checkpoints of the first, and their TensorBoard event files end up side by side.
    """
    runs = tmp_path / "runs"
    same = _dt.datetime(2030, 1, 1, 12, 0, 0)
    fixed_clock(monkeypatch, same, same)
    first = run(compose_config(cartpole_args(runs, "max_iterations=1", "seed=1")))
    second = run(compose_config(cartpole_args(runs, "max_iterations=1", "seed=2")))
    assert first["run_dir"] != second["run_dir"]
    assert len(run_dirs(runs)) == 2
    for summary in (first, second):
        on_disk = json.loads((Path(summary["run_dir"]) / "summary.json").read_text())
        assert on_disk["seed"] == summary["seed"]


# -------------------------------------------------------------------------------------------- 3. NaN/inf state
def twin_cartpoles(make_cartpole, n: int = 8):
    """Two tasks in the same state: same seed for the reset, same explicit progress counters."""
    tasks = []
    for _ in range(2):
        task = make_cartpole(n)
        torch.manual_seed(123)
        task.reset()
        tasks.append(task)
    assert torch.equal(tasks[0].sim.qpos, tasks[1].sim.qpos) and torch.equal(tasks[0].sim.qvel, tasks[1].sim.qvel)
    return tasks


# 1e6: finite, but past the simulator's divergence bound (1e4), as a world one step from NaN is.
@pytest.mark.parametrize("field,value", [("qvel", float("nan")), ("qpos", float("inf")), ("qvel", float("-inf")),
                                         ("qvel", 1.0e6)])
def test_nonfinite_world_is_reset_and_others_unaffected(make_cartpole, field, value):
    n, bad = 8, 3
    faulty, twin = twin_cartpoles(make_cartpole, n)
    actions = torch.linspace(-0.8, 0.8, n).view(n, 1)
    for task in (faulty, twin):
        torch.manual_seed(7)
        for _ in range(3):
            task.step(actions)
        # env `bad` is one step from its time-out: the blow-up must be reported as a termination, not a time-out
        task.progress_buf[bad] = task.max_episode_length - 2
    assert torch.equal(faulty.sim.qpos, twin.sim.qpos)

    getattr(faulty.sim, field)[bad, 0] = value
    torch.manual_seed(9)
    obs_f, rew_f, reset_f, extras_f = faulty.step(actions)
    torch.manual_seed(9)
    obs_t, rew_t, reset_t, extras_t = twin.step(actions)

    expected_mask = torch.zeros(n, dtype=torch.bool)
    expected_mask[bad] = True
    assert torch.equal(extras_f["nonfinite_resets"].bool(), expected_mask)
    assert not extras_t["nonfinite_resets"].any()
    assert int(reset_f[bad]) == 1 and int(extras_f["time_outs"][bad]) == 0
    assert int(extras_t["time_outs"][bad]) == 1  # control: without the fault this env times out on this step

    # A termination like any other: the task's reset_idx placed it within Cartpole's reset noise (qpos0 = zeros), and
    # its observation is that new state; everything is finite.
    assert (faulty.sim.qpos[bad].abs() <= faulty.reset_position_noise).all()
    assert (faulty.sim.qvel[bad].abs() <= faulty.reset_velocity_noise).all()
    q, v = faulty.sim.qpos[bad], faulty.sim.qvel[bad]
    state = torch.stack((q[0], v[0], q[1], v[1]))  # [cart pos, cart vel, pole angle, pole vel]
    assert torch.equal(obs_f["obs"][bad], state.clamp(-faulty.clip_obs, faulty.clip_obs))
    assert float(rew_f[bad]) == 0.0  # the blown-up step earns nothing
    for t in (faulty.sim.qpos, faulty.sim.qvel, obs_f["obs"], rew_f):
        assert torch.isfinite(t).all()

    # Every other env is bit-identical to the twin that never saw the fault.
    others = ~expected_mask
    for a, b in ((faulty.sim.qpos, twin.sim.qpos), (faulty.sim.qvel, twin.sim.qvel), (obs_f["obs"], obs_t["obs"]),
                 (rew_f, rew_t), (reset_f, reset_t), (extras_f["time_outs"], extras_t["time_outs"]),
                 (faulty.progress_buf, twin.progress_buf)):
        assert torch.equal(a[others], b[others])

    # The next step is ordinary again.
    _, _, _, extras_next = faulty.step(actions)
    assert not extras_next["nonfinite_resets"].any()


def test_nonfinite_resets_are_counted_by_the_vecenv_stats(make_cartpole):
    env = RslRlVecEnv(make_cartpole(8))
    assert env.stats.pop()["nonfinite_resets"] == 0
    actions = torch.zeros(8, 1)
    env.task.sim.qvel[3, 0] = float("nan")
    _, _, dones, _ = env.step(actions)
    assert int(dones[3]) == 1
    stats = env.stats.pop()
    assert stats["nonfinite_resets"] == 1 and stats["episodes"] >= 1
    env.step(actions)
    assert env.stats.pop()["nonfinite_resets"] == 0


def test_nonfinite_resets_reach_the_run_summary(tmp_path, monkeypatch):
    """A blow-up in the middle of a training run is survived, counted once and written to summary.json."""
    original = Cartpole.pre_physics_step

    def faulty_pre_physics_step(self, actions):
        original(self, actions)
        if self.control_steps == 5:  # sixth env step of the first iteration
            self.sim.qvel[2, 1] = float("nan")

    monkeypatch.setattr(Cartpole, "pre_physics_step", faulty_pre_physics_step)
    summary = run(compose_config(cartpole_args(tmp_path / "runs", "max_iterations=2")))
    on_disk = json.loads((Path(summary["run_dir"]) / "summary.json").read_text())
    assert on_disk["nonfinite_resets"] == 1
    assert [h["nonfinite_resets"] for h in on_disk["history"]] == [1, 0]
    assert on_disk["final_iteration"] == 2


# ---------------------------------------------------------------------------------------- 4. contact overflow
GO1_QUIET = ["~task.task.randomization_params.push", "~task.task.randomization_params.observations"]
GO1_STEPS = 10  # 0.2 s: dropped from 0.34 m, the feet are on the ground


def go1(*overrides: str):
    return isaacgymenvs_mw.make("Go1", num_envs=4, sim_device="cpu", rl_device="cpu",
                                overrides=[*GO1_QUIET, "task.sim.overflowCheckInterval=5", *overrides])


FEET = ["FL_foot", "FR_foot", "RL_foot", "RR_foot"]


def step_recording(task, steps: int) -> tuple[list[warnings.WarningMessage], list[str], torch.Tensor]:
    """Step with zero actions, recording warnings; returns them, the final poll's keys and each foot's peak load."""
    task.reset()
    actions = task.zero_actions()
    peak = torch.zeros(task.num_envs, len(FEET))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(steps):
            task.step(actions)
            feet = torch.stack([task.sim.sensor(f"contact_{foot}") for foot in FEET], dim=1)
            peak = torch.maximum(peak, feet.norm(dim=-1))
        keys = task.sim.poll_overflow()
    return caught, keys, peak


def test_contact_overflow_warns_naming_nconmax():
    caught, keys, _ = step_recording(go1("task.sim.nconmax=1"), GO1_STEPS)
    messages = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    # the periodic check inside step() (every 5 steps here) warned, and so did the explicit poll
    assert len(messages) >= 2, messages
    assert all("sim.nconmax" in m for m in messages), messages
    assert "sim.nconmax" in keys


def test_default_nconmax_fits_four_feet_on_the_ground():
    task = go1()
    caught, keys, peak = step_recording(task, GO1_STEPS)
    assert keys == []
    assert [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)] == []
    # the contacts were there (so no warning is not for lack of them): every foot of every robot touched down
    assert (peak > 1.0).all(), peak


# ----------------------------------------------------------------------------------------- 5. invalid run keys
@pytest.fixture
def no_simulator(monkeypatch):
    """Fail the test if a Simulator (device memory) is built."""
    from isaacgymenvs_mw.sim import simulator

    def forbidden(self, *args, **kwargs):
        raise AssertionError("Simulator was constructed before the bad key was reported")

    monkeypatch.setattr(simulator.Simulator, "__init__", forbidden)


def valid_device_choices() -> list[str]:
    n_gpu = torch.cuda.device_count() if torch.cuda.is_available() else 0
    return ["auto", "cpu"] + (["cuda"] + [f"cuda:{i}" for i in range(n_gpu)] if n_gpu else [])


@pytest.mark.parametrize("value", ["0", "-3"])
def test_bad_num_envs_fails_before_allocation(tmp_path, no_simulator, value):
    runs = tmp_path / "runs"
    with pytest.raises(ValueError, match=r"num_envs") as err:
        run(compose_config(["task=Cartpole", f"num_envs={value}", *CPU_ARGS, f"runs_dir={runs}"]))
    assert value in str(err.value) and ">= 1" in str(err.value)
    assert not runs.exists()


@pytest.mark.parametrize("key,value,other", [("sim_device", "tpu", "rl_device=cpu"),
                                             ("rl_device", "cuda:3", "sim_device=cpu")])
def test_bad_device_fails_before_allocation_listing_choices(tmp_path, no_simulator, key, value, other):
    if key == "rl_device" and torch.cuda.device_count() > 3:
        pytest.skip("this machine has a cuda:3")
    runs = tmp_path / "runs"
    with pytest.raises(ValueError) as err:
        run(compose_config(["task=Cartpole", "num_envs=4", f"{key}={value}", other, "headless=True",
                            f"runs_dir={runs}"]))
    msg = str(err.value)
    assert key in msg and value in msg
    for choice in valid_device_choices():
        assert f"'{choice}'" in msg, (choice, msg)
    assert not runs.exists()


def test_two_different_gpus_are_rejected_naming_both():
    with pytest.raises(ValueError) as err:
        check_device_pair("cuda:0", "cuda:1")
    assert "cuda:0" in str(err.value) and "cuda:1" in str(err.value)
    # supported pairs pass
    for pair in (("cuda:0", "cuda:0"), ("cuda:1", "cpu"), ("cpu", "cpu"), ("cpu", "cuda:0")):
        check_device_pair(*pair)


# --------------------------------------------------------------------------------- 6. checkpoint/task mismatch
@pytest.mark.parametrize("test_mode", [True, False])
def test_checkpoint_of_another_task_names_both_sizes(trained_cartpole, tmp_path, monkeypatch, test_mode):
    monkeypatch.syspath_prepend(str(REPO_ROOT))  # `examples` importable, as from train.py's directory
    if "Pendulum" not in isaacgym_task_map:
        sys.modules.pop("examples.pendulum_task", None)  # another test dropped the registration
    ckpt = tmp_path / "ckpt" / "model_2.pt"
    ckpt.parent.mkdir()
    shutil.copy(trained_cartpole, ckpt)
    args = ["task=Pendulum", "task_module=examples.pendulum_task", "num_envs=4", *CPU_ARGS,
            f"runs_dir={tmp_path / 'runs'}", f"checkpoint={ckpt}", f"test={test_mode}", "max_iterations=3"]
    with pytest.raises(ValueError) as err:
        run(compose_config(args))
    msg = str(err.value)
    assert re.search(r"\b4 observations\b", msg) and re.search(r"\b3 observations\b", msg), msg
    # nothing was evaluated or exported from the mismatched checkpoint
    assert sorted(p.name for p in ckpt.parent.iterdir()) == ["model_2.pt"]


def test_each_checkpoint_of_a_run_keeps_its_own_test_mode_results(trained_cartpole, tmp_path):
    # A run folder with an earlier and a last checkpoint (copies of one policy: only their names matter here).
    folder = (tmp_path / "run").resolve()
    folder.mkdir()
    for name in ("model_1.pt", "model_2.pt"):
        shutil.copy(trained_cartpole, folder / name)
    run(compose_config(cartpole_args(tmp_path / "runs", "test=True", f"checkpoint={folder / 'model_1.pt'}")))
    earlier = json.loads((folder / "eval_model_1.json").read_text())
    assert earlier["checkpoint"] == str(folder / "model_1.pt")
    assert (folder / "exported_model_1" / "policy.onnx").is_file()
    assert not (folder / "eval.json").exists() and not (folder / "exported").exists()

    run(compose_config(cartpole_args(tmp_path / "runs", "test=True", f"checkpoint={folder / 'model_2.pt'}")))
    assert json.loads((folder / "eval.json").read_text())["checkpoint"] == str(folder / "model_2.pt")
    assert json.loads((folder / "eval_model_1.json").read_text()) == earlier  # the earlier result stays
    # nothing half-written or private is left beside them
    assert sorted(p.name for p in folder.iterdir()) == [
        "eval.json", "eval_model_1.json", "exported", "exported_model_1", "model_1.pt", "model_2.pt"]
    assert sorted(p.name for p in (folder / "exported").iterdir()) == [
        "model.mjb", "policy.json", "policy.onnx", "policy.pt"]


# ------------------------------------------------------------------------------------------ 7. viewer fallback
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="display detection is the Linux path")
def test_headless_false_without_display_says_so_once_and_trains(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    runs = tmp_path / "runs"
    args = ["task=Cartpole", "num_envs=8", "sim_device=cpu", "rl_device=cpu", "headless=False",
            f"runs_dir={runs}"]
    summary = run(compose_config([*args, "max_iterations=1"]))
    out = capsys.readouterr().out
    assert out.count("no display") == 1, out
    run_dir = Path(summary["run_dir"])
    on_disk = json.loads((run_dir / "summary.json").read_text())
    assert on_disk["iterations"] == 1 and (run_dir / "model_1.pt").is_file()

    # test mode (which the README says opens the viewer) falls back the same way
    result = run(compose_config([*args, "test=True", f"checkpoint={run_dir / 'model_1.pt'}"]))
    out = capsys.readouterr().out
    assert out.count("no display") == 1, out
    assert result["episodes"] == 8 and (run_dir / "eval.json").is_file()
