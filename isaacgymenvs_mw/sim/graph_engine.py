"""The graph engine of the simulator: kernel loading, and each fixed group of Warp launches (the physics of one env
step, a forward pass, a kinematics refresh, a camera render) captured once as a CUDA graph and replayed.

``GraphEngine`` is a part of ``Simulator`` (sim/simulator.py), which sets the attributes it reads: ``model``,
``data``, ``mj_model``, ``wp_device``, ``use_graphs``, ``substeps``, the torque-speed limit, the angular speed cap and body forces, and the
carried state that ``_snapshot``/``_restore`` (sim/world_state.py) keep over a first capture. Graphs bake in array
pointers, so every write from torch must be in place (``view[:] = ...``, ``copy_``), never a rebinding.
"""

from __future__ import annotations

import itertools
import weakref
from typing import Callable

import torch
import warp as wp

import mujoco_warp as mjw
from isaacgymenvs_mw.sim.kernels import KernelLoad

# A kinematics refresh inside the compiled post-physics step (a reset that writes qpos and then observes body or site
# poses): torch.compile cannot trace Warp's launches, so there the refresh is an op of the graph (``_kinematics_op``)
# that names what MuJoCo Warp's ``kinematics`` reads and writes, for torch to keep it in order with the torch work
# around it. Data fields it reads, Model fields it reads that torch may write (the randomiser's), Data fields it writes:
_KINEMATICS_READS = ("qpos", "mocap_pos", "mocap_quat")
_KINEMATICS_MODEL_READS = ("qpos0", "body_pos", "body_quat", "body_ipos", "body_iquat", "jnt_pos", "jnt_axis",
                           "geom_pos", "geom_quat", "site_pos", "site_quat")
_KINEMATICS_WRITES = ("xpos", "xquat", "xanchor", "xaxis", "xmat", "xipos", "ximat", "geom_xpos", "geom_xmat",
                      "site_xpos", "site_xmat")
# The op's int argument names its simulator (its graph engine).
_ENGINES: weakref.WeakValueDictionary[int, GraphEngine] = weakref.WeakValueDictionary()
_ENGINE_IDS = itertools.count()


@torch.library.custom_op("isaacgymenvs_mw::kinematics", mutates_args=("poses",))
def _kinematics_op(sim: int, state: list[torch.Tensor], poses: list[torch.Tensor]) -> None:
    _ENGINES[sim]._kinematics_on(state, poses)


@_kinematics_op.register_fake
def _(sim: int, state: list[torch.Tensor], poses: list[torch.Tensor]) -> None:
    return None


def refreshes_kinematics(graph: torch.fx.Graph) -> bool:
    """Whether a graph traced by torch.compile holds the kinematics refresh (``_kinematics_op``). Inductor's
    ``reorder_for_locality`` moves each computation down to its first use, and a step's reward is first used by the
    writes at its end, so the reads of the poses (and of qpos) that come before the refresh in the code end up after
    it: Inductor then keeps their old values by cloning the arrays and hands the clones to the op, which copies them
    in and out (``_kinematics_on``). Compiled without that reordering, the op refreshes the simulator's own arrays,
    with the same values (FrankaCubeLift on the CPU: 4 arrays moved per step with the reordering, none without)."""
    return any(node.target is torch.ops.isaacgymenvs_mw.kinematics.default for node in graph.nodes)


class GraphEngine:
    """Kernel loading, graph capture and replay, and the stepping entry points built on them (``simulate``,
    ``forward``, ``refresh_kinematics``)."""

    def _start_graph_engine(self) -> None:
        """Register for the compiled step's kinematics op and start with no graphs and no kernels loaded (kernels
        load on the first launch, or earlier when the owner calls ``load_kernels``: VecTask does, so that it can
        compile its step meanwhile)."""
        self._kernels_recorded: bool | None = None  # None: not loaded yet
        self._kernel_load: KernelLoad | None = None
        self._graphs: dict[str, object] = {}
        self._id = next(_ENGINE_IDS)
        _ENGINES[self._id] = self
        d = self.data
        self._kinematics_state = tuple(self.torch_view(getattr(d, f)) for f in _KINEMATICS_READS) + tuple(
            self.model_field(f) for f in _KINEMATICS_MODEL_READS)
        self._kinematics_poses = tuple(self.torch_view(getattr(d, f)) for f in _KINEMATICS_WRITES)

    def load_kernels(self, alongside: Callable[[], None] | None = None) -> None:
        """Compile every kernel module that stepping, forward and kinematics use, in parallel, before the first launch
        (a dry run on scratch data of one world records them; see sim/kernels.py). ``alongside`` runs in this thread
        meanwhile and must not launch Warp kernels; its exceptions and the compiler's are raised here.

        Loads once: a later call only runs ``alongside``. The first launch through the simulator calls it when its
        owner has not."""
        if self._kernels_recorded is not None:
            if alongside is not None:
                alongside()
            return
        load, self._kernel_load = self._kernel_load or self._start_kernel_load(), None
        with wp.ScopedDevice(self.wp_device):
            loaded = load.wait(alongside)
        self._kernels_recorded = loaded is not None

    def _start_kernel_load(self) -> KernelLoad:
        """Record the modules of step, forward and kinematics (a dry run on scratch data of one world) and start
        compiling them on a pool of threads (sim/kernels.py); ``load_kernels`` waits for them."""
        with wp.ScopedDevice(self.wp_device):
            scratch = mjw.make_data(self.mj_model, nworld=1, nconmax=self._sizes[0], njmax=self._sizes[1])
            entry_points = [lambda: mjw.step(self.model, scratch), lambda: mjw.forward(self.model, scratch),
                            lambda: mjw.kinematics(self.model, scratch)]
            return KernelLoad(self.wp_device, entry_points)

    def _run(self, name: str, fn: Callable[[], None], keep_state: bool = False) -> None:
        """Run a fixed sequence of Warp launches, from a captured graph where graphs are on.

        Before a graph is first captured ``fn`` runs once eagerly (to compile its kernels); with ``keep_state`` the
        carried state is put back after that run, so that a first physics call advances the worlds once, not twice.
        """
        if self._kernels_recorded is None:
            self.load_kernels()
        if self.use_graphs and self.wp_device.is_cuda and torch.cuda.is_current_stream_capturing():
            # torch is capturing the step (a reset's kinematics refresh in the captured post-physics step): the
            # launches go to torch's capturing stream and become part of its graph. On Warp's own stream they
            # would run once, now, and never when torch replays the step.
            with wp.ScopedDevice(self.wp_device), wp.ScopedStream(
                    wp.stream_from_torch(torch.cuda.current_stream()), sync_enter=False, sync_exit=False):
                fn()
            return
        if not self.use_graphs:
            with wp.ScopedDevice(self.wp_device):
                fn()
            return
        graph = self._graphs.get(name)
        if graph is None:
            with wp.ScopedDevice(self.wp_device):
                saved = self._snapshot() if keep_state else None
                fn()  # compiles the kernels outside the capture
                if saved is not None:
                    self._restore(saved)
                # By default Warp loads every module imported so far before a capture: all of MuJoCo Warp's,
                # dozens this model never launches. After a recorded dry run the ones it does are loaded.
                with wp.ScopedCapture(device=self.wp_device, force_module_load=not self._kernels_recorded) as capture:
                    fn()
            graph = self._graphs[name] = capture.graph
        wp.capture_launch(graph)

    def simulate(self) -> None:
        """Advance every world by ``substeps`` physics steps."""

        limiter = self.torque_speed
        free_bodies = self.free_body_velocity  # damping and angular speed cap (sim/velocity_limit.py)
        forces = self.body_forces if self.body_forces is not None and self.body_forces.active else None
        pose = forces is not None and forces.needs_kinematics

        def physics() -> None:
            if forces is not None:
                forces.save_user()
            for _ in range(self.substeps):
                if limiter is not None:
                    limiter.launch()
                if pose:
                    mjw.kinematics(self.model, self.data)
                if forces is not None:
                    forces.launch()
                mjw.step(self.model, self.data)
                if free_bodies is not None:
                    free_bodies.launch()
            if forces is not None:
                forces.end_step()

        # One graph per variant: the force kernel (and its pose refresh) costs nothing until forces are used.
        self._run("physics" + ("+forces" if forces is not None else "") + ("+pose" if pose else ""), physics,
                  keep_state=True)
        self.physics_steps += self.substeps

    def forward(self) -> None:
        """Recompute every derived quantity (kinematics, contacts, sensors) from qpos/qvel/ctrl."""
        self._run("forward", lambda: mjw.forward(self.model, self.data))

    def refresh_kinematics(self) -> None:
        """Recompute body poses (xpos, xquat, ...) after writing qpos, without collisions or dynamics."""
        if torch.compiler.is_compiling():  # traced into the compiled step as one op, not a graph break
            _kinematics_op(self._id, list(self._kinematics_state), list(self._kinematics_poses))
        else:
            self._run("kinematics", lambda: mjw.kinematics(self.model, self.data))

    def _kinematics_on(self, state: list[torch.Tensor], poses: list[torch.Tensor]) -> None:
        """The refresh as the compiled step's op runs it: from the values ``state`` into ``poses``. Compiled code may
        hand over a tensor of its own in place of the simulator's (a value it writes back later, or not at all):
        the refresh then reads or fills that one, and the simulator's is left as it was."""
        pairs = [*zip(self._kinematics_state, state), *zip(self._kinematics_poses, poses)]
        moved = [(mine, given, mine.clone()) for mine, given in pairs if given.data_ptr() != mine.data_ptr()]
        for mine, given, _ in moved:
            mine.copy_(given)
        self._run("kinematics", lambda: mjw.kinematics(self.model, self.data))
        for mine, given, kept in moved:
            given.copy_(mine)  # the poses computed (the state read is unchanged)
            mine.copy_(kept)

    def recapture(self) -> None:
        """Drop captured graphs; call after replacing Model arrays or changing solver options."""
        self._graphs.clear()
