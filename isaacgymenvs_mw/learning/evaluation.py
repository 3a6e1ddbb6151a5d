"""Test mode's evaluation (``train.py test=True``): every env runs one episode with the deterministic policy, and
eval.json gets the per-episode means, the task's test-mode metrics and its per-group results."""

from __future__ import annotations

from typing import Protocol, Sequence

import torch

from isaacgymenvs_mw.learning.training_run import keep_stop_handler
from isaacgymenvs_mw.learning.vecenv import RslRlVecEnv
from isaacgymenvs_mw.tasks.base.metrics import OUTCOME, PER_STEP


class StepObserver(Protocol):
    """What a learner feature measures in test mode beside the task (AMP's discriminator scores, learning/amp.py):
    ``observe`` after each step, with the envs still in their first episode; ``result`` for eval.json."""

    def observe(self, active: torch.Tensor) -> None: ...

    def result(self) -> dict[str, float]: ...


def evaluate(task, policy, device: str, reward_scale: float = 1.0, observers: Sequence[StepObserver] = ()) -> dict:
    """Run every env for one full episode with the deterministic policy; report per-episode means (the reward
    times the recipe's ``reward_scale``, as training reports it), and what each of ``observers`` reports.

    Each env contributes its first episode, so the result is an unbiased sample of ``num_envs`` episodes from
    the task's reset distribution (commands too, for the legged tasks).
    """
    task.metrics.evaluate()  # the task records its per-step metrics (tasks/base/metrics.py), if it declares any
    env = RslRlVecEnv(task, reward_scale)
    n = env.num_envs
    ret = torch.zeros(n, device=env.device)
    length = torch.zeros(n, device=env.device)
    finished = torch.zeros(n, dtype=torch.bool, device=env.device)
    result_ret = torch.zeros(n, device=env.device)
    result_len = torch.zeros(n, device=env.device)
    result_timeout = torch.zeros(n, dtype=torch.bool, device=env.device)
    metric_sums: dict[str, torch.Tensor] = {}
    outcomes: dict[str, torch.Tensor] = {}  # per env, how its first episode ended (e.g. success 1 / 0)
    # Results per group the task declares (the terrain tasks: each env's level during its first episode; levels
    # change only at resets), as the task defines them at the start.
    groups = {name: value.clone() for name, value in task.evaluation_groups().items()}
    obs = env.get_observations()
    max_steps = task.longest_episode() + 2
    reset_policy = getattr(policy, "reset", None)  # a recurrent policy: its state starts afresh with each episode
    with torch.inference_mode():
        for step in range(max_steps):
            actions = policy(obs.to(device))
            obs, rew, dones, extras = env.step(actions.to(env.device))
            if reset_policy is not None:
                reset_policy(dones)
            if step == 0:  # the first step compiles (torch, Triton): check after it
                keep_stop_handler()
            active = ~finished
            ret += rew * active
            length += active.float()
            for key, value in task.metrics.recorded(PER_STEP).items():
                # per-env per-step values, averaged over the steps each env spent in its first episode
                metric_sums[key] = metric_sums.get(key, torch.zeros(n, device=env.device)) + value * active
            just_done = active & (dones != 0)
            result_ret = torch.where(just_done, ret, result_ret)
            result_len = torch.where(just_done, length, result_len)
            timed_out = extras["time_outs"] != 0
            if "successes" in extras:  # bootstrapped like time-outs for learning, but not time-outs
                timed_out &= ~extras["successes"]
            result_timeout |= just_done & timed_out
            for key, value in task.metrics.recorded(OUTCOME).items():
                # per-env values of the episodes that ended in this step (a task's success flag)
                outcomes[key] = torch.where(just_done, value, outcomes.get(key, torch.zeros(n, device=env.device)))
            for observer in observers:
                observer.observe(active)
            finished |= just_done
            if step % 50 == 0 and bool(finished.all()):
                break
    if not bool(finished.all()):
        # Envs still running at the cap count with what they reached.
        result_ret = torch.where(finished, result_ret, ret)
        result_len = torch.where(finished, result_len, length)
    out = {
        "episodes": n,
        "mean_episode_reward": float(result_ret.mean()),
        "mean_episode_length": float(result_len.mean()),
        "timeout_fraction": float(result_timeout.float().mean()),
    }
    for key, value in metric_sums.items():
        out[key] = float((value / length.clamp(min=1)).mean())
    for key, value in outcomes.items():  # an episode still running at the cap counts 0
        out[key] = float(value.mean())
    for observer in observers:
        out.update(observer.result())
    for name, labels in groups.items():
        out[f"per_{name}"] = {}
        for label in sorted(set(labels.tolist())):
            sel = labels == label
            row = {"episodes": int(sel.sum()), "survival": float(result_timeout[sel].float().mean()),
                   "mean_episode_length": float(result_len[sel].mean())}
            row.update({k: float((v / length.clamp(min=1))[sel].mean()) for k, v in metric_sums.items()})
            out[f"per_{name}"][str(label)] = row
    return out
