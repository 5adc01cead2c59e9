"""Session set-up shared by the test modules."""

import sys
import time


def pytest_collection_finish(session):
    """Compile (or load from numba's cache) the trial kernel once, before any test runs, if a
    collected test module uses it: a cold compile takes ~40 s (more on a busy machine) and
    must not count against the first test's timeout."""
    if "snan_hil.host.snan_kernel" not in sys.modules or not session.items:
        return
    from snan_hil.host.config import load_config
    from snan_hil.host.simulate import simulate

    t0 = time.perf_counter()
    simulate(load_config(preset="snan-3x3", overrides=["grid.max_steps=3"]), 1, 0)
    took = time.perf_counter() - t0
    if took > 5:
        session.config.get_terminal_writer().line(
            f"trial kernel compiled in {took:.0f} s (numba cache was cold)")
