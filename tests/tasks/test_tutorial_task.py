"""The README tutorial's Pendulum (examples/pendulum_task.py): registration from a user module, physics against
MuJoCo C and the pendulum formula, reward against numpy, and a short training run (CI trains it briefly)."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys

import mujoco
import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from conftest import CPU_ARGS, REPO_ROOT
from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.learning.launch import run
from isaacgymenvs_mw.tasks import get_task_class, isaacgym_task_map
from isaacgymenvs_mw.utils.config import compose_config

if str(REPO_ROOT) not in sys.path:  # `examples` is importable from the repository root, as train.py sees it
    sys.path.insert(0, str(REPO_ROOT))

MODULE = "examples.pendulum_task"
TASK_ARGS = ["task=Pendulum", f"task_module={MODULE}"]

# The pendulum as assets/urdf/pendulum.urdf describes it: a 1 kg ball of radius 5 cm, 1 m from the hinge.
MASS, LENGTH, BALL_RADIUS, G = 1.0, 1.0, 0.05, 9.81
INERTIA = MASS * LENGTH**2 + 0.4 * MASS * BALL_RADIUS**2  # about the hinge


def make_pendulum(num_envs: int, *overrides: str):
    """The task exactly as train.py builds it: Hydra config, then build_task imports task_module and looks it up."""
    if "Pendulum" not in isaacgym_task_map:
        sys.modules.pop(MODULE, None)  # another test dropped the registration: let the import redo it
    return build_task(compose_config([*TASK_ARGS, f"num_envs={num_envs}", *CPU_ARGS, *overrides]))


def set_state(task, angle, velocity) -> None:
    n = task.num_envs
    mask = torch.ones(n, dtype=torch.bool)
    task.sim.write_state(mask, dof_pos=torch.tensor(angle, dtype=torch.float32).reshape(n, 1),
                         dof_vel=torch.tensor(velocity, dtype=torch.float32).reshape(n, 1))
    task.progress_buf.zero_()


def pendulum_reward_reference(angle, velocity, effort, progress, fall_angle, max_len, scales):
    """The tutorial's reward in float64 numpy, written from the README: Σ scale·term, fall when |wrap(θ)| > limit."""
    angle, velocity, effort = (np.asarray(a, np.float64) for a in (angle, velocity, effort))
    wrapped = (angle + math.pi) % (2 * math.pi) - math.pi
    fallen = np.abs(wrapped) > fall_angle
    reward = (scales["upright"] * np.cos(angle) + scales["velocity"] * velocity**2
              + scales["effort"] * effort**2 + scales["fall"] * fallen)
    reset = fallen | (np.asarray(progress) >= max_len - 1)
    return reward, reset, fallen


# ------------------------------------------------------------------------------------------------ registration
def test_task_module_registers_pendulum_on_import():
    saved = dict(isaacgym_task_map)
    try:
        isaacgym_task_map.pop("Pendulum", None)
        sys.modules.pop(MODULE, None)
        task = make_pendulum(3)
        assert type(task).__name__ == "Pendulum" and get_task_class("Pendulum") is type(task)
        assert type(task).__module__ == MODULE  # the class came from the user's module, not the package
        assert task.num_envs == 3 and task.num_obs == 3 and task.num_actions == 1
        assert task.sim.dof_names == ["hinge"] and task.sim.mj_model.nu == 1
        obs = task.reset()["obs"]
        assert obs.shape == (3, 3)
        q, v = task.sim.dof_pos[:, 0], task.sim.dof_vel[:, 0]
        torch.testing.assert_close(obs, torch.stack((torch.cos(q), torch.sin(q), v), dim=-1))
        assert (q.abs() <= task.reset_angle).all() and (v.abs() <= task.reset_velocity).all()
    finally:  # the other tasks as they were; Pendulum as the fresh import registered it
        fresh = isaacgym_task_map.get("Pendulum")
        isaacgym_task_map.clear()
        isaacgym_task_map.update(saved)
        if fresh is not None:
            isaacgym_task_map["Pendulum"] = fresh


def test_without_task_module_the_task_is_unknown():
    saved = dict(isaacgym_task_map)
    try:
        isaacgym_task_map.pop("Pendulum", None)
        with pytest.raises(KeyError, match="Pendulum"):
            build_task(compose_config(["task=Pendulum", "num_envs=2", *CPU_ARGS]))
    finally:
        isaacgym_task_map.clear()
        isaacgym_task_map.update(saved)


# ----------------------------------------------------------------------------------------------------- physics
def test_controlled_steps_match_mujoco_c():
    """task.step (torque = action · maxTorque, controlFrequencyInv physics steps) against mujoco.mj_step."""
    n, steps = 6, 40
    task = make_pendulum(n)
    model = task.sim.mj_model
    substeps, max_torque = task.control_freq_inv, task.max_torque
    assert substeps == 2 and model.nq == 1 and model.nu == 1
    task.reset()
    rng = np.random.default_rng(3)
    q0 = rng.uniform(-0.4, 0.4, n)
    v0 = rng.uniform(-0.5, 0.5, n)
    set_state(task, q0, v0)
    refs = []
    for i in range(n):
        d = mujoco.MjData(model)
        d.qpos[0], d.qvel[0] = q0[i], v0[i]
        refs.append(d)

    worst = 0.0
    for t in range(steps):
        # A PD balancer plus noise, computed from the MuJoCo C state: both keep the poles well inside fallAngle.
        a = np.array([np.clip(-(3.0 * d.qpos[0] + 0.8 * d.qvel[0]) + rng.uniform(-0.3, 0.3), -1, 1)
                      for d in refs], np.float32)
        obs_dict, rew, reset, _ = task.step(torch.from_numpy(a).reshape(n, 1))
        assert not reset.any(), f"an episode ended at step {t}; the comparison assumes none does"
        for i, d in enumerate(refs):
            d.ctrl[0] = float(a[i]) * max_torque
            for _ in range(substeps):
                mujoco.mj_step(model, d)
        q_ref = np.array([d.qpos[0] for d in refs])
        v_ref = np.array([d.qvel[0] for d in refs])
        np.testing.assert_allclose(obs_dict["obs"].numpy(), np.stack([np.cos(q_ref), np.sin(q_ref), v_ref], 1),
                                   atol=1e-4, rtol=0)
        worst = max(worst, np.abs(task.sim.dof_pos[:, 0].numpy() - q_ref).max())
    assert worst < 1e-4, worst
    assert np.abs(a).max() > 0.1  # the motor really pushed


@pytest.mark.parametrize("action", [0.0, 1.0, -0.5])
def test_first_step_acceleration_matches_newton(action):
    """From rest, θ̈ = (m g l sin θ + τ) / I: gravity tips the pole away from upright, the motor adds τ."""
    task = make_pendulum(3)
    task.reset()
    angles = np.array([0.3, -0.2, 0.0])
    set_state(task, angles, np.zeros(3))
    task.step(torch.full((3, 1), action))
    elapsed = task.control_dt
    expected = (MASS * G * LENGTH * np.sin(angles) + action * task.max_torque) / INERTIA * elapsed
    # One control step is 2 physics steps; θ barely moves, so θ̇ ≈ θ̈ · Δt to well under 1 %.
    np.testing.assert_allclose(task.sim.dof_vel[:, 0].numpy(), expected, rtol=1e-2, atol=1e-4)


def test_hanging_small_swing_period_matches_formula():
    """Hanging down (θ = π) and released a little off, the pole swings with T = 2π √(I / (m g l))."""
    task = make_pendulum(1)
    task.reset()
    set_state(task, [math.pi - 0.05], [0.0])
    offsets, crossings = [], []
    for k in range(260):  # ~2.6 periods, sim steps only (the task would count this as a fall)
        task.sim.simulate()
        offsets.append(float(task.sim.dof_pos[0, 0]) - math.pi)
        if k and offsets[-2] < 0.0 <= offsets[-1]:  # upward zero crossing, interpolated
            frac = -offsets[-2] / (offsets[-1] - offsets[-2])
            crossings.append((k - 1 + frac) * task.control_dt)
    assert len(crossings) >= 3, crossings
    period = float(np.mean(np.diff(crossings)))
    assert period == pytest.approx(2 * math.pi * math.sqrt(INERTIA / (MASS * G * LENGTH)), rel=5e-3)
    assert max(abs(o) for o in offsets) == pytest.approx(0.05, rel=0.05)  # no damping: amplitude is kept


# ------------------------------------------------------------------------------------------------------ reward
def test_reward_function_matches_numpy():
    from examples.pendulum_task import compute_pendulum_reward, pendulum_fallen

    cfg = compose_config(TASK_ARGS).task.env
    scales = {k: float(v) for k, v in cfg.rewards.items()}
    assert set(scales) == {"upright", "velocity", "effort", "fall"}
    rng = np.random.default_rng(11)
    n, max_len, fall_angle = 5000, 50, float(cfg.fallAngle)
    angle = rng.uniform(-8, 8, n).astype(np.float32)  # beyond ±π too: the hinge is continuous
    velocity = rng.uniform(-10, 10, n).astype(np.float32)
    effort = rng.uniform(-1, 1, n).astype(np.float32)
    progress = rng.integers(0, max_len + 3, n)
    # The task's fall test and reward, with VecTask's time limit (an episode ends when progress reaches cap - 1).
    fell = pendulum_fallen(torch.from_numpy(angle), fall_angle)
    rew = compute_pendulum_reward(angle=torch.from_numpy(angle), velocity=torch.from_numpy(velocity),
                                  effort=torch.from_numpy(effort), fallen=fell, scales=scales)
    reset = (fell | (torch.from_numpy(progress) >= max_len - 1)).long()
    ref_rew, ref_reset, fallen = pendulum_reward_reference(angle, velocity, effort, progress, fall_angle, max_len,
                                                           scales)
    assert fallen.any() and (~fallen).any() and (ref_reset & ~fallen).any() and (~ref_reset).any()
    assert (np.abs(angle) > math.pi).any() and (np.abs(angle[~fallen]) > math.pi).any()  # wrapped upright poles
    assert rew.dtype == torch.float32 and reset.dtype == torch.long
    np.testing.assert_array_equal(reset.numpy(), ref_reset.astype(np.int64))
    np.testing.assert_allclose(rew.numpy(), ref_rew, rtol=1e-5, atol=1e-4)


def test_step_rewards_falls_and_timeouts():
    """In task.step: the reward of the reached state, a fall resets (not a timeout), the cap is a timeout."""
    task = make_pendulum(4, "task.env.episodeLength_s=0.4")  # 20 policy steps of 0.02 s
    assert task.max_episode_length == 20
    scales = dict(task.reward_scales)
    task.reset()
    set_state(task, [0.1, -0.2, 0.99, 0.0], [0.0, 0.3, 6.0, 0.0])  # env 2 is about to fall
    task.progress_buf[3] = 18  # env 3 reaches the cap on this step
    actions = torch.tensor([[0.5], [-1.0], [0.0], [0.2]])
    _, rew, reset, extras = task.step(actions)
    assert reset.tolist() == [0, 0, 1, 1]
    assert extras["time_outs"].tolist() == [0, 0, 0, 1]
    assert task.progress_buf.tolist() == [1, 1, 0, 0]
    # envs 0 and 1 kept their state: the reward is the reference at that state
    q, v = task.sim.dof_pos[:2, 0].numpy(), task.sim.dof_vel[:2, 0].numpy()
    ref, _, _ = pendulum_reward_reference(q, v, actions[:2, 0].numpy(), [1, 1], task.fall_angle, 20, scales)
    np.testing.assert_allclose(rew[:2].numpy(), ref, rtol=1e-5, atol=1e-5)
    assert rew[2] < scales["fall"] + 1.0  # the fall penalty was paid
    # the reset envs start again near upright
    assert (task.sim.dof_pos[2:, 0].abs() <= task.reset_angle).all()


# ------------------------------------------------------------------------------------------------------ README
def test_readme_tutorial_shows_the_example_files_verbatim():
    """The README's "Write your own task" code is the example's code: together its Python blocks are the whole
    file (after the module docstring), and its URDF and YAML blocks are those files."""
    readme = (REPO_ROOT / "README.md").read_text()
    section = readme.split("\n## Write your own task\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"^```(\w*)\n(.*?)^```", section, re.S | re.M)
    code = (REPO_ROOT / "examples" / "pendulum_task.py").read_text()
    python = [b for lang, b in blocks if lang == "python"]
    assert python and all(b in code for b in python)
    body = code[code.index("from __future__"):]
    shown = [line for b in python for line in b.splitlines() if line.strip()]
    assert shown == [line for line in body.splitlines() if line.strip()]
    files = ["assets/urdf/pendulum.urdf", "cfg/task/Pendulum.yaml", "cfg/train/PendulumPPO.yaml"]
    contents = {(REPO_ROOT / f).read_text().strip(): f for f in files}
    shown_files = [contents.get(b.strip(), "<not a file>") for lang, b in blocks if lang in ("xml", "yaml")]
    assert shown_files == files
    commands = [b for lang, b in blocks if lang == "bash"]
    assert commands[0].strip() == "python train.py task=Pendulum task_module=examples.pendulum_task headless=True"


# ---------------------------------------------------------------------------------------------------- training
def test_short_training_writes_summary_and_checkpoint(tmp_path, run_args):
    n, iters = 16, 2
    cfg = compose_config([*TASK_ARGS, f"num_envs={n}", f"max_iterations={iters}", *run_args])
    summary = run(cfg)
    run_dirs = list((tmp_path / "runs" / "Pendulum").iterdir())
    assert len(run_dirs) == 1
    run_dir = run_dirs[0]
    on_disk = json.loads((run_dir / "summary.json").read_text())
    assert on_disk["task"] == "Pendulum" and on_disk["num_envs"] == n and on_disk["iterations"] == iters
    assert on_disk["env_steps"] == iters * n * cfg.train.runner.num_steps_per_env
    assert math.isfinite(on_disk["mean_episode_reward"])
    assert 1 <= on_disk["mean_episode_length"] <= round(cfg.task.env.episodeLength_s / 0.02) - 1
    assert summary["mean_episode_length"] == on_disk["mean_episode_length"]
    state = torch.load(run_dir / f"model_{iters}.pt", map_location="cpu", weights_only=False)
    first = [v for k, v in state["actor_state_dict"].items() if k.endswith(".weight")][0]
    assert first.shape == (cfg.train.actor.hidden_dims[0], 3)
    assert OmegaConf.load(run_dir / "config.yaml").task_module == MODULE


def test_readme_command_trains_from_another_directory(tmp_path):
    """The README's command, shortened, run from outside the repository: train.py finds examples/ itself."""
    runs = tmp_path / "runs"
    cmd = [sys.executable, str(REPO_ROOT / "train.py"), *TASK_ARGS, "headless=True", "num_envs=8",
           "max_iterations=1", "sim_device=cpu", "rl_device=cpu", f"runs_dir={runs}"]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    (run_dir,) = (runs / "Pendulum").iterdir()
    assert json.loads((run_dir / "summary.json").read_text())["iterations"] == 1
    assert (run_dir / "model_1.pt").is_file()
