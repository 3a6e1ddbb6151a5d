"""How a step executes: the compiled post-physics step (sim.compileStep) against the eager one, the step compiled
alongside Warp's kernels against the step compiled at its first call, and the simulator's state save/load that the
throughput benchmark relies on.

The reference for the compiled step is the eager step of a second task in the same state with the same random
streams: torch.compile (Inductor, here generating C++ for the CPU) must change how the step runs, not what it
computes. On the GPU the same graph is generated as Triton kernels (benchmarks/diagnostics/check_step_graph.py checks that).
Compiling ahead (during the first reset, while Warp's kernel modules compile on their threads) must change only when
the compilation happens: the same tensors bit for bit, nothing run or drawn by the compilation itself.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import threading

import pytest
import torch
import torch._dynamo
import warp as wp

import isaacgymenvs_mw
from isaacgymenvs_mw.sim import kernels
from isaacgymenvs_mw.tasks.base.metrics import EPISODE_SUM, OUTCOME
from isaacgymenvs_mw.tasks.base.step_execution import _CompiledStep

N = 4


def make_go1(overrides=()):
    return isaacgymenvs_mw.make("Go1", num_envs=N, sim_device="cpu", rl_device="cpu", headless=True, seed=0,
                                overrides=list(overrides))


def go1_twins(overrides_a, overrides_b, compile_ahead_b=True):
    """Two Go1 tasks reset into the same state (worlds and commands)."""
    a, b = make_go1(overrides_a), make_go1(overrides_b)
    b.execution.compile_ahead = compile_ahead_b
    for task in (a, b):
        torch.manual_seed(3)
        task.reset()
    b.sim.load_state(a.sim.save_state())
    b.commands.copy_(a.commands)
    return a, b


def actions_through_resets(tasks, steps=16):
    """(step, random actions) for ``steps`` steps; before step 8 two envs are put one step from the episode limit,
    so that reset_idx runs with a non-empty mask."""
    generator = torch.Generator().manual_seed(1)
    for i in range(steps):
        if i == 8:
            for task in tasks:
                task.progress_buf[:2] = task.max_episode_length - 2
        yield i, 2.0 * torch.rand(N, tasks[0].num_actions, generator=generator) - 1.0


def test_compiled_step_computes_what_the_eager_step_computes_through_resets():
    compiled, eager = go1_twins(["+task.sim.compileStep=True"], ["+task.sim.compileStep=False"])
    assert (compiled.step_execution, eager.step_execution) == ("compiled", "eager")
    saw_timeouts = False
    for i, a in actions_through_resets((compiled, eager)):
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


class _Messages(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())


def test_the_step_compiles_in_one_pass_of_torchs_analysis():
    # torch.compile once read a 0-dim CPU tensor the step adds to (a counter of the episode) as a Python number,
    # made it a symbolic float, and then started its analysis of the whole step over to specialise it: 1-2 s more
    # of every CPU start-up. Its log says so in one line per restart.
    torch._dynamo.reset()
    messages = _Messages()
    logger = logging.getLogger("torch._dynamo.convert_frame")
    torch._logging.set_logs(dynamo=logging.INFO)
    logger.addHandler(messages)
    try:
        task = isaacgymenvs_mw.make("Cartpole", num_envs=N, sim_device="cpu", rl_device="cpu", headless=True, seed=0,
                                    overrides=["+task.sim.compileStep=True"])
        task.reset()
        task.step(torch.zeros(N, task.num_actions))
    finally:
        logger.removeHandler(messages)
        torch._logging.set_logs()
    assert task.step_execution == "compiled"
    # The logger was heard (it reports each compile it finishes), so the assertion below is not empty by accident.
    assert any("after_compile" in m for m in messages.messages), messages.messages
    assert not [m for m in messages.messages if "Restarting analysis" in m], messages.messages


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


def step_outputs(task, actions):
    obs, rew, done, extras = task.step(actions)
    return (obs["obs"].clone(), obs["states"].clone(), rew.clone(), done.clone(), extras["time_outs"].clone(),
            task.sim.qpos.clone(), task.sim.qvel.clone())


def test_step_compiled_alongside_the_kernels_computes_bit_for_bit_what_the_first_step_compile_computes():
    # The second is compiled by its first call, after the kernels: the path before the two overlapped.
    ahead, first_call = go1_twins(["+task.sim.compileStep=True"], ["+task.sim.compileStep=True"],
                                  compile_ahead_b=False)
    saw_resets = False
    for i, a in actions_through_resets((ahead, first_call)):
        outputs = []
        for task in (ahead, first_call):
            torch.manual_seed(200 + i)
            # The steps run under inference_mode, as the runner's rollout does, after a reset outside it, as
            # RslRlVecEnv's is. Later steps must not compile the step again.
            with torch._dynamo.config.patch(error_on_recompile=i > 0), torch.inference_mode():
                outputs.append(step_outputs(task, a))
        for name, x, y in zip(("obs", "states", "rew", "done", "time_outs", "qpos", "qvel"), *outputs):
            assert torch.equal(x, y), f"{name} differs at step {i}"
        saw_resets |= bool(outputs[0][4].any())
    assert saw_resets
    # The step compiled ahead was used as it was: its first call compiled nothing (one would mean torch's guards
    # found the first step's state or mode unlike those it was compiled in), and nothing compiled it again.
    assert (ahead.execution.compiled_at, first_call.execution.compiled_at) == ("alongside Warp's kernels", "first step")
    assert ahead.execution._step.compiles == first_call.execution._step.compiles == 1


class Counter:
    """A stand-in for a task's post-physics step: tensor work, a random draw and Python state."""

    def __init__(self) -> None:
        self.x = torch.zeros(5)
        self.extras = {"calls": 0}

    def after(self) -> None:
        self.x.add_(torch.rand(5)).mul_(2.0)
        self.extras["calls"] += 1

    def after_with_host_work(self) -> None:
        self.x.add_(1.0)
        print("host work")  # a graph break: torch runs this line itself, between two compiled graphs
        self.extras["calls"] += 1
        self.x.mul_(2.0)


def test_compiling_ahead_runs_nothing_and_the_first_call_uses_what_it_compiled():
    counter, reference = Counter(), Counter()
    step = _CompiledStep(counter.after)
    rng = torch.get_rng_state()
    assert step.compile_only() is None
    assert step.compiles == 1
    assert torch.equal(counter.x, torch.zeros(5)) and counter.extras == {"calls": 0}
    assert torch.equal(torch.get_rng_state(), rng)  # no random draw consumed
    for i in range(3):
        torch.manual_seed(7)
        # The first call finds the code compiled (later ones recompile: torch specialises on the int in extras).
        with torch._dynamo.config.patch(error_on_recompile=i == 0):
            step.fn()
        torch.manual_seed(7)
        reference.after()
    assert torch.equal(counter.x, reference.x) and counter.extras == reference.extras == {"calls": 3}


def test_a_step_with_a_graph_break_is_left_to_its_first_call(capsys):
    counter, reference = Counter(), Counter()
    step = _CompiledStep(counter.after_with_host_work)
    why_not = step.compile_only()
    assert why_not is not None and why_not.startswith("Unsupported")
    assert torch.equal(counter.x, torch.zeros(5)) and counter.extras == {"calls": 0}
    assert "host work" not in capsys.readouterr().out  # nothing before or after the break ran
    for _ in range(2):
        step.fn()
        reference.after_with_host_work()
    assert torch.equal(counter.x, reference.x) and counter.extras == reference.extras == {"calls": 2}


def test_where_torch_would_run_the_step_uncompiled_compiling_ahead_runs_nothing():
    # Tasks compiled before in this process do not count against a new task's step: each has its own code object.
    many, fresh = [Counter() for _ in range(3)], Counter()
    with torch._dynamo.config.patch(recompile_limit=2):
        for counter in many:
            _CompiledStep(counter.after).fn()
        assert _CompiledStep(fresh.after).compile_only() is None
    with torch._dynamo.config.patch(recompile_limit=0):  # no compilation allowed: torch would run it uncompiled
        why_not = _CompiledStep(fresh.after).compile_only()
    assert why_not is not None and "RecompileLimit" in why_not
    with torch.compiler.set_stance("force_eager"):
        why_not = _CompiledStep(fresh.after).compile_only()
    assert why_not is not None and "force_eager" in why_not
    assert torch.equal(fresh.x, torch.zeros(5)) and fresh.extras == {"calls": 0}


def test_an_error_in_the_compile_alongside_the_kernels_surfaces_at_the_first_step():
    task = make_go1(["+task.sim.compileStep=True"])
    task.reset()

    def failing_inductor(gm, example_inputs):
        raise RuntimeError("inductor could not generate code")

    task.execution._step._inductor = failing_inductor
    with pytest.raises(Exception, match="inductor could not generate code"):
        task.step(task.zero_actions())


@wp.kernel(module="unique")
def _fill_ones(x: wp.array(dtype=float)):
    x[wp.tid()] = 1.0


@wp.kernel(module="unique")
def _fill_twos(x: wp.array(dtype=float)):
    x[wp.tid()] = 2.0


@wp.kernel(module="unique")
def _fill_threes(x: wp.array(dtype=float)):
    x[wp.tid()] = 3.0


@pytest.fixture
def three_modules():
    """Entry points launching kernels of three modules of their own (recorded, never run), and those modules."""
    found = (_fill_ones, _fill_twos, _fill_threes)
    scratch = wp.zeros(2, dtype=float, device="cpu")
    entry_points = [lambda k=k: wp.launch(k, dim=2, inputs=[scratch], device="cpu") for k in found]
    modules = [k.module for k in found]
    kernels._loaded.difference_update([e for e in kernels._loaded if e[0] in modules])  # pending in every test
    return entry_points, modules


def test_kernel_modules_compile_while_the_step_compiles_and_errors_come_back(monkeypatch, three_modules):
    entry_points, modules = three_modules
    alongside_ran = threading.Event()
    compiled, waited_out = [], []

    def force_load(device=None, modules=None, block_dim=None, max_workers=None):
        # Each module finishes only once `alongside` has started: were it called after the modules, this would wait
        # out its timeout and say so.
        if not alongside_ran.wait(timeout=60):
            waited_out.append(modules[0])
        compiled.append(modules[0])

    monkeypatch.setattr(wp, "force_load", force_load)
    assert kernels.load_kernels(wp.get_device("cpu"), entry_points, max_workers=3, alongside=alongside_ran.set) == 3
    assert sorted(map(id, compiled)) == sorted(map(id, modules)) and not waited_out


def test_a_kernel_load_compiles_in_the_background_until_waited_for(monkeypatch, three_modules):
    """KernelLoad (what the simulator starts on CUDA at construction) returns with its modules compiling on other
    threads; ``wait`` runs ``alongside`` and then returns once they are done."""
    entry_points, modules = three_modules
    started, release, compiled = threading.Event(), threading.Event(), []

    def force_load(device=None, modules=None, block_dim=None, max_workers=None):
        started.set()
        assert threading.current_thread() is not threading.main_thread()
        assert release.wait(timeout=60)
        compiled.append(modules[0])

    monkeypatch.setattr(wp, "force_load", force_load)
    load = kernels.KernelLoad(wp.get_device("cpu"), entry_points, max_workers=3)
    assert started.wait(timeout=60) and compiled == []  # compiling, and this thread is free
    assert load.wait(alongside=release.set) == 3
    assert sorted(map(id, compiled)) == sorted(map(id, modules))


def test_a_module_that_fails_to_compile_fails_the_load_in_the_calling_thread(monkeypatch, three_modules):
    entry_points, modules = three_modules

    def force_load(device=None, modules=None, block_dim=None, max_workers=None):
        if modules[0] is modules_to_fail[0]:
            raise RuntimeError("nvrtc: error in module 2")

    modules_to_fail = [modules[1]]
    monkeypatch.setattr(wp, "force_load", force_load)
    ran = []
    with pytest.raises(RuntimeError, match=r"^nvrtc: error in module 2$"):
        kernels.load_kernels(wp.get_device("cpu"), entry_points, max_workers=2, alongside=lambda: ran.append(1))
    assert ran == [1]


def test_an_error_alongside_is_raised_once_the_started_modules_are_done(monkeypatch, three_modules):
    entry_points, _ = three_modules
    running = []

    def force_load(device=None, modules=None, block_dim=None, max_workers=None):
        running.append(modules[0])
        release.wait(timeout=60)
        running.remove(modules[0])

    release = threading.Event()
    monkeypatch.setattr(wp, "force_load", force_load)

    def alongside():
        release.set()
        raise ValueError("the step could not be compiled")

    with pytest.raises(ValueError, match="the step could not be compiled"):
        kernels.load_kernels(wp.get_device("cpu"), entry_points, max_workers=1, alongside=alongside)
    assert running == []  # no module thread is left compiling behind the error


def test_inductor_compile_workers_start_with_sigterm_ignored_and_the_handler_comes_back():
    """A group-wide SIGTERM (timeout, a scheduler) must stop the run through its own handler, not kill Inductor's
    compile workers: the worker process starts with SIGTERM ignored (the kernel's SigIgn mask of the process), the
    main process keeps its handler. A fresh interpreter, so that no earlier test has made the pool already."""
    code = """
import signal, sys
from torch._inductor.async_compile import AsyncCompile, shutdown_compile_workers
from isaacgymenvs_mw.tasks.base.step_execution import start_compile_workers_ignoring_sigterm
def handler(signum, frame):
    pass
signal.signal(signal.SIGTERM, handler)
start_compile_workers_ignoring_sigterm()
pid = AsyncCompile.process_pool().process.pid
with open(f"/proc/{pid}/status") as status:
    ignored = int(next(line for line in status if line.startswith("SigIgn:")).split()[1], 16)
print(bool(ignored >> (signal.SIGTERM - 1) & 1), signal.getsignal(signal.SIGTERM) is handler)
shutdown_compile_workers()
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "TORCHINDUCTOR_COMPILE_THREADS": "2"})
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-2:] == ["True", "True"], out.stdout


def test_the_stop_watchdog_leaves_sigterm_ignored_while_the_compile_workers_start():
    """train.py's stop watchdog writes the handler back wherever the C-level disposition changes; while the compile
    workers start (a slow start here: 0.5 s, ten watchdog rounds) SIGTERM must stay ignored, or the workers start
    killable and a group-wide SIGTERM hangs the run in its first step (seen on an H200), and the handler comes back
    after."""
    code = """
import signal, time
from torch._inductor import config
from torch._inductor import async_compile
from torch._inductor.async_compile import AsyncCompile
from isaacgymenvs_mw.tasks.base import step_execution
from isaacgymenvs_mw.utils.stop import PROCESS_STOP, native_handler
PROCESS_STOP.install()
seen = []
def slow_pool():
    time.sleep(0.5)
    seen.append(native_handler(signal.SIGTERM))
AsyncCompile.process_pool = staticmethod(slow_pool)
config.worker_start_method = "subprocess"
async_compile.get_compile_threads = lambda: 2
step_execution.start_compile_workers_ignoring_sigterm()
time.sleep(0.2)
print(seen == [1], signal.getsignal(signal.SIGTERM) is PROCESS_STOP._handler,
      native_handler(signal.SIGTERM) == PROCESS_STOP._native[signal.SIGTERM], PROCESS_STOP.reassert())
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["True", "True", "True", "None"], out.stdout


def test_a_task_with_equality_constraints_compiles_its_step_once():
    # The blow-up check reads the equality rows' residuals inside the compiled step (the Panda's coupled fingers): a
    # MuJoCo enum converted there made torch.compile's tracing recurse without end, and the step failed.
    task = isaacgymenvs_mw.make("FrankaCabinet", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True, seed=0,
                                overrides=["+task.sim.compileStep=True"])
    assert task.step_execution == "compiled" and task.sim.equality_violation() is not None
    task.reset()
    for i in range(4):
        with torch._dynamo.config.patch(error_on_recompile=i > 1):
            obs, rew, _, _ = task.step(torch.zeros(2, task.num_actions))
    assert bool(torch.isfinite(obs["obs"]).all()) and bool(torch.isfinite(rew).all())


def test_a_reset_that_refreshes_the_poses_compiles_into_the_one_graph_and_observes_the_new_poses():
    # FrankaCubeLift's reset recomputes the poses (Warp's kinematics, an op of the compiled graph) and observes the
    # grasp site: the compiled step must order the op after the reset's writes and before the observation.
    tasks = [isaacgymenvs_mw.make("FrankaCubeLift", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True,
                                  seed=0, overrides=[f"+task.sim.compileStep={on}"]) for on in (True, False)]
    for task in tasks:
        torch.manual_seed(3)
        task.reset()
    tasks[1].sim.load_state(tasks[0].sim.save_state())
    generator = torch.Generator().manual_seed(1)
    for i in range(4):
        a = 2.0 * torch.rand(2, tasks[0].num_actions, generator=generator) - 1.0
        outputs = []
        for task in tasks:
            if i == 2:
                task.progress_buf[0] = task.max_episode_length - 1
            torch.manual_seed(100 + i)
            obs, rew, done, _ = task.step(a)
            outputs.append((obs["obs"].clone(), rew.clone(), done.clone()))
        (o1, r1, d1), (o2, r2, d2) = outputs
        torch.testing.assert_close(o1, o2, atol=1e-5, rtol=1e-5, msg=f"observations differ at step {i}")
        torch.testing.assert_close(r1, r2, atol=1e-6, rtol=1e-5, msg=f"rewards differ at step {i}")
        assert torch.equal(d1, d2) and bool(d1[0]) == (i == 2), f"resets differ at step {i}"
    assert tasks[0].execution.compiled_at == "alongside Warp's kernels" and tasks[0].execution._step.compiles == 1


def test_the_compiled_refresh_works_on_the_simulators_own_arrays():
    # Inductor's default reordering moved the reward's reads of the poses and of qpos after the refresh, so it cloned
    # those arrays and the op copied each one in and out around the kinematics (FrankaCubeLift: 4 arrays per step).
    # Compiled in code order (graph_engine.refreshes_kinematics), the op gets the simulator's arrays themselves.
    task = isaacgymenvs_mw.make("FrankaCubeLift", num_envs=2, sim_device="cpu", rl_device="cpu", headless=True,
                                seed=0, overrides=["+task.sim.compileStep=True"])
    sim, handed = task.sim, []
    own_refresh = sim._kinematics_on

    def spy(state: list[torch.Tensor], poses: list[torch.Tensor]) -> None:
        mine = [*sim._kinematics_state, *sim._kinematics_poses]
        handed.append([i for i, (m, g) in enumerate(zip(mine, [*state, *poses])) if g.data_ptr() != m.data_ptr()])
        own_refresh(state, poses)

    sim._kinematics_on = spy
    task.reset()
    for _ in range(3):
        task.step(torch.zeros(2, task.num_actions))
    assert handed == [[], [], []]


def test_a_replayed_step_reports_the_metric_tensors_its_capture_recorded():
    """A captured step's replays run no Python, so nothing records; the task's metrics must still be the tensors
    the step recorded while it was captured (the graphs rewrite them in place). CUDA graphs need a GPU: here the
    capture is the step's Python run once and a replay runs none of it."""
    task = isaacgymenvs_mw.make("FrankaCubeLift", num_envs=N, sim_device="cpu", rl_device="cpu", headless=True)
    task.reset()
    real_run = task.execution.run

    def run(actions):
        if task.execution.graphs is None:  # the capture
            real_run(actions)
            task.execution.graphs = ("before", "after")
        # a replay: the graphs would rewrite the recorded tensors; no Python of the step runs

    task.execution.run = run
    actions = torch.zeros(N, task.num_actions)
    task.step(actions)
    captured = {kind: task.metrics.recorded(kind) for kind in (EPISODE_SUM, OUTCOME)}
    assert set(captured[EPISODE_SUM]) == {"success"} and set(captured[OUTCOME]) == {"success"}
    task.reset()  # an eager reset between replays records its own values
    for _ in range(2):
        task.step(actions)
        for kind, values in captured.items():
            replayed = task.metrics.recorded(kind)
            assert replayed.keys() == values.keys()
            assert all(replayed[name] is values[name] for name in values)
