"""How VecTask runs the torch work around the physics of one env step: eagerly, compiled, and captured.

On a GPU a step's torch work is a few hundred small kernels; launched one by one from Python they, not the maths,
were what a step cost beyond the physics. So, on CUDA:
  * the post-physics work is compiled with torch.compile (``sim.compileStep``; "auto": where the step is captured),
    which fuses those kernels into a few dozen;
  * after a few eager warm-up steps, the pre- and post-physics work are captured as two CUDA graphs
    (``sim.captureStep``), so that a step costs three graph launches (the physics is the third).
Both need the task's hooks to be device-only tensor code: no host syncs, and no Warp launches in
``post_physics_step`` but the simulator's kinematics refresh (``write_state(refresh=True)``), which is an op of the
compiled graph. VecTask hands the step over as phases (``StepPhases``), run in this order: before physics, physics,
after physics (whose sequence refreshes the computed sensors, ``Simulator.sense()``), render (the sensors a render
refreshes, the cameras: ``Simulator.render_cameras()``, after the step's resets, with Warp graphs of their own), and,
when the task observes camera images, the image observation (torch), so that images show the state after the resets.
The image observation writes one of two frame-stack buffers, chosen by the step number's parity (``ImageStack``), so
it is captured twice, once per buffer, and each step replays the one for its parity.

Start-up: compiling the post-physics step (Inductor and Triton code generation, tens of seconds with cold caches)
and compiling Warp's kernel modules (tens of seconds, on a pool of threads) are both CPU work, and neither needs
the other. So the first step, before anything else, has the simulator load its kernels with the step's compilation
running meanwhile in this thread (``Simulator.load_kernels(alongside=...)``; VecTask leaves the kernels to it when
the step is compiled). The step is compiled there without being run: the compiled code is called in a dry mode that
stops before it executes (no tensor, random stream or Python object changes), and torch keeps it, so the step's own
call finds it compiled. It is compiled at the first step, not at the reset, because torch's guards include the
caller's mode: training and evaluation step under ``torch.inference_mode``, and code compiled outside it would be
compiled again. That takes one graph for the whole step; a task whose step has a graph break is compiled by its first
call instead, as before.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
import types
import warnings
from dataclasses import dataclass
from typing import Callable, Iterator

import torch

from isaacgymenvs_mw.sim.graph_engine import refreshes_kinematics
from isaacgymenvs_mw.tasks.base.python_state import PythonStateWatch
from isaacgymenvs_mw.utils.errors import ConfigError
from isaacgymenvs_mw.utils.stop import PROCESS_STOP

# Eager steps before the capture: the first compiles, the next ones let lazily allocated buffers settle.
WARMUP_STEPS = 3


@dataclass(frozen=True)
class StepPhases:
    """One env step as VecTask hands it over, in the order it runs. A phase that takes an ``int`` gets the number of
    the step (0-based), the one clock of the run."""

    before: Callable[[torch.Tensor], None]  # torch: clipped actions -> actuator commands (captured)
    physics: Callable[[], None]  # the simulator's controlFrequencyInv physics steps (its own graph)
    after: Callable[[], None]  # torch: terminations, reward, resets, observations (compiled, captured)
    render: Callable[[int], None]  # the cameras' render after the resets (Warp, with graphs of its own)
    observe_images: Callable[[int], None] | None = None  # torch: the image observation (captured per parity)


@contextlib.contextmanager
def fresh_dict(owner: object, name: str) -> Iterator[None]:
    """The step's torch work writes into an empty dict ``owner.<name>`` (VecTask's ``extras``), merged into the
    run's afterwards. torch.compile guards on every entry of a dict the compiled step writes into, and the run's
    entries are remade by each step (as inference tensors in training): guarded, they would make the first steps
    compile the step again."""
    kept = getattr(owner, name)
    setattr(owner, name, {})
    try:
        yield
    finally:
        kept.update(getattr(owner, name))
        setattr(owner, name, kept)


class StepExecution:
    """Runs the ``phases`` of one env step in the cheapest way the device allows, and counts the steps.

    ``name`` is the task's class name, for messages; ``sim_cfg`` is the task YAML's ``sim`` section."""

    def __init__(self, name: str, phases: StepPhases, sim_cfg: dict, graphs_possible: bool,
                 action_shape: tuple[int, int], device: str,
                 load_kernels: Callable[[Callable[[], None] | None], None] | None = None,
                 task: object | None = None) -> None:
        self.name, self.phases = name, phases
        self.before, self.physics, after = phases.before, phases.physics, phases.after
        self.graphs_wanted = bool(sim_cfg.get("captureStep", True)) and graphs_possible
        self.compiled = _compile_wanted(sim_cfg.get("compileStep", "auto"), self.graphs_wanted)
        self._step = _CompiledStep(after) if self.compiled else None
        self.after = after if self._step is None else self._first_compiled_call
        # The simulator's load_kernels, which the first step calls with the step's compilation alongside
        # (compile_ahead=False: compiled by its first call, after the kernels; tests compare the two).
        self._load_kernels = load_kernels
        self.compile_ahead = True
        # Where the step was compiled: "alongside Warp's kernels", "first step" (None: not yet, or not compiled).
        self.compiled_at: str | None = None
        self.graph_actions = torch.zeros(action_shape, device=device)  # a captured graph reads its input here
        self.graphs: tuple[torch.cuda.CUDAGraph, ...] | None = None  # before, after[, observe even, odd]
        self.device = device
        self.steps = 0  # env steps run so far: the run's one step counter
        # The task's Python numbers that its hooks change: frozen by a capture, so named in the eager steps before it
        # (on every device; not where sim.captureStep=False keeps the hooks' Python running on a GPU too).
        self.python_state = None if task is None or not sim_cfg.get("captureStep", True) else PythonStateWatch(
            task, name, WARMUP_STEPS)

    @property
    def mode(self) -> str:
        """"eager", "compiled", "captured" or "compiled+captured"."""
        parts = [name for name, on in (("compiled", self.compiled), ("captured", self.graphs_wanted)) if on]
        return "+".join(parts) or "eager"

    @property
    def replays(self) -> bool:
        """The next ``run`` replays captured graphs: none of the step's Python code runs."""
        return self.graphs is not None

    def run(self, actions: torch.Tensor) -> None:
        if self.steps == 0 and self._step is not None:
            start_compile_workers_ignoring_sigterm()
        if self.steps == 0 and self._load_kernels is not None:
            # Warp's kernels load (when nothing has loaded them yet), with the step compiled meanwhile in the state
            # and mode its first call sees.
            self._load_kernels(self._compile_ahead if self._step is not None and self.compile_ahead else None)
        if self.graphs_wanted and self.steps >= WARMUP_STEPS:
            self.graph_actions.copy_(actions)
            if self.graphs is None:
                self._capture()
            before, after = self.graphs[:2]
            before.replay()
            self.physics()
            after.replay()
            self.phases.render(self.steps)
            if self.phases.observe_images is not None:
                self.graphs[2 + self.steps % 2].replay()
        else:
            watch = self.python_state if self.python_state is not None and self.python_state.watching(
                self.steps) else None
            state = watch.snapshot() if watch is not None else None
            self.before(actions)
            self.physics()
            self.after()
            self.phases.render(self.steps)
            if self.phases.observe_images is not None:
                self.phases.observe_images(self.steps)
            if watch is not None:
                watch.compare(state, self.steps)
        self.steps += 1

    def _first_compiled_call(self) -> None:
        # Compiles unless the first step compiled it ahead (about 15 s on a GPU host with cold caches, 2 s warm): say
        # where the time of a run's first iteration went, then step with the compiled function alone.
        started, graphs, cache = time.perf_counter(), self._step.compiles, inductor_cache_counts()
        self._step.fn()
        self.after = self._step.fn
        if self._step.compiles > graphs:
            again = self.compiled_at is not None  # compiled ahead, but torch's guards found the state changed since
            self.compiled_at = "first step"
            print(f"[isaacgymenvs_mw] {'re' if again else ''}compiled {self.name}'s post-physics step "
                  f"(sim.compileStep) at the first step in {time.perf_counter() - started:.1f} s"
                  f"{inductor_cache_note(cache)}", flush=True)

    def _compile_ahead(self) -> None:
        """Compile the step without running it (the simulator calls this while its kernels compile). When torch
        cannot take the whole step as one graph, it compiles at the first step instead, as it always did; any other
        error is raised here, as the first step would have raised it."""
        started, cache = time.perf_counter(), inductor_cache_counts()
        why_not = self._step.compile_only()
        if why_not is not None:
            print(f"[isaacgymenvs_mw] {self.name}'s post-physics step is compiled by its first call instead "
                  f"({why_not})", flush=True)
            return
        self.compiled_at = "alongside Warp's kernels"
        print(f"[isaacgymenvs_mw] compiled {self.name}'s post-physics step (sim.compileStep) "
              f"in {time.perf_counter() - started:.1f} s, alongside Warp's kernels{inductor_cache_note(cache)}",
              flush=True)

    def _capture(self) -> None:
        before, after = torch.cuda.CUDAGraph(), torch.cuda.CUDAGraph()
        torch.cuda.synchronize(self.device)
        try:
            with torch.cuda.graph(before):
                self.before(self.graph_actions)
            with torch.cuda.graph(after, pool=before.pool()):
                self.after()
            observe = [torch.cuda.CUDAGraph() for _ in range(2 if self.phases.observe_images is not None else 0)]
            for step in range(self.steps, self.steps + len(observe)):  # graphs[2 + parity]: steps of that parity
                with torch.cuda.graph(observe[step % 2], pool=before.pool()):
                    self.phases.observe_images(step)
        except Exception as err:
            raise RuntimeError(
                f"sim.captureStep: {self.name}'s step could not be captured as CUDA graphs ({err}). A task whose "
                "post_physics_step syncs with the host or launches Warp kernels cannot be captured: run with "
                "+task.sim.captureStep=False"
            ) from err
        self.graphs = (before, after, *observe)


class _DryRun(Exception):
    """Raised instead of running code that ``_CompiledStep.compile_only`` has compiled."""


class _CompiledStep:
    """``torch.compile`` of the post-physics function ``fn`` (Inductor), which can also compile without running.

    Random draws stay torch's own (``fallback_random``), so a seed gives the numbers the eager step gives. Inductor is
    reached through a backend of ours that wraps each compiled graph: in dry mode the wrapper raises instead of
    running it. Dynamo calls a frame's graph before it replays any of the frame's side effects, and keeps what it
    compiled when the call raises, so a dry call leaves everything as it was and the next call finds the code ready.
    """

    def __init__(self, fn: Callable[[], None]) -> None:
        self._inductor = torch._TorchCompileInductorWrapper(None, {"fallback_random": True}, False)
        # A step that refreshes the kinematics keeps its code order around the refresh (sim/graph_engine.py,
        # refreshes_kinematics says why): the refresh then needs no copies of the simulator's arrays.
        self._inductor_in_order = torch._TorchCompileInductorWrapper(
            None, {"fallback_random": True, "reorder_for_locality": False}, False)
        self._dry = False
        self.compiles = 0  # graphs compiled so far
        self.fn = torch.compile(_with_own_code(fn), backend=self._backend, dynamic=False)

    def _backend(self, gm: torch.fx.GraphModule, example_inputs: list) -> Callable:
        inductor = self._inductor_in_order if refreshes_kinematics(gm.graph) else self._inductor
        compiled = inductor(gm, example_inputs)
        self.compiles += 1

        def run(*args):
            if self._dry:
                raise _DryRun()
            return compiled(*args)

        run._boxed_call = getattr(compiled, "_boxed_call", False)  # the calling convention torch expects of it
        return run

    def compile_only(self) -> str | None:
        """Compile ``fn`` as one graph, running none of it; None when done. When torch cannot (a graph break, its
        recompile limit, torch.compile turned off, a torch without ``error_on_graph_break``), nothing has run either
        and the reason is returned: the first call then compiles, or runs uncompiled, as torch decides."""
        dynamo = torch._dynamo
        if not hasattr(dynamo, "error_on_graph_break"):  # torch < 2.9
            return f"torch {torch.__version__} has no torch._dynamo.error_on_graph_break"
        # Where torch would run the function uncompiled, the dry call would run it: TORCHDYNAMO_DISABLE, a stance.
        stance = getattr(getattr(dynamo.eval_frame, "_stance", None), "stance", "default")
        if dynamo.config.disable or stance != "default":
            return f"torch.compile is off in this process (TORCHDYNAMO_DISABLE or the stance {stance!r})"
        # A graph break would run the code before it eagerly, and so would torch past its recompile limit (many
        # compiled tasks in one process) or on an error it was told to suppress: here all are errors, raised before
        # anything runs.
        limit_hit = getattr(dynamo.exc, "FailOnRecompileLimitHit", dynamo.exc.Unsupported)
        strict = {"suppress_errors": False}
        if hasattr(dynamo.config, "fail_on_recompile_limit_hit"):
            strict["fail_on_recompile_limit_hit"] = True
        self._dry = True
        try:
            with dynamo.error_on_graph_break(True), dynamo.config.patch(**strict):
                self.fn()
        except _DryRun:
            return None
        except (dynamo.exc.Unsupported, limit_hit) as err:
            return f"{type(err).__name__}: {(str(err).strip().splitlines() or [''])[0][:200]}"
        finally:
            self._dry = False
        # Not expected (the step's first graph runs first); the state has changed, so the run must not go on.
        raise RuntimeError("the post-physics step ran while it was only to be compiled (torch ran it outside a "
                           "compiled graph); set +task.sim.compileStep=False and report this")


def _with_own_code(fn: Callable[[], None]) -> Callable[[], None]:
    """``fn`` (a function or bound method) with a code object of its own. torch keeps compiled code, and counts
    compilations against its recompile limit, per code object, and VecTask's step is one function for all tasks: in a
    process with several compiled tasks, their compilations would add up and, past the limit, torch would mark the
    step to run uncompiled, for every task, a dry call included."""
    func = getattr(fn, "__func__", fn)
    copy = types.FunctionType(func.__code__.replace(), func.__globals__, func.__name__, func.__defaults__,
                              func.__closure__)
    copy.__kwdefaults__, copy.__qualname__ = func.__kwdefaults__, func.__qualname__
    return types.MethodType(copy, fn.__self__) if hasattr(fn, "__func__") else copy


def inductor_cache_counts() -> tuple[int, int]:
    """Graphs that Inductor has so far, in this process, read back from its FX graph cache, and compiled (a miss, or
    a graph its cache cannot hold)."""
    from torch._dynamo.utils import counters

    inductor = counters["inductor"]
    return inductor["fxgraph_cache_hit"], inductor["fxgraph_cache_miss"] + inductor["fxgraph_cache_bypass"]


def inductor_cache_note(before: tuple[int, int]) -> str:
    """What Inductor's cache served since ``inductor_cache_counts()`` gave ``before``, for the step's compile line: a
    shipped cache folder (utils/compile_cache.py) that serves the step reads every graph back. Empty where Inductor
    counted no graph (its caches turned off)."""
    hits, compiled = (now - then for now, then in zip(inductor_cache_counts(), before))
    if hits + compiled == 0:
        return ""
    return f" (Inductor's cache: {hits} of {hits + compiled} graphs read back)"


def start_compile_workers_ignoring_sigterm() -> None:
    """Start TorchInductor's compile-worker processes with SIGTERM ignored, before the step compiles.

    ``timeout`` and job schedulers send SIGTERM to the whole process group. The training process then stops at the
    next env step and keeps its checkpoint and summary (``learning/launch.py``), but Inductor's workers share the
    group and leave SIGTERM at its default (they ignore SIGINT themselves), so they would die with it: a run
    signalled while the step compiles would hang there, and one signalled later would die without its checkpoint or
    summary. An ignored signal stays ignored across fork and exec, so workers started while it is ignored
    outlive it; they exit with their parent (Inductor's own watchdog). The main thread's handler is ignored only
    while the worker process starts (milliseconds). Nothing happens where the pool already exists or is not made of
    subprocesses."""
    try:
        from torch._inductor import config
        from torch._inductor.async_compile import AsyncCompile, get_compile_threads
    except ImportError:
        return
    start_pool = getattr(AsyncCompile, "process_pool", None)
    if (start_pool is None or getattr(config, "worker_start_method", None) != "subprocess"
            or get_compile_threads() <= 1 or threading.current_thread() is not threading.main_thread()):
        return
    with PROCESS_STOP.watchdog_paused():  # it would otherwise put the handler back while the workers start
        previous = signal.signal(signal.SIGTERM, signal.SIG_IGN)
        try:
            start_pool()  # cached by torch: the pool the compile then uses
        finally:
            signal.signal(signal.SIGTERM, previous)


def _compile_wanted(value, graphs_wanted: bool) -> bool:
    """``sim.compileStep``: True / False, or "auto": compiled where the step is captured (CUDA) and Triton exists."""
    if value not in (True, False, "auto"):
        raise ConfigError(f"sim.compileStep={value!r} is invalid: give True, False or auto")
    if value != "auto":
        return bool(value)
    if not graphs_wanted:
        return False
    try:
        from torch.utils._triton import has_triton  # torch's own probe for a usable Triton
    except ImportError:  # a torch without that probe: compiling would not find Triton either
        return False
    if not has_triton():
        warnings.warn("sim.compileStep=auto: Triton is not installed, so the post-physics step runs uncompiled "
                      "(slower on GPU); `pip install triton` or set +task.sim.compileStep=False to silence this",
                      RuntimeWarning, stacklevel=3)
        return False
    return True
