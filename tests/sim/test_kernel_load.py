"""The kernel line: how many modules were compiled and how many read from the cache (never a negative count), and
the time left while they compile, estimated from the work left (or not said while no estimate is sound).

The counts are checked on real Warp modules compiled on the CPU into a kernel cache of the test's own, so that the
expectation (compiled on the first load, read back on the second, one of two after its cache folder was removed)
does not depend on what ~/.cache/warp holds.
"""

from __future__ import annotations

import re
import shutil
import threading

import pytest
import warp as wp

from isaacgymenvs_mw.sim import kernels


@wp.kernel(module="unique")
def _double(x: wp.array(dtype=float)):
    i = wp.tid()
    x[i] = 2.0 * x[i]


@wp.kernel(module="unique")
def _shift(x: wp.array(dtype=float), by: float):
    i = wp.tid()
    x[i] = x[i] + by + 0.5 * wp.sin(x[i]) * wp.cos(by)


MODULES = (_double.module, _shift.module)


def _entry_point() -> None:
    x = wp.zeros(4, dtype=float, device="cpu")
    wp.launch(_double, dim=4, inputs=[x], device="cpu")
    wp.launch(_shift, dim=4, inputs=[x, 1.0], device="cpu")


def _load(capsys, alongside=None) -> str:
    """Load both modules afresh (unloaded from this process first) and return the line the load printed."""
    for module in MODULES:
        module.unload()
    kernels._loaded.difference_update({key for key in kernels._loaded if key[0] in MODULES})
    capsys.readouterr()
    assert kernels.load_kernels(wp.get_device("cpu"), [_entry_point], max_workers=2, alongside=alongside) == 2
    (line,) = [ln for ln in capsys.readouterr().out.splitlines() if "modules ready in" in ln]
    return line


@pytest.fixture
def own_cache(tmp_path, monkeypatch):
    wp.init()
    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(tmp_path))
    yield tmp_path
    for module in MODULES:
        module.unload()  # later tests load them from the usual cache again


def test_compiled_and_cached_modules_are_counted_by_module(own_cache, capsys):
    def another_module_compiled_meanwhile():
        # The negative count's cause: the old count was every new entry of the cache folder, whoever wrote it.
        (own_cache / "wp_elsewhere_0123456").mkdir()
        (own_cache / "wp_elsewhere_0123456" / "wp_elsewhere_0123456.meta").write_text("{}")

    line = _load(capsys, alongside=another_module_compiled_meanwhile)
    assert re.search(rf"2 modules ready in [\d.]+ s \(2 compiled on 2 threads, 0 from the cache {own_cache}\)$", line)

    assert _load(capsys).endswith(f"(all from the cache {own_cache})")

    (shift_folder,) = own_cache.glob(f"wp_{_shift.module.name}_*")  # Warp's folder of the module's binaries
    shutil.rmtree(shift_folder)
    assert _load(capsys).endswith(f"(1 compiled on 2 threads, 1 from the cache {own_cache})")


def test_every_module_is_hashed_in_the_calling_thread_before_the_pool_starts(own_cache, capsys, monkeypatch):
    # Warp names a module's cache folder after its content hash. Computed by a pool thread, it could depend on what
    # the other threads' code generation was doing at the time (issue 61); the load computes each before the pool.
    hashed_by: list[tuple[str, int]] = []
    original = wp._src.context.ModuleHasher.__init__

    def recording_init(self, live_kernels, options):
        hashed_by.extend((k.module.name, threading.get_ident()) for k in live_kernels)
        original(self, live_kernels, options)

    monkeypatch.setattr(wp._src.context.ModuleHasher, "__init__", recording_init)
    _load(capsys)
    names = {m.name for m in MODULES}
    assert {name for name, _ in hashed_by} >= names  # both were hashed afresh (unloaded first)...
    assert {ident for name, ident in hashed_by if name in names} == {threading.get_ident()}  # ...in this thread
    # and under the names their cache folders have.
    folders = {p.name for p in own_cache.iterdir()}
    assert {m.get_module_identifier(1) for m in MODULES} <= folders


def test_load_detail_counts_never_go_below_zero():
    assert kernels.load_detail([True, False, False], 2, "C") == "1 compiled on 2 threads, 2 from the cache C"
    assert kernels.load_detail([False, False], 4, "C") == "all from the cache C"
    assert kernels.load_detail([True, None], 4, "C") == "compiled or read from the cache C on 4 threads"


def test_module_work_follows_the_source():
    assert kernels.module_work(_shift.module) > kernels.module_work(_double.module) > 1


@pytest.mark.parametrize("done, left, elapsed, expected", [
    (50.0, 50.0, 10.0, 10.0),   # half the work in 10 s: 10 s more
    (25.0, 75.0, 5.0, 15.0),
    (10.0, 90.0, 2.0, 18.0),    # a tenth done: the first estimate
    (9.0, 91.0, 2.0, None),     # less: Warp's start-up and the modules in hand outweigh the pace
    (0.0, 100.0, 16.0, None),   # nothing compiled yet (only modules from the cache, or none at all)
    (2.0, 98.0, 16.0, None),    # the H100 case: 1 small module of 42 after 16 s said "about 648 s left"
    (80.0, 0.0, 9.0, 0.0),
])
def test_time_left_is_the_work_left_at_the_pace_of_the_work_done(done, left, elapsed, expected):
    got = kernels.time_left(done, left, elapsed)
    assert got == (None if expected is None else pytest.approx(expected))
