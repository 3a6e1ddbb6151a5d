"""Warp start-up: quiet initialisation, and every kernel module a simulator needs compiled in parallel up front.

MuJoCo Warp builds its kernels for the model at hand while ``step`` runs, and Warp compiles each module the first
time one of its kernels launches: one module after another, dozens of them. ``load_kernels`` instead runs the
simulator's entry points once with launches recorded rather than executed, then compiles and loads the recorded
modules on a pool of threads (what ``wp.force_load(max_workers=...)`` does), printing a progress line every few
seconds (with an estimate of the time left once the pace is known) and one line when done, which says how many
modules were compiled and how many read back from Warp's kernel cache. Warp's own line per module is shown only
with ``verbose``. The calling thread is free while the pool works: ``KernelLoad`` starts the pool in the background
(the simulator does so as soon as its model and data exist, so that the task builds the rest of itself meanwhile),
and ``alongside`` runs in the waiting thread (VecTask compiles its post-physics step with torch.compile, CPU work of
the same size, so that a cold start pays the longest of the three rather than their sum).
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from typing import Callable, Sequence

import warp as wp

_PREFIX = "[isaacgymenvs_mw]"
_CUDA_DRIVER_WARNING = b"Could not find or load the NVIDIA CUDA driver"
_PROGRESS_EVERY_S = 5.0  # a progress line at most this often while modules compile

_state = {"verbose": False}
_loaded: set[tuple[object, object, object]] = set()  # (module, device, block_dim) loaded in this process
# One load compiles at a time: two simulators built one after the other must not compile the same module at once
# (Warp builds a module in a folder named after it); the second finds the first's modules loaded.
_compile_lock = threading.Lock()


def set_verbose(verbose: bool) -> None:
    """``verbose=True`` shows Warp's start-up banner and its line per loaded module; False only warnings."""
    _state["verbose"] = bool(verbose)
    wp.config.log_level = wp.LOG_INFO if verbose else wp.LOG_WARNING


set_verbose(False)


def init_warp(device: str) -> None:
    """``wp.init()``; on a CPU-only run, without Warp's "could not load the NVIDIA CUDA driver" warning.

    Warp's native library prints that warning to the C-level stderr while it looks for CUDA, on every machine
    without a GPU driver. When the simulator runs on the CPU nothing is lost by not finding one, so the line is
    dropped; anything else written meanwhile is passed on unchanged. Runs asking for a GPU keep it.
    """
    if wp._src.context.runtime is not None or str(device).startswith("cuda") or _state["verbose"]:
        wp.init()
        return
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            captured.seek(0)
            kept = [line for line in captured.read().splitlines(keepends=True) if _CUDA_DRIVER_WARNING not in line]
    if kept:
        sys.stderr.buffer.write(b"".join(kept))
        sys.stderr.flush()


def kernel_cache_dir(device: str) -> str:
    """The folder of Warp's kernel cache (``WARP_CACHE_PATH``, else Warp's default under the user's cache folder),
    which Warp knows once it is initialised."""
    init_warp(device)
    return str(wp.config.kernel_cache_dir)


def _record_launches(entry_points: Sequence[Callable[[], None]]) -> list[tuple[object, int | None]]:
    """Run ``entry_points`` with every kernel launch recorded instead of executed: (module, block_dim) pairs.

    MuJoCo Warp's step is capturable in a CUDA graph, so its Python side does not depend on device values; the
    only loops over device values are ``capture_while``/``capture_if``, whose bodies are run once here (both
    branches of an ``if``) so that their kernels are recorded too. Copies and fills still run, which is why the
    entry points work on scratch data.

    MuJoCo Warp sizes some launches with ``wp.get_suggested_block_size``, which on CUDA compiles the kernel's
    module then and there, in this thread: on a heightfield (the convex collision kernels) that is about a minute
    of a cold AnymalTerrain start on a GPU, spent before the parallel load could begin. During the recording the query
    returns a stand-in size and records the module with the default block size, the variant the real query loads.
    """
    found: dict[tuple[object, int | None], None] = {}

    def record(kernel, dim=None, *args, block_dim: int | None = None, **kwargs) -> None:
        if math.prod([dim] if isinstance(dim, int) else (dim or [0])) == 0:
            return  # Warp skips an empty launch without loading its module
        module = getattr(kernel, "module", None)
        if module is not None and not getattr(kernel, "is_generic", False):
            found[(module, block_dim)] = None

    def run_while(condition, while_body, stream=None, **kwargs) -> None:
        if callable(while_body):
            while_body(**kwargs)

    def run_if(condition, on_true=None, on_false=None, stream=None, **kwargs) -> None:
        for branch in (on_true, on_false):
            if callable(branch):
                branch(**kwargs)

    def suggest_block_size(kernel, device=None) -> tuple[int, int]:
        device = device if hasattr(device, "is_cuda") else wp.get_device(device)
        if not device.is_cuda:
            return (1, 1)  # what Warp answers on the CPU, without loading anything
        if not getattr(kernel, "is_generic", False):
            found[(kernel.module, None)] = None
        return (256, max(1, int(device.sm_count)))  # any plausible size: recorded launches do not run

    names = ("launch", "launch_tiled", "capture_while", "capture_if", "get_suggested_block_size")
    saved = {name: getattr(wp, name) for name in names}
    wp.launch, wp.launch_tiled, wp.capture_while, wp.capture_if = record, record, run_while, run_if
    wp.get_suggested_block_size = suggest_block_size
    try:
        for fn in entry_points:
            fn()
    finally:
        for name, fn in saved.items():
            setattr(wp, name, fn)
    return list(found)


def _pin_cache_names(pending: Sequence[tuple[object, int | None]], device: wp.context.Device) -> None:
    """Name every pending module's cache entry now, in this thread, before the pool starts.

    Warp names a module's cache folder and files after its content hash (and, on the CPU, a hash of the compile
    target), computes both on first need and keeps them until the module changes. Left to the pool, each is
    computed by whichever thread reaches the module first, interleaved with other modules' code generation and
    with the process's first look-ups of the CPU target; computed here, once, they come from the state right after
    the recording, the same in every process, so a later process finds what this one writes. A Warp without these
    names only loses the pinning: the pool computes them as before."""
    context = wp._src.context
    resolve = getattr(context, "_resolve_launch_block_dim", None)
    for module, block_dim in pending:
        try:  # the variant force_load will load: on the CPU an omitted block size is one, as for a launch
            dim = resolve(device, block_dim) if resolve is not None else block_dim
            module._get_compile_output_name(device, block_dim=dim)  # content hash, then the target's name
        except Exception:  # noqa: BLE001  (a Warp that names them otherwise: nothing is pinned, nothing else)
            return


def _cache_files() -> dict[str, set[str]]:
    """The kernel cache's files by module folder (Warp keeps a module's binaries and metadata in a folder named
    after its identifier), read before a load: a module whose folder gains a file was compiled, not read back."""
    cache = wp.config.kernel_cache_dir
    try:
        entries = os.listdir(cache) if cache else []
    except OSError:
        return {}
    return {entry: _folder_files(entry) for entry in entries}


def _folder_files(folder: str) -> set[str]:
    try:
        return set(os.listdir(os.path.join(wp.config.kernel_cache_dir, folder)))
    except OSError:  # not a folder, or not there (yet)
        return set()


def _load_one(module, device: wp.context.Device, block_dim: int | None, before: dict[str, set[str]]) -> bool | None:
    """Load ``module`` on ``device`` (compiled, or read from the kernel cache); returns whether it was compiled now
    (its cache folder gained a file), or None where this Warp does not say which folders are the module's."""
    known = set(module.execs)
    wp.force_load(device=device, modules=[module], block_dim=block_dim, max_workers=0)
    try:
        folders = {module.get_module_identifier(key[1]) for key in set(module.execs) - known}
    except Exception:  # noqa: BLE001  (a Warp without these names: the count is left out, nothing else)
        return None
    return any(_folder_files(folder) - before.get(folder, set()) for folder in folders)


def module_work(module) -> int:
    """How much compiling ``module`` takes, in characters of its kernels' source: the time to compile MuJoCo Warp's
    modules on the CPU follows it (correlation 0.95 over Cartpole's 33; from 0.1 s for 800 characters to 5 s for
    60,000), where the count of modules does not (one module of 33 was half the work)."""
    kernels = getattr(module, "kernels", None) or {}
    sources = kernels.values() if hasattr(kernels, "values") else kernels
    return max(1, sum(len(getattr(getattr(k, "adj", None), "source", "") or "") for k in sources))


# An estimate of the time left is given once at least this share of the work is done: before, Warp's one-off
# start-up and the modules every thread is busy with weigh more than the pace of the work.
_ESTIMATE_AFTER = 0.1


def time_left(work_done: float, work_left: float, elapsed: float) -> float | None:
    """Seconds until the modules of ``work_left`` are ready, at the pace at which ``work_done`` was (``module_work``
    units, compiled modules only: one read back from the cache takes milliseconds); None while no estimate is sound.

    Counting modules misleads, because their compile times differ widely: on a GPU host 1 of 42 modules can be ready
    after 16 s and the other 41 within the next 5 s (elapsed time per module would say 648 s left); on 2 CPU cores,
    6 of 33 after 7 s and the rest within 4 s (it would say 30 s)."""
    if work_left <= 0:
        return 0.0
    if work_done <= 0 or work_done < _ESTIMATE_AFTER * (work_done + work_left):
        return None
    return elapsed * work_left / work_done


def load_kernels(device: wp.context.Device, entry_points: Sequence[Callable[[], None]],
                 max_workers: int | None = None, alongside: Callable[[], None] | None = None) -> int | None:
    """Compile/load every module the entry points launch, on ``max_workers`` threads (default: all cores).

    ``alongside`` is called once in this thread while the pool compiles (also when there is nothing to load); it
    must not launch Warp kernels. An exception from it or from a module's compilation is raised here, unchanged,
    once the modules already compiling are done; the ones not yet started are dropped (a Ctrl-C does not wait for
    them either).

    Returns how many modules were loaded now (0 when all were already loaded in this process), or None when the
    dry run failed and nothing was recorded. Anything the recording misses is still compiled on first use, as
    Warp always does, so this can only save time.
    """
    return KernelLoad(device, entry_points, max_workers).wait(alongside)


class KernelLoad:
    """``load_kernels`` in two halves: the constructor records the entry points' modules (in this thread: the
    recording replaces ``wp.launch`` while it runs) and starts compiling them on a pool of threads, in the
    background; ``wait`` joins it. In between, this thread is free to build the rest of the task. Its own Warp
    launches must not need the pending modules (two threads compiling one module would share its build folder):
    the simulator waits before any launch of its own.
    """

    def __init__(self, device: wp.context.Device, entry_points: Sequence[Callable[[], None]],
                 max_workers: int | None = None) -> None:
        self.device = device
        try:
            recorded = _record_launches(entry_points)
        except Exception as err:  # noqa: BLE001  (a dry run that fails only loses the head start)
            if _state["verbose"]:
                print(f"{_PREFIX} Warp kernels load on first use ({type(err).__name__}: {err})", flush=True)
            recorded = None
        self.recorded = recorded is not None
        self.pending = [(m, bd) for m, bd in recorded or () if (m, str(device), bd) not in _loaded]
        _pin_cache_names(self.pending, device)
        self.workers = max(1, int(max_workers or os.cpu_count() or 1))
        self._stop = threading.Event()  # set when the waiting thread gives up: drop the modules not yet started
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._compile, name="warp-kernel-load", daemon=True)
        if self.pending:
            self._thread.start()

    def wait(self, alongside: Callable[[], None] | None = None) -> int | None:
        """Run ``alongside`` in this thread, then wait for the modules; raise the first error of either (the
        modules already compiling finish first). Returns what ``load_kernels`` returns."""
        try:
            if alongside is not None:
                alongside()
        except BaseException:
            self._stop.set()
            self._join()
            raise
        self._join()
        if self._error is not None:
            raise self._error
        if not self.pending:
            return 0 if self.recorded else None
        return len(self.pending)

    def _join(self) -> None:
        if not self._thread.is_alive():
            return
        try:
            while self._thread.is_alive():
                self._thread.join(timeout=0.5)  # in slices: a Ctrl-C here is taken at once
        except BaseException:
            self._stop.set()
            raise

    def _compile(self) -> None:
        with _compile_lock:
            self.pending = [(m, bd) for m, bd in self.pending if (m, str(self.device), bd) not in _loaded]
            if self.pending:
                self._compile_pending()

    def _compile_pending(self) -> None:
        device, pending = self.device, self.pending
        before = _cache_files()
        start = last_print = time.perf_counter()
        work = {(m, bd): module_work(m) for m, bd in pending}
        # Per module ready: when (Warp's own time, whatever else runs meanwhile), whether it was compiled now, its work.
        ready: list[tuple[float, bool | None, int]] = []

        def load(module, block_dim: int | None) -> bool | None:
            compiled = _load_one(module, device, block_dim, before)
            ready.append((time.perf_counter(), compiled, work[module, block_dim]))
            return compiled

        try:
            with ThreadPoolExecutor(max_workers=self.workers) as pool:
                futures = [pool.submit(load, m, bd) for m, bd in pending]
                try:
                    for future in _completed(futures, self._stop):
                        future.result()
                        now, done = time.perf_counter(), sum(f.done() for f in futures)  # all ready by now
                        if done < len(futures) and now - last_print >= _PROGRESS_EVERY_S:
                            # A module compiling now is counted half done: the big ones take seconds each.
                            busy = sum(work[key] for key, f in zip(pending, futures) if f.running()) / 2
                            done_work = sum(w for _, compiled, w in list(ready) if compiled is not False) + busy
                            left_work = sum(work.values()) - sum(w for *_, w in list(ready)) - busy
                            left = time_left(done_work, left_work, now - start)
                            guess = "" if left is None else f", about {left:.0f} s left"
                            print(f"{_PREFIX} Warp kernels on {device}: {done}/{len(futures)} modules ready after "
                                  f"{now - start:.0f} s{guess}", flush=True)
                            last_print = now
                except BaseException:
                    pool.shutdown(wait=False, cancel_futures=True)  # the with-block still waits for the running ones
                    raise
            compiled = [f.result() for f in futures]
        except BaseException as err:  # noqa: BLE001  (handed to the waiting thread)
            self._error = err
            return
        _loaded.update((m, str(device), bd) for m, bd in pending)
        took = max(t for t, *_ in ready) - start
        print(f"{_PREFIX} Warp kernels on {device}: {len(pending)} modules ready in {took:.1f} s "
              f"({load_detail(compiled, self.workers, wp.config.kernel_cache_dir)})", flush=True)


def load_detail(compiled: Sequence[bool | None], workers: int, cache: str) -> str:
    """How the modules of a load were made ready: how many were compiled, how many read from the cache."""
    if any(c is None for c in compiled):
        return f"compiled or read from the cache {cache} on {workers} threads"
    count = sum(bool(c) for c in compiled)
    if not count:
        return f"all from the cache {cache}"
    return f"{count} compiled on {workers} threads, {len(compiled) - count} from the cache {cache}"


class _Stopped(Exception):
    """The waiting thread gave up (its own error or a Ctrl-C): modules not yet started are dropped."""


def _completed(futures: list, stop: threading.Event):
    """``as_completed(futures)``, checking ``stop`` between completions (and at least every half second)."""
    remaining = set(futures)
    while remaining:
        if stop.is_set():
            raise _Stopped()
        done, remaining = wait(remaining, timeout=0.5, return_when=FIRST_COMPLETED)
        yield from done
