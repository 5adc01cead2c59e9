"""bench/bench_legacy.py's report logic (the bench itself is run by a command, not here)."""

import importlib.util
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_legacy.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_legacy", BENCH)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_one_run_is_not_called_identical():
    """Finding 10: with --repeat 1 nothing was compared, so nothing is claimed."""
    text = _bench().identical_text
    assert text(None, 1) == "not checked (1 run)"
    assert text(True, 1) == "not checked (1 run)"
    assert text(True, 3) == "True (3 runs)" and text(False, 2) == "False (2 runs)"
