"""How a step executes: the compiled post-physics step (sim.compileStep) against the eager one, and the
simulator's state save/load that the throughput benchmark relies on.

The reference for the compiled step is the eager step of a second task in the same state with the same random
streams: torch.compile (Inductor, here generating C++ for the CPU) must change how the step runs, not what it
computes. On the GPU the same graph is generated as Triton kernels (benchmarks/check_step_graph.py checks that).
"""

from __future__ import annotations

import pytest
import torch
import torch._dynamo

import isaacgymenvs_mw

N = 4


def make_go1(overrides=()):
    return isaacgymenvs_mw.make("Go1", num_envs=N, sim_device="cpu", rl_device="cpu", headless=True, seed=0,
                                overrides=list(overrides))


def test_compiled_step_computes_what_the_eager_step_computes_through_resets():
    compiled = make_go1(["+task.sim.compileStep=True"])
    eager = make_go1(["+task.sim.compileStep=False"])
    assert (compiled.step_execution, eager.step_execution) == ("compiled", "eager")
    compiled.reset()
    eager.reset()
    eager.sim.load_state(compiled.sim.save_state())
    eager.commands.copy_(compiled.commands)

    actions = torch.Generator().manual_seed(1)
    saw_timeouts = False
    for i in range(16):
        a = 2.0 * torch.rand(N, compiled.num_actions, generator=actions) - 1.0
        if i == 8:  # two envs reach the episode limit: reset_idx runs with a non-empty mask
            for task in (compiled, eager):
                task.progress_buf[:2] = task.max_episode_length - 2
        outputs = []
        # After the first steps, later ones (resets included) must reuse the compiled graph: a recompilation
        # per step would cost seconds each and, past torch's limit, fall back to eager without a word.
        with torch._dynamo.config.patch(error_on_recompile=i > 2):
            for task in (compiled, eager):
                torch.manual_seed(100 + i)  # the same noise, command and reset draws in both
                obs, rew, done, extras = task.step(a)
                outputs.append((obs["obs"].clone(), obs["states"].clone(), rew.clone(), done.clone(),
                                extras["time_outs"].clone()))
        (o1, s1, r1, d1, t1), (o2, s2, r2, d2, t2) = outputs
        torch.testing.assert_close(o1, o2, atol=1e-5, rtol=1e-5, msg=f"observations differ at step {i}")
        torch.testing.assert_close(s1, s2, atol=1e-5, rtol=1e-5, msg=f"critic states differ at step {i}")
        torch.testing.assert_close(r1, r2, atol=1e-6, rtol=1e-5, msg=f"rewards differ at step {i}")
        assert torch.equal(d1, d2) and torch.equal(t1, t2), f"resets differ at step {i}"
        saw_timeouts |= bool(t1.any())
    assert saw_timeouts


@pytest.mark.parametrize("value", ["yes", 2])
def test_bad_compile_step_value_names_the_key_and_the_choices(value):
    with pytest.raises(ValueError, match=r"sim\.compileStep=.*True, False or auto"):
        make_go1([f"+task.sim.compileStep={value}"])


def test_auto_compiles_only_where_the_step_is_captured():
    # On the CPU nothing is captured, so "auto" keeps the eager step (no compiler start-up cost for CPU runs).
    assert make_go1().step_execution == "eager"


def test_save_and_load_state_replays_the_same_physics():
    task = make_go1()
    task.reset()
    task.sim.ctrl[:] = task.default_dof_pos + 0.2 * (2.0 * torch.rand(N, task.num_actions) - 1.0)
    task.sim.simulate()  # warm start and contacts now carry over
    saved = task.sim.save_state()
    first = []
    for _ in range(3):
        task.sim.simulate()
        first.append(task.sim.qpos.clone())
    assert not torch.equal(first[-1], saved["qpos"])
    task.sim.qvel.add_(1.0)  # anything written after the save is undone by the load
    task.sim.load_state(saved)
    for step in range(3):
        task.sim.simulate()
        assert torch.equal(task.sim.qpos, first[step]), f"physics step {step} after load_state differs"
