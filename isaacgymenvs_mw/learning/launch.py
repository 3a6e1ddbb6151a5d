"""What ``python train.py ...`` does: build the task from the composed config, then train or evaluate."""

from __future__ import annotations

import datetime
import json
import os
import signal
import time
from pathlib import Path
from omegaconf import DictConfig, OmegaConf

from isaacgymenvs_mw.learning.best_checkpoint import BestCheckpoint
from isaacgymenvs_mw.learning.evaluation import evaluate
from isaacgymenvs_mw.learning.export import export_policy
from isaacgymenvs_mw.learning.reporting import device_description, package_versions, write_json
from isaacgymenvs_mw.learning.ige_amp import use_ige_amp_recipe
from isaacgymenvs_mw.learning.learners import Learner, check_resume_total, learner_for, read_checkpoint
from isaacgymenvs_mw.learning.sweep import evaluation_outputs
from isaacgymenvs_mw.learning.train_config import recipe_reward_scale
from isaacgymenvs_mw.learning.training_run import TrainingRun, episode_metrics
from isaacgymenvs_mw.learning.vecenv import success_metric_key, training_metric_keys
from isaacgymenvs_mw.tasks.build import build_task
from isaacgymenvs_mw.learning.checkpoints import check_runs_dir
from isaacgymenvs_mw.utils.config import check_run_config, time_budget, to_dict
from isaacgymenvs_mw.utils.device import resolve_device
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.files import atomic_save
from isaacgymenvs_mw.utils.seeding import set_seed
from isaacgymenvs_mw.utils.stop import PROCESS_STOP


def run(cfg: DictConfig, started_at: float | None = None) -> dict:
    """Train (default) or evaluate (test=True); returns what was written to summary.json / eval.json."""
    started_at = time.perf_counter() if started_at is None else started_at
    check_run_config(cfg)
    use_ige_amp_recipe(cfg)  # IsaacGymEnvs' AMP YAML -> its rsl-rl-lib recipe (learning/ige_amp.py)
    rank = int(os.getenv("RANK", "0"))
    seed = seed_run(cfg, rank)
    if int(cfg.seed) == -1:  # drawn: told, and recorded in the run's config.yaml, so that the run can be repeated
        cfg.seed = seed - rank  # the base seed; seed_run adds the rank
        if rank == 0:
            print(f"[train] seed=-1 drew seed {cfg.seed} (give seed={cfg.seed} to repeat this run)", flush=True)
    learner = learner_for(cfg)
    learner.check()
    checkpoint, saved = read_checkpoint(cfg, learner)
    if not cfg.test and rank == 0:
        check_runs_dir(cfg.runs_dir)
    if not cfg.test and saved is not None:
        check_resume_total(learner.max_iterations(), learner.saved_iteration(saved), cfg.checkpoint)

    task = build_with_notice(cfg)
    make_runner, experiment = learner.runner_factory(task)
    check_experiment_name(experiment)
    if cfg.test:
        return evaluate_checkpoint(cfg, task, make_runner(), checkpoint, saved, rank == 0)
    return train(cfg, task, learner, make_runner(), (checkpoint, saved), experiment, seed, started_at)


def evaluate_checkpoint(cfg: DictConfig, task, runner: TrainingRun, checkpoint: Path, saved: dict,
                        is_main: bool) -> dict:
    """Test mode: load the checkpoint, export its policy beside it, run each env for one episode, write eval.json."""
    eval_path, exported, videos_dir = evaluation_outputs(checkpoint)
    if cfg.get("capture_video", False) and is_main:
        _attach_video_recorder(cfg, task, videos_dir)
    runner.load_checkpoint(checkpoint, task, saved)
    policy = runner.get_inference_policy(device=task.rl_device)
    onnx_path, jit_path = export_policy(runner, exported, task=task)
    print(f"[eval] policy exported to {onnx_path} and {jit_path}", flush=True)
    # a learner feature's own test-mode measure (AMP: the discriminator's scores, learning/amp.py)
    scores = getattr(getattr(runner, "env", None), "test_mode_scores", None)
    observers = [scores()] if callable(scores) else []
    result = evaluate(task, policy, task.rl_device, recipe_reward_scale(to_dict(cfg.train)), observers)
    result.update(test_actions=runner.test_actions, task=cfg.task_name, checkpoint=str(checkpoint),
                  num_envs=task.num_envs, device=device_description(task.sim_device), versions=package_versions())
    write_json(eval_path, result)
    print(f"[eval] {json.dumps({k: v for k, v in result.items() if k != 'versions'})}", flush=True)
    print(f"[eval] written to {eval_path}", flush=True)
    task.close()
    runner.leave_process_group()
    return result


def train(cfg: DictConfig, task, learner: Learner, runner: TrainingRun, resume: tuple[Path | None, dict | None],
          experiment: str, seed: int, started_at: float) -> dict:
    """Train ``runner`` (from ``resume``'s checkpoint when given) to the learner's iterations or the time budget, with
    its run folder, checkpoints and summary.json, whatever ends it."""
    max_iterations = learner.max_iterations()
    checkpoint, saved = resume
    if checkpoint is not None:
        runner.load_checkpoint(checkpoint, task, saved)
        print(f"[train] resuming from {checkpoint} at iteration {runner.current_learning_iteration} and "
              f"{runner.total_env_steps:,} env steps: training to iteration {max_iterations} (max_iterations counts "
              "the total, as in IsaacGymEnvs)", flush=True)
    run_dir = Path(cfg.runs_dir) / experiment / datetime.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    is_main = int(os.getenv("RANK", "0")) == 0
    if is_main:
        run_dir = _open_run_dir(cfg, task, runner, run_dir, experiment)
    start = runner.current_learning_iteration, runner.total_env_steps
    interrupted: KeyboardInterrupt | None = None
    # From here on a signal only asks the run to stop, and the summary is always written: a signal that comes while
    # it is written is recorded, not raised.
    budget = time_budget(cfg.get("max_train_time_s", ""))
    with PROCESS_STOP.training(runner):
        print(f"[train] {cfg.task_name}: {task.num_envs} envs on {device_description(task.sim_device)}, "
              f"{max_iterations} iterations{f' or {budget:g} s of training' if budget else ''}, run dir {run_dir}",
              flush=True)
        try:  # max_iterations is the total: a resumed run trains the rest
            runner.learn(max_iterations - start[0], init_at_random_ep_len=learner.random_start(),
                         max_train_time_s=budget)
        except KeyboardInterrupt as err:  # SIGINT or SIGTERM (StopRequested): learn() has saved the model
            interrupted = err
        summary = _summary(cfg, task, runner, seed, start, started_at, run_dir, interrupted)
        if is_main:
            _report_end(summary, runner, run_dir, interrupted)
        task.close()
        runner.leave_process_group()
    if interrupted is not None:
        interrupted.reported = True  # train.py only sets the exit status
        raise interrupted  # train.py turns it into exit status 128 + signal number
    return summary


def _open_run_dir(cfg: DictConfig, task, runner: TrainingRun, run_dir: Path, experiment: str) -> Path:
    """Make the run folder with the run's config.yaml, and point the runner's logs, best checkpoint and videos at
    it (the main process only)."""
    run_dir = _new_run_dir(run_dir)
    atomic_save(run_dir / "config.yaml", lambda partial: OmegaConf.save(cfg, partial, resolve=True))
    runner.log_dir = str(run_dir)
    runner.experiment, runner.run_config = experiment, to_dict(cfg)  # W&B's project default and run config
    if cfg.get("save_best", False):
        runner.best = BestCheckpoint(run_dir, str(cfg.get("sweep_metric", "auto")), success_metric_key(task))
    if cfg.get("capture_video", False):
        _attach_video_recorder(cfg, task, run_dir / "videos")
    return run_dir


def check_experiment_name(experiment: str) -> None:
    """The run folder is ``runs_dir/<experiment>/<stamp>``: a name that leaves ``runs_dir`` (an absolute path, a
    ``..``) would write it elsewhere, so it is refused."""
    parts = Path(experiment).parts
    if Path(experiment).is_absolute() or ".." in parts or not parts:
        raise ConfigError(f"experiment={experiment!r} is invalid: give a name, or a relative folder path without "
                          "'..', under runs_dir (runs_dir= picks where runs go)")


def _summary(cfg: DictConfig, task, runner: TrainingRun, seed: int, start: tuple[int, int], started_at: float,
             run_dir: Path, interrupted: KeyboardInterrupt | None) -> dict:
    """What summary.json holds: the run's final metrics, throughput, learner health, device and versions. ``start``:
    the iteration and env steps it began at (a checkpoint's, when resumed; its env steps count on from there)."""
    start_it, start_steps = start
    wall = time.perf_counter() - started_at
    means = runner.recent_means()
    return {
        "task": cfg.task_name,
        "num_envs": task.num_envs,
        "world_size": runner.gpu_world_size,
        "seed": seed,
        "iterations": runner.current_learning_iteration - start_it,
        "final_iteration": runner.current_learning_iteration,
        "env_steps": runner.total_env_steps,
        "wall_time_s": wall,
        "train_time_s": runner.train_time,
        "env_steps_per_s": (runner.total_env_steps - start_steps) / max(runner.train_time, 1e-9),
        "mean_episode_reward": means.get("mean_episode_reward"),
        "mean_episode_length": means.get("mean_episode_length"),
        "timeout_fraction": means.get("timeout_fraction"),
        **episode_metrics(means),  # what the task declares, by name (terrain_level on the terrain tasks)
        "metrics": training_metric_keys(task),  # their history keys, in the task's order
        "success_metric": success_metric_key(task),  # the history key of its declared success (sweep_metric=auto)
        "nonfinite_resets": runner.nonfinite_resets,
        **runner.learner_health(),  # optimiser steps skipped, states restored
        "noise_collapse": runner.noise_collapse,  # the first action whose noise collapsed with the rate at its floor
        "device": device_description(task.sim_device),
        "versions": package_versions(),
        "run_dir": str(run_dir),
        "time_budget_reached": runner.time_budget_reached,  # ended at max_train_time_s
        "interrupted": interrupted is not None,
        "signal": None if interrupted is None else signal.Signals(_signal_number(interrupted)).name,
        "interrupted_checkpoint": runner.interrupted_checkpoint,
        "best_checkpoint": None if runner.best is None else runner.best.summary(),  # save_best
        "history": runner.history,
    }


def _report_end(summary: dict, runner: TrainingRun, run_dir: Path, interrupted: KeyboardInterrupt | None) -> None:
    write_json(run_dir / "summary.json", summary)
    ended = f"stopped by {summary['signal']} after" if interrupted is not None else "done in"
    if summary["mean_episode_length"] is None:  # e.g. a resumed run that ended before any episode did
        episodes = "no episode ended in this run"
    else:
        episodes = (f"mean_episode_length={summary['mean_episode_length']}, "
                    f"mean_episode_reward={summary['mean_episode_reward']}")
    print(f"[train] {ended} {summary['wall_time_s']:.1f}s: {episodes}; summary {run_dir / 'summary.json'}", flush=True)
    if runner.best is not None and runner.best.never_moved():
        print(runner.best.never_moved(), flush=True)
    if interrupted is None:
        return
    if runner.interrupted_checkpoint is not None:
        print(f"[train] what it learned is in {runner.interrupted_checkpoint}", flush=True)
    elif summary["iterations"] == 0:
        print("[train] no checkpoint exists yet: the first is written when an iteration ends", flush=True)


# Worlds on the CPU device above which building and the first iteration take long enough to deserve a word.
_MANY_CPU_WORLDS = 8192


def build_with_notice(cfg: DictConfig):
    """build_task, telling the user when it will be slow (many worlds on the CPU) and what it took when it was."""
    # task.env.numEnvs already holds the run's num_envs where one is given (the task YAML's resolve_default); a bad
    # value is left to build_task, whose check names it.
    num_envs = OmegaConf.select(cfg, "task.env.numEnvs", default=0, throw_on_resolution_failure=False)
    on_cpu = resolve_device(cfg.sim_device, "sim_device") == "cpu" and not cfg.get("multi_gpu", False)
    if on_cpu and isinstance(num_envs, int) and num_envs >= _MANY_CPU_WORLDS:
        print(f"[train] {num_envs} worlds on the CPU: building them and the first iteration take minutes (Cartpole "
              "steps about 75 k env-steps/s on 2 cores); a GPU runs them far faster", flush=True)
    rss_before, t0 = _resident_bytes(), time.perf_counter()
    task = build_task(cfg)
    took = time.perf_counter() - t0
    if took > 10.0:
        grown = (_resident_bytes() - rss_before) / 2**30
        print(f"[train] built {task.num_envs} worlds in {took:.0f} s; the process grew by {grown:.1f} GiB of host "
              "memory", flush=True)
    return task


def _resident_bytes() -> int:
    """This process's resident memory (Linux; 0 elsewhere, where the build report then shows no growth)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def seed_run(cfg: DictConfig, rank: int = 0) -> int:
    """Seed the run; ``deterministic=True`` implies ``torch_deterministic`` (bit-identical training needs both)."""
    deterministic = bool(cfg.get("deterministic", False))
    return set_seed(int(cfg.seed), bool(cfg.torch_deterministic) or deterministic, rank=rank)


def _signal_number(err: KeyboardInterrupt) -> int:
    return int(getattr(err, "signum", signal.SIGINT))


def _attach_video_recorder(cfg: DictConfig, task, out_dir: Path) -> None:
    """capture_video=True: film env 0 in real time, capture_video_len env steps every capture_video_freq."""
    # deferred: only recording needs GL
    from isaacgymenvs_mw.sim.video import VIEW_KEY, GLBackendError, VideoRecorder, camera_view

    every, length = int(cfg.get("capture_video_freq", 1464)), int(cfg.get("capture_video_len", 100))
    # A task that observes camera images: what the policy sees (env 0's latest frame) beside the view.
    observations = task.observations
    beside = None if observations.images is None else (
        lambda: observations.camera_picture(task.control_steps).cpu().numpy())
    try:
        recorder = VideoRecorder(task.sim, out_dir, fps=1.0 / task.control_dt, every=every, length=length,
                                 beside=beside, view=camera_view(task.cfg["env"].get(VIEW_KEY.rsplit(".", 1)[1])))
    except GLBackendError as err:  # only the video is lost: the run goes on, as the README promises
        print(f"[video] no video: {err}; the run goes on without it", flush=True)
        return
    task.display.record(recorder)
    print(f"[video] env 0: {length} steps every {every} env steps -> {out_dir}/video_<step>.mp4", flush=True)


def _new_run_dir(path: Path) -> Path:
    """Create the run directory; runs started in the same second get _1, _2, ... instead of sharing one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    candidate, n = path, 0
    while True:
        try:
            candidate.mkdir()
            return candidate
        except FileExistsError:
            n += 1
            candidate = path.with_name(f"{path.name}_{n}")
