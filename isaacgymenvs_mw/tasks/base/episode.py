"""The episodes of every env and their clock, owned by VecTask (``VecTask.episode``).

VecTask shows the buffers under IsaacGymEnvs' names (``progress_buf``, ``reset_buf``, ``timeout_buf``, ``rew_buf``,
...; ``EpisodeBuffer``): each name reads the episode's tensor, so that a task's hooks and a captured step see one
state. The time limit has one formula (``timed_out``); a blown-up world (NaN/inf, or a speed past
``DIVERGED_SPEED``) is put back in the model's initial pose, its step counted as a termination that earns nothing
(``after_physics``).
"""

from __future__ import annotations

from typing import Any, Callable

import torch

from isaacgymenvs_mw.sim.blowup import BlowupLog


class EpisodeBuffer:
    """A task's IsaacGymEnvs name for one of its ``episode``'s buffers (a class attribute of VecTask). An assignment
    writes into the buffer: ``self.rew_buf += r`` rebinds the name in Python, and torch.compile's replay of such a
    rebinding stores the graph's output, a new tensor, which a second name for the buffer would not see."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, task: Any, owner: type | None = None) -> Any:
        return self if task is None else getattr(task.episode, self.name)

    def __set__(self, task: Any, value: torch.Tensor) -> None:
        buffer = getattr(task.episode, self.name)
        if value is not buffer:
            buffer.copy_(value)


class Episode:
    """Per-env episode state on ``device``: reward, resets, time-outs, terminations, successes, the step counter and
    the worlds whose state or inputs were not finite. ``max_episode_length``: policy steps of the time limit."""

    def __init__(self, num_envs: int, device: str, max_episode_length: int, blowups: BlowupLog,
                 shared_sequence: bool = True) -> None:
        n, dev = num_envs, device
        # The run's env steps per env so far, a () float32 device tensor: randomisation schedules and the penalty
        # curriculum read it (Randomizer.follow_clock), and a resumed run or test mode sets it from the checkpoint
        # (VecTask.set_train_info).
        self.run_steps = torch.zeros((), device=dev, dtype=torch.float32)
        self.max_episode_length = max_episode_length
        # The task runs VecTask's after-physics sequence (terminations, time-outs, reward, resets), which sets
        # timeout_buf (close_step); a ported IsaacGymEnvs task may replace it with a post_physics_step of its own.
        self.shared_sequence = shared_sequence
        self.blowups = blowups  # which joint ran away: named by VecTask's periodic check
        self.rew_buf = torch.zeros(n, device=dev, dtype=torch.float)
        self.reset_buf = torch.ones(n, device=dev, dtype=torch.long)
        self.timeout_buf = torch.zeros(n, device=dev, dtype=torch.long)
        self.progress_buf = torch.zeros(n, device=dev, dtype=torch.long)
        self.terminate_buf = torch.zeros(n, device=dev, dtype=torch.bool)  # failed this step, blown-up included
        self.success_buf = torch.zeros(n, device=dev, dtype=torch.bool)  # reached the goal this step
        self.nonfinite_buf = torch.zeros(n, device=dev, dtype=torch.bool)
        self.nonfinite_inputs_buf = torch.zeros(n, device=dev, dtype=torch.bool)  # NaN/inf in its obs or reward
        # Summed over steps. Shape (1,), not (): torch.compile reads a 0-dim CPU tensor as a Python number, turns
        # it into a symbolic float and then restarts its analysis of the step to specialise it (1-2 s of every
        # CPU start-up).
        self.nonfinite_inputs_count = torch.zeros(1, device=dev, dtype=torch.float64)

    def count_step(self) -> None:
        """One more env step of the run (in place: the schedules and the reward curriculum hold this tensor, and a
        compiled ``+=`` would rebind it)."""
        self.run_steps.add_(1.0)

    def mask(self, env_ids: torch.Tensor) -> torch.Tensor:
        """A boolean (num_envs,) mask from a mask or an index tensor (IsaacGymEnvs passes indices)."""
        if env_ids.dtype == torch.bool:
            return env_ids
        mask = torch.zeros_like(self.nonfinite_buf)
        mask[env_ids.to(mask.device, torch.long)] = True
        return mask

    def timed_out(self, episode_step: torch.Tensor) -> torch.Tensor:
        """(num_envs,) bool: episodes at their time limit after ``episode_step`` steps (the one formula of it)."""
        return episode_step >= self.max_episode_length - 1

    def close_step(self, check_termination: Callable[[], torch.Tensor],
                   check_success: Callable[[], torch.Tensor]) -> None:
        """Which episodes end in this step, and how: the task's terminations (``check_termination``) and blown-up
        worlds, its successes (``check_success``), and the time-outs (a blown-up world's is none). The clock read is
        the task's ``progress_buf``, which a task may move (AllegroHand does)."""
        # Blown-up worlds are terminations: the task's reset_idx places them and closes their episodes.
        self.terminate_buf.copy_(check_termination() | self.nonfinite_buf)
        self.success_buf.copy_(check_success() & ~self.terminate_buf)
        timeout = self.timed_out(self.progress_buf)
        self.timeout_buf.copy_(timeout & ~self.nonfinite_buf)
        self.reset_buf.copy_(self.terminate_buf | self.success_buf | timeout)

    def restart(self, mask: torch.Tensor) -> None:
        """The envs of ``mask`` start a new episode: the clock is VecTask's, a task's ``reset_idx`` only places."""
        self.progress_buf.masked_fill_(mask, 0)

    def after_physics(self, post_physics_step: Callable[[], None]) -> None:
        """Run ``post_physics_step`` around the blow-up handling. With the shared sequence it sets the time-outs by
        the task's clock (``close_step``); a ported IsaacGymEnvs ``post_physics_step`` resets envs itself, and their
        step count is taken from before it ran."""
        # A world whose state blew up (NaN/inf) goes back to the model's initial state before the task reads it;
        # its episode restarts and the step is reported as a termination, so training goes on.
        blown_up = self.blowups.reset_nonfinite()
        self.progress_buf.masked_fill_(blown_up, 0)
        # Tasks read it while computing rewards: quantities the physics derives from the state (body positions and
        # velocities) are still non-finite in those worlds until the next physics step.
        self.nonfinite_buf.copy_(blown_up)

        # post_physics_step adds one to progress_buf and may reset envs (which zeroes it); the step count at
        # which an episode ended is therefore taken before, so timeouts survive an in-step reset.
        episode_step = self.progress_buf + 1
        post_physics_step()
        # The blown-up step earns nothing and its env starts the next step at progress 0, like any reset env.
        self.rew_buf.masked_fill_(blown_up, 0.0)
        self.progress_buf.masked_fill_(blown_up, 0)
        self.reset_buf.bitwise_or_(blown_up)
        if self.shared_sequence:
            self.timeout_buf.bitwise_and_((self.reset_buf != 0) & ~blown_up)
        else:
            self.timeout_buf.copy_(self.timed_out(episode_step) & (self.reset_buf != 0) & ~blown_up)

    def guard_inputs(self, finish_observations: Callable[[torch.Tensor], torch.Tensor]) -> None:
        """The learner's last line of defence: a NaN or inf that escaped the blow-up reset (a term dividing by a zero
        distance, a quantity the reset does not refresh) would make one sample's loss NaN and, through one Adam step,
        every weight. Such rewards become 0 here and such observations in ``finish_observations`` (which gets the
        envs reset in this step and returns the envs it cleaned); their worlds are counted."""
        bad = ~torch.isfinite(self.rew_buf)
        torch.nan_to_num(self.rew_buf, nan=0.0, posinf=0.0, neginf=0.0, out=self.rew_buf)
        bad |= finish_observations(self.reset_buf != 0)
        self.nonfinite_inputs_buf.copy_(bad)
        self.nonfinite_inputs_count.add_(bad.sum())

    def step_extras(self, rl_device: str) -> dict[str, torch.Tensor]:
        """What a step reports of the episodes beside the reward and resets (IsaacGymEnvs' ``extras``)."""
        # The learner bootstraps the value of the episodes in "time_outs": time-outs and successes.
        return {"time_outs": (self.timeout_buf | self.success_buf).to(rl_device),
                "successes": self.success_buf.to(rl_device),
                "nonfinite_resets": self.nonfinite_buf,
                "nonfinite_inputs": self.nonfinite_inputs_buf}
