"""How a ``train.py`` process stops on SIGTERM (``timeout``, schedulers' preemption) and SIGINT (Ctrl-C), from its
first line to its last.

One handler serves the whole process, installed by train.py before anything else is imported. What it does depends
on what the process is doing when the signal comes:

* **starting** (composing the config, building the model, compiling Warp's kernels) or **evaluating**: nothing
  exists that a stop could lose, so the handler raises ``StopRequested`` where the signal lands and train.py ends
  the process with one line and the signal's status (143 for SIGTERM);
* **training** (``StopProtocol.training``): it only records the signal on the runner, which stops at its next env
  step, saves ``model_<it>_interrupted.pt`` and writes summary.json. Raising inside library code (a compiled step, a
  CUDA graph, TensorBoard's queue) is how a stopped run could lose both.

A library loaded into the process can replace the handler behind Python's back: native code calling ``sigaction``
(Python's own view, ``signal.getsignal``, then still shows the old one) or Python code calling ``signal.signal``.
On a GPU both SIGTERM and SIGINT were taken over by native code while the post-physics step compiled (torch.compile
with Triton, whose LLVM registers its own handlers for them), and a signal in that window ended the run without its
stop line, checkpoint or summary. Two guards: a watchdog thread reads the C-level handler every
``WATCH_INTERVAL_S`` and writes ours back with ``sigaction`` the moment it differs (any thread may); and the runner
calls ``reassert`` once per iteration, which also catches a replacement made through Python, puts the handler back
and says once, in one line, what had replaced it (for native code: the library, from /proc/self/maps).

A signal can also land inside a finaliser (a Warp array's ``__del__`` freeing its memory during garbage collection),
where Python prints and swallows whatever is raised. The protocol's ``sys.unraisablehook`` catches a swallowed
``StopRequested`` and delivers the signal again to the main thread a moment later (``_thread.interrupt_main``), so the stop still
happens at once, at the next line outside the finaliser.

Only the main thread handles signals; a process that never calls ``install`` (the package used as a library) gets
the training behaviour for the duration of ``training`` and its own handlers back afterwards.
"""

from __future__ import annotations

import _thread
import ctypes
import ctypes.util
import functools
import signal
import sys
import threading
import time
from contextlib import contextmanager
from typing import Any, Iterator

SIGNALS = (signal.SIGTERM, signal.SIGINT)
WATCH_INTERVAL_S = 0.05  # how long a replaced C-level handler can stay in place: 20 reads of 2 signals per second
# A stop still under way this long after its signal is stuck (e.g. a compile waiting forever for Inductor workers
# the signal killed): the process prints every thread's stack and ends with the signal's status, so that
# a scheduler's job ends with a diagnosis instead of hanging until its SIGKILL. Saving a checkpoint and the summary
# takes seconds.
STOP_GRACE_S = 120.0
REDELIVER_AFTER_S = 0.01  # a signal discarded in a finaliser is delivered again this much later


class StopRequested(KeyboardInterrupt):
    """A stop asked for by a signal: raised where the signal lands while nothing can be lost, and by
    ``Runner.learn`` between env steps while training. A KeyboardInterrupt, so that code which cleans up after Ctrl-C
    cleans up after SIGTERM too."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


class StopProtocol:
    """The process's SIGTERM / SIGINT handler and its phases (see the module docstring).

    ``repeat_window_s``: a second SIGINT this long or longer after the first is a user insisting, and raises
    KeyboardInterrupt at once even while training. ``timeout -s INT`` sends one signal to the process and one to its
    process group within microseconds; both must count as one request. Repeated SIGTERMs are always ignored."""

    def __init__(self, repeat_window_s: float = 1.0, stop_grace_s: float = STOP_GRACE_S) -> None:
        self.repeat_window_s = repeat_window_s
        self.stop_grace_s = stop_grace_s
        self.signum: int | None = None  # the first signal received
        self._first_at = 0.0
        self._runner: Any = None  # while training: the object whose ``stop_signal`` the handler sets
        self._installed = False
        self._native: dict[int, int | None] = {}  # the C-level handler address right after installing
        self._handler = self._handle  # one bound method, so that signal.getsignal can be compared by identity
        self._actions: dict[int, ctypes.Array] = {}  # the C-level struct sigaction of ours, to write back
        self._taken: list[str] = []  # what the watchdog found in our place, reported once by ``reassert``
        self._watchdog: threading.Thread | None = None
        self._watch_lock = threading.Lock()
        self._watch_paused = 0  # > 0 while code of ours changes the disposition on purpose (watchdog_paused)
        self._swallowed = False  # our StopRequested was raised inside a finaliser, which discarded it
        self._previous_unraisablehook: Any = None

    @property
    def installed(self) -> bool:
        return self._installed

    def install(self) -> None:
        """Handle SIGTERM and SIGINT from now on (main thread only; elsewhere nothing changes). SIGINT is handled
        even where the process started with it ignored (a background job of a non-interactive shell)."""
        if threading.current_thread() is not threading.main_thread():
            return
        for signum in SIGNALS:
            signal.signal(signum, self._handler)
            self._native[signum] = native_handler(signum)
            action = read_sigaction(signum)
            if action is not None:
                self._actions[signum] = action
        self._installed = True
        if self._previous_unraisablehook is None:
            self._previous_unraisablehook = sys.unraisablehook
            sys.unraisablehook = self._unraisable
        if self._actions and self._watchdog is None:
            self._watchdog = threading.Thread(target=self._watch, name="stop-handler-watchdog", daemon=True)
            self._watchdog.start()

    def _watch(self) -> None:
        """Put our C-level handler back wherever native code replaced it (see the module docstring)."""
        while True:
            time.sleep(WATCH_INTERVAL_S)
            with self._watch_lock:
                if not self._installed or self._watch_paused:
                    continue  # not ours to guard now (the package used as a library, outside ``training``)
                if self.signum is not None and time.monotonic() - self._first_at > self.stop_grace_s:
                    self._give_up()
                for signum, action in self._actions.items():
                    current = native_handler(signum)
                    if current is not None and current != self._native.get(signum):
                        _libc_sigaction()(signum, action, None)
                        self._taken.append(f"{signal.Signals(signum).name} by native code "
                                           f"(sigaction: {_describe_native(current)})")

    def _give_up(self) -> None:
        """The stop is stuck (see STOP_GRACE_S): say so, print every thread's stack, end the process."""
        import faulthandler
        import os

        name = signal.Signals(self.signum).name
        print(f"[train] still running {self.stop_grace_s:.0f} s after {name}: the stop is stuck; every thread's stack "
              f"follows, then the process ends with status {128 + self.signum}", file=sys.stderr, flush=True)
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
        sys.stderr.flush()
        sys.stdout.flush()
        os._exit(128 + self.signum)

    @contextmanager
    def watchdog_paused(self) -> Iterator[None]:
        """While inside, the watchdog leaves the disposition alone: for code of ours that changes it on purpose
        (Inductor's compile workers start with SIGTERM ignored, see tasks/base/step_execution.py; a watchdog that
        wrote the handler back in that window let them start killable, and a signal then hung the run)."""
        with self._watch_lock:
            self._watch_paused += 1
        try:
            yield
        finally:
            with self._watch_lock:
                self._watch_paused -= 1

    def _unraisable(self, unraisable: Any) -> None:
        """``sys.unraisablehook``: a StopRequested raised inside a finaliser is not lost (see the module docstring);
        anything else goes to the hook that was there before."""
        if isinstance(unraisable.exc_value, StopRequested) and self._runner is None:
            self._swallowed = True
            # From another thread, a moment later: called here, the handler would run again inside this hook
            # and be discarded again. Should it land in a finaliser again, this hook repeats it.
            threading.Timer(REDELIVER_AFTER_S, _thread.interrupt_main, (unraisable.exc_value.signum,)).start()
            return
        self._previous_unraisablehook(unraisable)

    def _handle(self, signum: int, frame) -> None:
        if self.signum is None or self._swallowed:
            if self.signum is None:
                self.signum, self._first_at = signum, time.monotonic()
            self._swallowed = False
            if self._runner is None:
                raise StopRequested(self.signum)  # starting or evaluating: nothing to save, stop right here
            self._runner.stop_signal = self.signum
        elif signum == signal.SIGINT and time.monotonic() - self._first_at >= self.repeat_window_s:
            raise KeyboardInterrupt()

    @contextmanager
    def training(self, runner: Any) -> Iterator[None]:
        """While inside: a signal only sets ``runner.stop_signal``. A signal that came earlier and was not raised
        (it landed where it was caught) is handed to the runner at once."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        previous = None if self._installed else {s: signal.getsignal(s) for s in SIGNALS}
        if previous is not None:
            self.install()
        self._runner = runner
        if self.signum is not None and getattr(runner, "stop_signal", None) is None:
            runner.stop_signal = self.signum
        try:
            yield
        finally:
            self._runner = None
            if previous is not None:  # the package used as a library: the caller's handlers come back
                for signum, handler in previous.items():
                    signal.signal(signum, handler)
                sys.unraisablehook, self._previous_unraisablehook = self._previous_unraisablehook, None
                self._installed = False
                self.signum = None  # that run has answered its signal; the next one starts unstopped

    def reassert(self) -> str | None:
        """Put the handler back where something replaced it since ``install``; returns the one line that says what
        had (None when nothing had). Cheap: two ``sigaction`` reads per signal, no GPU work."""
        if not self._installed or threading.current_thread() is not threading.main_thread():
            return None
        found, self._taken = self._taken, []
        for signum in SIGNALS:
            python_side = signal.getsignal(signum)
            native = native_handler(signum)
            if python_side is not self._handler:
                found.append(f"{signal.Signals(signum).name} by {_describe(python_side)} (through Python)")
            elif native != self._native.get(signum):
                found.append(f"{signal.Signals(signum).name} by native code (sigaction: {_describe_native(native)})")
        if not found:
            return None
        self.install()
        return ("[train] the stop handler had been replaced (" + "; ".join(found) + "); it is back, so a signal "
                "still stops the run with its checkpoint and summary")


def read_sigaction(signum: int) -> ctypes.Array | None:
    """The process's whole C-level ``struct sigaction`` for ``signum`` (None where it cannot be read)."""
    sigaction = _libc_sigaction()
    if sigaction is None:
        return None
    buffer = ctypes.create_string_buffer(256)  # larger than any libc's struct sigaction
    return buffer if sigaction(signum, None, buffer) == 0 else None


def native_handler(signum: int) -> int | None:
    """The address of the process's C-level handler for ``signum`` (0: default, 1: ignored), read with
    ``sigaction``; None where it cannot be read (not Linux/glibc, or no libc found)."""
    action = read_sigaction(signum)
    return None if action is None else (ctypes.c_void_p.from_buffer(action).value or 0)  # sa_handler comes first


@functools.cache
def _libc_sigaction():
    """libc's ``sigaction`` through ctypes (Linux), looked up once; None where there is none to call."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        function = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True).sigaction
    except (OSError, AttributeError):
        return None
    function.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p]
    function.restype = ctypes.c_int
    return function


def _describe(handler) -> str:
    if handler is signal.SIG_DFL:
        return "the default action (the process dies)"
    if handler is signal.SIG_IGN:
        return "'ignore'"
    if handler is None:
        return "a handler not set from Python"
    return f"{getattr(handler, '__module__', '?')}.{getattr(handler, '__qualname__', repr(handler))}"


def _describe_native(address: int | None) -> str:
    if address is None:
        return "unreadable"
    if address in (0, 1):
        return "the default action, the process dies" if address == 0 else "ignored"
    return f"a handler at {address:#x} in {_library_of(address)}"


def _library_of(address: int) -> str:
    """The file mapped at ``address`` in this process (Linux), to name the library that took a signal."""
    try:
        with open("/proc/self/maps") as maps:
            for line in maps:
                fields = line.split()
                start, end = (int(x, 16) for x in fields[0].split("-"))
                if start <= address < end:
                    return fields[5] if len(fields) > 5 else "an anonymous mapping"
    except (OSError, ValueError, IndexError):
        pass
    return "an unknown mapping"


# The one protocol of a train.py process.
PROCESS_STOP = StopProtocol()
