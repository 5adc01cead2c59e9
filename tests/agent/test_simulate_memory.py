"""The memory estimate of a simulation batch, and the refusal of batches that do not fit."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from snan_hil.host.config import apply_overrides, load_config
from snan_hil.host.simulate import memory_estimate
from snan_hil.tools import cli
from snan_hil.tools import resources

MEASURE = """
import gc
from snan_hil.host.config import apply_overrides, load_config
from snan_hil.host.simulate import simulate

def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1]) * 1024

cfg = load_config(preset="snan-10x10")
simulate(cfg, 2, 1)                      # compiled (a cold numba cache peaks far higher)
gc.collect()
with open("/proc/self/clear_refs", "w") as fh:
    fh.write("5")                        # reset the peak (VmHWM) to the current RSS
base = status("VmRSS")
simulate(apply_overrides(cfg, ["grid.rows=250", "grid.cols=250"]), 4, 1)
print(status("VmHWM") - base)
"""


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"),
                    reason="needs Linux's /proc/self/clear_refs to reset the peak RSS")
def test_estimate_matches_the_measured_peak():
    """Peak RSS growth of a 250x250 batch of 4 trials (~30 MB of data) in a fresh process."""
    out = subprocess.run([sys.executable, "-c", MEASURE], capture_output=True, text=True,
                         timeout=300, check=True)
    measured = int(out.stdout.split()[-1])
    cfg = apply_overrides(load_config(preset="snan-10x10"), ["grid.rows=250", "grid.cols=250"])
    assert measured == pytest.approx(memory_estimate(cfg, 4), rel=0.15)


def test_estimate_grows_with_cells_trials_and_steps():
    cfg = load_config(preset="snan-10x10")
    big = apply_overrides(cfg, ["grid.rows=10000", "grid.cols=10000"])
    assert memory_estimate(big, 1) == pytest.approx(35.2e9, rel=0.01)      # issue 13's case
    assert memory_estimate(cfg, 2000) - memory_estimate(cfg, 1000) == \
        1000 * (33 + 8 * 1001 + 64 * 100)


def test_sim_refuses_a_batch_that_does_not_fit_with_the_estimate(monkeypatch, capsys):
    monkeypatch.setattr(resources, "available_memory", lambda: 4_000_000_000)

    def never(*args, **kwargs):
        raise AssertionError("simulate started")
    monkeypatch.setattr("snan_hil.tools.commands.sim.simulate", never)
    assert cli.main(["sim", "--grid", "10000", "--trials", "1"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == ("snan-hil sim: error: a 10000x10000 grid with 1 trial(s) needs about "
                           "35.2 GB of memory, 4.0 GB is available; use a smaller --grid or "
                           "fewer --trials")
    assert cli.main(["demo", "--software-only", "--trials", "2000000"]) == 2
    assert "2000000 trials of snan-10x10 needs about" in capsys.readouterr().err


def test_a_batch_that_fits_runs(monkeypatch, capsys):
    monkeypatch.setattr(resources, "available_memory", lambda: 4_000_000_000)
    assert cli.main(["sim", "--grid", "3", "--trials", "5", "--json"]) == 0


def test_train_refuses_a_grid_whose_weights_do_not_fit(monkeypatch, capsys, tmp_path):
    """train holds two dense sets x N x N weight stacks: refused before any training, with the
    estimate (issue 27 item 11: train --grid 2000 ran out of memory with a traceback)."""
    monkeypatch.setattr(resources, "available_memory", lambda: 4_000_000_000)

    def never(*args, **kwargs):
        raise AssertionError("training started")
    monkeypatch.setattr("snan_hil.tools.commands.train.train_sets", never)
    out = tmp_path / "w.npz"
    assert cli.main(["train", "--grid", "2000", "--sets", "1", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("snan-hil train: error: training 1 set(s) on a 2000x2000 grid needs "
                          "about 2560") and "4.0 GB is available" in err and "\n" not in err, err
    assert not out.exists()


def test_training_estimate_counts_the_two_dense_stacks():
    from snan_hil.host.hil.train import training_memory_estimate
    cfg = apply_overrides(load_config(preset="snan-10x10"), ["grid.rows=6", "grid.cols=6"])
    one, three = training_memory_estimate(cfg, 1), training_memory_estimate(cfg, 3)
    assert three - one == 2 * 2 * 36 * 36 * 8
    assert one > 2 * 36 * 36 * 8
