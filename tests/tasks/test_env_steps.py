"""``VecTask.env_steps`` (issue 59): the run's env steps over all envs as a device tensor a task reads in the step
(IsaacGymEnvs' frame count), starting where ``set_train_info`` (a checkpoint, resumed or in test mode) puts it. The
resume through a checkpoint is checked end to end in tests/workflow/test_workflow.py."""

from __future__ import annotations

import torch


def test_env_steps_counts_num_envs_per_step_and_starts_from_set_train_info(make_cartpole):
    task = make_cartpole(num_envs=4)
    task.reset()
    assert task.env_steps.dtype == torch.int64 and task.env_steps.device == torch.device(task.device)
    assert int(task.env_steps) == 0
    for _ in range(5):
        task.step(task.zero_actions())
    assert int(task.env_steps) == 5 * 4
    # what Runner.load_checkpoint does with a checkpoint of 3 iterations of 16 steps per env
    task.set_train_info(3 * 16 * 4)
    assert int(task.env_steps) == 192
    task.step(task.zero_actions())
    assert int(task.env_steps) == 196
    assert int(task.env_steps) // task.num_envs == int(task.randomizer.step_count)  # the schedules' own count
