"""How VecTask runs the torch work around the physics of one env step: eagerly, compiled, and captured.

On a GPU a step's torch work is a few hundred small kernels; launched one by one from Python they, not the maths,
were what a step cost beyond the physics. So, on CUDA:
  * the post-physics work is compiled with torch.compile (``sim.compileStep``; "auto": where the step is captured),
    which fuses those kernels into a few dozen;
  * after a few eager warm-up steps, the pre- and post-physics work are captured as two CUDA graphs
    (``sim.captureStep``), so that a step costs three graph launches (the physics is the third).
Both need the task's hooks to be device-only tensor code: no host syncs, no Warp launches in ``post_physics_step``.
A task with cameras adds two phases after those (``sensors``): the render (Warp: its own graph, replayed by the
simulator) and the image observation (torch: a third captured graph), so that images show the state after the
resets.
"""

from __future__ import annotations

import time
import warnings
from typing import Callable

import torch

from isaacgymenvs_mw.utils.errors import ConfigError

# Eager steps before the capture: the first compiles, the next ones let lazily allocated buffers settle.
WARMUP_STEPS = 3


class StepExecution:
    """Runs ``before(actions)``, ``physics()``, ``after()`` for one env step in the cheapest way the device allows.

    ``name`` is the task's class name, for messages; ``sim_cfg`` is the task YAML's ``sim`` section."""

    def __init__(self, name: str, before: Callable[[torch.Tensor], None], physics: Callable[[], None],
                 after: Callable[[], None], sim_cfg: dict, graphs_possible: bool, action_shape: tuple[int, int],
                 device: str) -> None:
        self.name, self.before, self.physics = name, before, physics
        self.graphs_wanted = bool(sim_cfg.get("captureStep", True)) and graphs_possible
        self.compiled = _compile_wanted(sim_cfg.get("compileStep", "auto"), self.graphs_wanted)
        self.after = after if not self.compiled else self._compile_on_first_call(after)
        self.graph_actions = torch.zeros(action_shape, device=device)  # a captured graph reads its input here
        self.graphs: tuple[torch.cuda.CUDAGraph, ...] | None = None
        # (render, observe) when the task observes camera images: run after ``after`` (VecTask sets it).
        self.sensors: tuple[Callable[[], None], Callable[[], None]] | None = None
        self.device = device
        self.steps = 0

    @property
    def mode(self) -> str:
        """"eager", "compiled", "captured" or "compiled+captured"."""
        parts = [name for name, on in (("compiled", self.compiled), ("captured", self.graphs_wanted)) if on]
        return "+".join(parts) or "eager"

    def run(self, actions: torch.Tensor) -> None:
        if self.graphs_wanted and self.steps >= WARMUP_STEPS:
            self.graph_actions.copy_(actions)
            if self.graphs is None:
                self._capture()
            before, after = self.graphs[:2]
            before.replay()
            self.physics()
            after.replay()
            if self.sensors is not None:
                self.sensors[0]()
                self.graphs[2].replay()
        else:
            self.before(actions)
            self.physics()
            self.after()
            if self.sensors is not None:
                self.sensors[0]()
                self.sensors[1]()
        self.steps += 1

    def _compile_on_first_call(self, after: Callable[[], None]) -> Callable[[], None]:
        # Random draws stay torch's own (fallback_random), so a seed gives the numbers the eager step gives.
        compiled = torch.compile(after, dynamic=False, options={"fallback_random": True})

        def first_call() -> None:
            # The first call compiles (about 15 s on a GPU host with cold caches, 2 s warm): say where the time of
            # a run's first iteration went, then step with the compiled function alone.
            started = time.perf_counter()
            compiled()
            print(f"[isaacgymenvs_mw] compiled {self.name}'s post-physics step (sim.compileStep) "
                  f"in {time.perf_counter() - started:.1f} s", flush=True)
            self.after = compiled

        return first_call

    def _capture(self) -> None:
        before, after = torch.cuda.CUDAGraph(), torch.cuda.CUDAGraph()
        torch.cuda.synchronize(self.device)
        try:
            with torch.cuda.graph(before):
                self.before(self.graph_actions)
            with torch.cuda.graph(after, pool=before.pool()):
                self.after()
            if self.sensors is not None:
                observe = torch.cuda.CUDAGraph()
                with torch.cuda.graph(observe, pool=before.pool()):
                    self.sensors[1]()
        except Exception as err:
            raise RuntimeError(
                f"sim.captureStep: {self.name}'s step could not be captured as CUDA graphs ({err}). A task whose "
                "post_physics_step syncs with the host or launches Warp kernels cannot be captured: run with "
                "+task.sim.captureStep=False"
            ) from err
        self.graphs = (before, after) if self.sensors is None else (before, after, observe)


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
