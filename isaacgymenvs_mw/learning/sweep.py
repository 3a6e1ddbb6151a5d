"""``python train.py -m task=X seed=1,2,3,4``: a sweep of runs, side by side on the GPUs, and what they add up to.

A learning result holds when it holds across seeds, so a sweep is how a task's success is measured here. Hydra's
override grammar expands the command line into jobs (comma lists, ``range(1,5)``, ``choice(...)``: the cartesian
product, in Hydra's order). Each job is one ``train.py`` process with the job's overrides:

* on a machine with several GPUs (and a CUDA ``sim_device``), as many jobs run at once as there are GPUs, one per GPU
  (``CUDA_VISIBLE_DEVICES``); otherwise one after another, each printing its progress as a single run does;
* everything is written under ``<runs_dir>/sweeps/<task>_<stamp>/``: ``job<k>/`` is the job's runs_dir and
  ``job<k>.log`` its output (no ``multirun/`` folder in the working directory);
* with ``sweep_eval=True`` each job's last checkpoint is evaluated in test mode on the job's GPU when its training
  ends (``train.py test=True``: eval.json beside the checkpoint, output appended to the job's log), then its best
  checkpoint when save_best kept one (eval_best.json);
* when the jobs are done, ``sweep.json`` and ``sweep.md`` hold one row per job (final, best and final/best of the
  sweep metric, its test-mode values for the last and the best checkpoint, iterations, training time and rate) and
  ``sweep.png`` the metric against training time, one line per job.

The metric (run key ``sweep_metric``; ``auto``: the task's declared success metric, such as ``success``,
``consecutive_successes``, ``reached_target`` or ``terrain_level``, else ``mean_episode_reward``; the rule is
save_best's, learning/best_checkpoint.py) is read from each run's summary.json history, smoothed over ``SMOOTHING``
iterations that finished episodes: "final" is the smoothed value at the end, "best" the largest smoothed value, so
that final/best <= 1 says how much of its best a run kept.

SIGTERM or SIGINT to the sweep reaches every running job (each stops with its checkpoint and summary as a single
run does), starts no new one, writes the aggregate of what exists and exits with the signal's status.
"""

from __future__ import annotations

import datetime
import itertools
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from isaacgymenvs_mw.learning.best_checkpoint import (BEST_CHECKPOINT, METRIC_PREFIX, SMOOTHING, chosen_by,
                                                      metric_key, smoothed)
from isaacgymenvs_mw.learning.checkpoints import checkpoint_iteration, latest_checkpoint
from isaacgymenvs_mw.utils.errors import ConfigError


def evaluation_outputs(checkpoint: Path) -> tuple[Path, Path, Path]:
    """Where test mode writes beside ``checkpoint``: its eval JSON, its exported/ folder and its videos folder.

    The run's last checkpoint (none of a later iteration beside it), or one of another name, writes eval.json,
    exported/ and videos_eval/; the best (save_best) eval_best.json, exported_best/ and videos_eval_best/; an earlier
    checkpoint its own, e.g. eval_model_100.json, exported_model_100/ and videos_eval_model_100/. So evaluating several
    checkpoints of one run, one after another or side by side, keeps each one's results and never mixes two policies.
    """
    folder = checkpoint.parent
    iteration, latest = checkpoint_iteration(checkpoint.name), latest_checkpoint(folder.glob("model_*.pt"))
    later = iteration is not None and latest is not None and checkpoint_iteration(latest.name) > iteration
    suffix = "_best" if checkpoint.name == BEST_CHECKPOINT else f"_{checkpoint.stem}" if later else ""
    return folder / f"eval{suffix}.json", folder / f"exported{suffix}", folder / f"videos_eval{suffix}"


def expand(overrides: list[str]) -> tuple[list[list[str]], list[list[str]]]:
    """Hydra's basic sweep: the jobs (each a full override list) and, per job, the overrides that vary (labels)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    choices, varies = [], []
    for override in OverridesParser.create().parse_overrides(overrides):
        if override.is_sweep_override():
            if not override.is_discrete_sweep():
                raise ConfigError(f"{override.input_line}: an interval sweep needs a sweeper that samples it; give a "
                                  "list (a,b,c), range(a,b) or choice(a,b)")
            key = override.get_key_element()
            choices.append([f"{key}={value}" for value in override.sweep_string_iterator()])
            varies.append(True)
        else:
            choices.append([override.input_line])
            varies.append(False)
    jobs = [list(job) for job in itertools.product(*choices)]
    labels = [[o for o, sweep in zip(job, varies) if sweep] for job in jobs]
    return jobs, labels


@dataclass
class Job:
    index: int
    overrides: list[str]
    label: str
    runs_dir: Path
    log: Path
    gpu: str | None = None  # its CUDA_VISIBLE_DEVICES entry
    process: subprocess.Popen | None = None
    returncode: int | None = None  # the training's
    echo: bool = False
    evaluating: bool = False  # the process is the test-mode evaluation that follows the training (sweep_eval)
    to_evaluate: list[Path] = field(default_factory=list)  # sweep_eval: its checkpoints still to evaluate
    _reader: threading.Thread | None = field(default=None, repr=False)


def run_sweep(argv: list[str], train_script: Path) -> int:
    """Run the sweep that ``argv`` (train.py's arguments without ``-m``) describes; returns the exit status."""
    config_args, overrides = _split_config_args(argv)
    jobs_overrides, labels = expand(overrides)
    cfg = _compose(jobs_overrides[0], config_args)
    for job in jobs_overrides[1:]:
        _compose(job, config_args)  # a bad value in any job is told now, not after the first jobs have trained
    metric = str(cfg.get("sweep_metric", "auto") or "auto")
    stamp = datetime.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    sweep_dir = Path(cfg.runs_dir).expanduser().resolve() / "sweeps" / f"{cfg.task_name}_{stamp}"
    sweep_dir.mkdir(parents=True, exist_ok=False)
    gpus = _gpus_for(cfg)
    jobs = [Job(k, o, " ".join(label) or f"job{k}", sweep_dir / f"job{k}", sweep_dir / f"job{k}.log")
            for k, (o, label) in enumerate(zip(jobs_overrides, labels))]
    side_by_side = len(gpus) > 1
    evaluate = cfg.get("sweep_eval", False) is True  # check_before_start refused anything but a boolean
    print(f"[sweep] {len(jobs)} job(s) of {cfg.task_name} "
          f"{f'side by side on {len(gpus)} GPUs' if side_by_side else 'one after another'}; {sweep_dir}", flush=True)

    stopped: list[int] = []

    def forward(signum, frame):  # every running job stops with its checkpoint and summary; no new one starts
        if not stopped:
            stopped.append(signum)
            for job in jobs:
                if job.process is not None and job.process.poll() is None:
                    job.process.send_signal(signum)

    previous = {s: signal.signal(s, forward) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        _launch_all(jobs, gpus, config_args, train_script, stopped, echo=not side_by_side, evaluate=evaluate)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    key, rows = aggregate(jobs, sweep_dir, metric)
    print(markdown_table(rows, key), flush=True)
    print(f"[sweep] {sweep_dir / 'sweep.md'}, {sweep_dir / 'sweep.json'}, {sweep_dir / 'sweep.png'}", flush=True)
    if stopped:
        return 128 + stopped[0]
    failed = [job for job in jobs if job.returncode != 0]
    if failed:
        print(f"[sweep] {len(failed)} job(s) failed: " + ", ".join(f"{j.label} (status {j.returncode}, {j.log})"
                                                                   for j in failed), file=sys.stderr, flush=True)
        return 1
    return 0


def _split_config_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """Hydra's own options (--config-dir DIR, --config-name NAME, ...) apart from the overrides."""
    options, overrides, i = [], [], 0
    while i < len(argv):
        arg = argv[i]
        if arg.startswith("-"):
            options.append(arg)
            if "=" not in arg and i + 1 < len(argv) and arg in ("--config-dir", "-cd", "--config-path", "-cp",
                                                                  "--config-name", "-cn"):
                options.append(argv[i + 1])
                i += 1
        else:
            overrides.append(arg)
        i += 1
    return options, overrides


def _compose(overrides: list[str], options: list[str]):
    """The job's config, with what a sweep cannot run refused, then its run-level keys and train YAML checked as
    train.py checks them."""
    from isaacgymenvs_mw.learning.train_config import check_before_start
    from isaacgymenvs_mw.utils.config import compose_config

    config_dir = None
    for i, option in enumerate(options):
        if option in ("--config-dir", "-cd") and i + 1 < len(options):
            config_dir = options[i + 1]
        elif option.startswith("--config-dir="):
            config_dir = option.split("=", 1)[1]
    cfg = compose_config(overrides, config_dir=config_dir)
    if cfg.get("multi_gpu", False):
        raise ConfigError("multi_gpu=True: a sweep runs its jobs one per GPU already; leave multi_gpu out of a sweep")
    if cfg.get("test", False):
        raise ConfigError("test=True: a sweep trains; evaluate each job's checkpoint with train.py test=True")
    check_before_start(cfg)
    return cfg


def _gpus_for(cfg) -> list[str]:
    """The GPUs jobs can run on side by side, as ``CUDA_VISIBLE_DEVICES`` entries: every GPU this process sees when
    the run's devices are CUDA, else none. Under ``CUDA_VISIBLE_DEVICES=2,3`` they are "2" and "3", not the indexes
    0 and 1, which a job's own ``CUDA_VISIBLE_DEVICES`` would read as the host's first two GPUs."""
    devices = {str(cfg.get("sim_device", "auto")), str(cfg.get("rl_device", "auto"))}
    if any(d == "cpu" for d in devices):
        return []
    import torch

    if not torch.cuda.is_available():
        return []
    return visible_gpus(os.environ.get("CUDA_VISIBLE_DEVICES"), torch.cuda.device_count())


def visible_gpus(cuda_visible_devices: str | None, count: int) -> list[str]:
    """The ``count`` GPUs this process sees, named as a child's ``CUDA_VISIBLE_DEVICES`` must name them: the parent's
    own entries (indexes or UUIDs) in order when it has that variable, else the indexes 0 .. count-1."""
    if cuda_visible_devices is None or not cuda_visible_devices.strip():
        return [str(i) for i in range(count)]
    return [entry.strip() for entry in cuda_visible_devices.split(",")][:count]


def _launch_all(jobs: list[Job], gpus: list[str], options: list[str], train_script: Path, stopped: list[int],
                echo: bool, evaluate: bool = False) -> None:
    """Run the jobs, as many at once as there are GPUs (one at a time without); with ``evaluate``, each job's last
    checkpoint, then its best (save_best), is evaluated in test mode on the job's GPU as soon as its training ends."""
    free = list(gpus) if gpus else [None]
    pending, running = list(jobs), []
    while pending or running:
        while pending and free and not stopped:
            job = pending.pop(0)
            job.gpu, job.echo = free.pop(0), echo
            _start(job, options, train_script)
            running.append(job)
        if stopped and not running:
            break
        time.sleep(0.2)
        for job in list(running):
            if job.process.poll() is None:
                continue
            job._reader.join()
            if not job.evaluating:
                job.returncode = job.process.returncode
                print(f"[sweep] job {job.index} ({job.label}) ended with status {job.returncode}", flush=True)
                if evaluate:
                    job.to_evaluate = checkpoints_to_evaluate(job.runs_dir)
            if job.to_evaluate and not stopped:
                _start(job, options, train_script, evaluate=job.to_evaluate.pop(0))
                continue
            running.remove(job)
            free.append(job.gpu)
        if stopped:
            pending.clear()


def checkpoints_to_evaluate(runs_dir: Path) -> list[Path]:
    """A finished job's last checkpoint, then its best one when save_best kept one."""
    last = last_checkpoint(runs_dir)
    if last is None:
        return []
    best = last.parent / BEST_CHECKPOINT
    return [last, best] if best.is_file() else [last]


def last_checkpoint(runs_dir: Path) -> Path | None:
    """The checkpoint of the highest iteration a job's run wrote (its final or interrupted one), or None."""
    return latest_checkpoint(runs_dir.glob("*/*/model_*.pt"))


def _start(job: Job, options: list[str], train_script: Path, evaluate: Path | None = None) -> None:
    """Start the job's training, or (``evaluate``: a checkpoint) its test-mode evaluation, whose output is appended
    to the same log and whose eval.json (eval_best.json) lands beside the checkpoint."""
    env = dict(os.environ)
    if job.gpu is not None:
        env["CUDA_VISIBLE_DEVICES"] = str(job.gpu)
    env["PYTHONUNBUFFERED"] = "1"
    cmd = [sys.executable, str(train_script), *options, *job.overrides, f"runs_dir={job.runs_dir}"]
    where = f" on GPU {job.gpu}" if job.gpu is not None else ""
    if evaluate is None:
        print(f"[sweep] job {job.index} ({job.label}){where}: log {job.log}", flush=True)
    else:
        cmd += ["test=True", f"checkpoint={evaluate}"]
        print(f"[sweep] job {job.index} ({job.label}){where}: test mode on {evaluate.name}", flush=True)
    job.evaluating = evaluate is not None
    job.process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    job._reader = threading.Thread(target=_copy_output, args=(job, "a" if job.evaluating else "w"), daemon=True)
    job._reader.start()


def _copy_output(job: Job, mode: str = "w") -> None:
    with open(job.log, mode) as log:
        for line in job.process.stdout:
            log.write(line)
            log.flush()
            if job.echo:
                sys.stdout.write(line)
                sys.stdout.flush()


# ---------------------------------------------------------------------------------------------------- aggregate
def summarise(summary: dict, key: str) -> dict:
    """One row of the sweep table from a run's summary.json."""
    points = [(float(r["time_s"]), float(r[key])) for r in summary.get("history", []) if r.get(key) is not None]
    row = {"iterations": summary.get("final_iteration"), "train_time_s": summary.get("train_time_s"),
           "env_steps_per_s": summary.get("env_steps_per_s"), "interrupted": summary.get("interrupted"),
           "final": None, "best": None, "final_over_best": None, "best_at_s": None,
           "noise_collapse": summary.get("noise_collapse")}  # where a lane's learning stopped (runner.py)
    if points:
        smooth = smoothed([v for _, v in points])
        best = max(range(len(smooth)), key=smooth.__getitem__)
        row.update(final=smooth[-1], best=smooth[best], best_at_s=points[best][0])
        row["final_over_best"] = smooth[-1] / smooth[best] if smooth[best] > 0 else None
    return row


def _summary_of(job: Job) -> dict | None:
    found = sorted(job.runs_dir.glob("*/*/summary.json"))
    return json.loads(found[-1].read_text()) if found else None


def aggregate(jobs: list[Job], sweep_dir: Path, metric: str) -> tuple[str, list[dict]]:
    """sweep.json, sweep.md and sweep.png from the jobs' summaries; returns the metric's history key and the rows."""
    summaries = [_summary_of(job) for job in jobs]
    histories = [r for s in summaries if s for r in s.get("history", [])]
    success = next((s.get("success_metric") for s in summaries if s), None)
    key = metric_key(histories, metric, success)
    if histories and not any(r.get(key) is not None for r in histories):
        known = sorted({k for r in histories for k in r
                        if k.startswith(METRIC_PREFIX) or k.startswith("mean_") or k == "timeout_fraction"})
        print(f"[sweep] sweep_metric={metric}: no job reported {key}; its runs report {', '.join(known)}",
              file=sys.stderr, flush=True)
    rows = []
    for job, summary in zip(jobs, summaries):
        row = {"job": job.index, "label": job.label, "status": job.returncode, "log": str(job.log)}
        row.update(summarise(summary, key) if summary else {"final": None, "best": None, "final_over_best": None})
        row["test"] = test_result(job, key)
        row["test_best"] = test_result(job, key, best=True)
        rows.append(row)
    (sweep_dir / "sweep.json").write_text(json.dumps({"metric": key, "chosen_by": chosen_by(metric, success),
                                                     "smoothing": SMOOTHING, "jobs": rows},
                                                     indent=2) + "\n")
    (sweep_dir / "sweep.md").write_text(markdown_table(rows, key) + "\n")
    plotted = [(s, job.label) for job, s in zip(jobs, summaries) if s and any(r.get(key) is not None
                                                                             for r in s.get("history", []))]
    if plotted:
        plot_curves([s for s, _ in plotted], [label for _, label in plotted], sweep_dir / "sweep.png", [key])
    return key, rows


def test_result(job: Job, key: str, best: bool = False) -> float | None:
    """The sweep metric in the job's test-mode evaluation of its last checkpoint (eval.json beside it), or of its
    best (``best``: eval_best.json), or None."""
    checkpoint = last_checkpoint(job.runs_dir)
    if checkpoint is None:
        return None
    path = evaluation_outputs(checkpoint.parent / BEST_CHECKPOINT if best else checkpoint)[0]
    if not path.is_file():
        return None
    result = json.loads(path.read_text())
    value = result.get(key[len(METRIC_PREFIX):] if key.startswith(METRIC_PREFIX) else key)
    return float(value) if isinstance(value, (int, float)) else None


def markdown_table(rows: list[dict], key: str) -> str:
    name = key[len(METRIC_PREFIX):] if key.startswith(METRIC_PREFIX) else key

    def fmt(value, spec: str = ".3f") -> str:
        return "-" if value is None else format(value, spec)

    def collapse(c: dict | None) -> str:
        return "-" if not c else f"it {c['iteration']}, {c['actuator'] or 'action ' + str(c['action'])}"

    lines = [f"| job | {name}: final | best | final/best | best at (s) | test mode | test, best checkpoint | "
             "iterations | training (s) | env-steps/s | noise collapsed |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['label']} | {fmt(r.get('final'))} | {fmt(r.get('best'))} | "
                     f"{fmt(r.get('final_over_best'), '.2f')} | {fmt(r.get('best_at_s'), '.0f')} | "
                     f"{fmt(r.get('test'))} | {fmt(r.get('test_best'))} | "
                     f"{r.get('iterations') if r.get('iterations') is not None else '-'} | "
                     f"{fmt(r.get('train_time_s'), '.0f')} | {fmt(r.get('env_steps_per_s'), ',.0f')} | "
                     f"{collapse(r.get('noise_collapse'))} |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------- learning curves
AXIS_LABELS = {"mean_episode_reward": "mean episode reward", "mean_episode_length": "mean episode length (steps)",
               "Episode/terrain_level": "mean terrain level"}


def curve(summary: dict, key: str) -> tuple[list[float], list[float]]:
    """(training time s, value) for every iteration that reported ``key``."""
    xs, ys = [], []
    for record in summary.get("history", []):
        if record.get(key) is not None:
            xs.append(float(record["time_s"]))
            ys.append(float(record[key]))
    return xs, ys


def plot_curves(summaries: list[dict], labels: list[str], out: Path, keys: list[str]) -> None:
    """A PNG with one panel per history key and one line per run, against training time (rollouts + updates)."""
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(keys), 1, figsize=(7, 3.2 * len(keys)), sharex=True, squeeze=False)
    for summary, label in zip(summaries, labels):
        for ax, key in zip(axes[:, 0], keys):
            xs, ys = curve(summary, key)
            ax.plot(xs, ys, label=label, linewidth=1.5)
    for ax, key in zip(axes[:, 0], keys):
        ax.set_ylabel(AXIS_LABELS.get(key, key[len(METRIC_PREFIX):] if key.startswith(METRIC_PREFIX) else key))
    axes[-1, 0].set_xlabel("training time (s): rollouts + updates")
    first = summaries[0]
    startup = float(first.get("wall_time_s", 0.0)) - float(first.get("train_time_s", 0.0))
    title = (f"{first.get('task', '?')}: {first.get('num_envs', '?')} envs on {first.get('device', '?')}\n"
             f"start-up {startup:.0f} s before the first iteration")
    axes[0, 0].set_title(title, fontsize=9)
    for ax in axes[:, 0]:
        ax.grid(True, alpha=0.3)
    if len(summaries) > 1:
        axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
