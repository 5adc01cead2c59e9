"""Launches interleaved on one board (issue 33, host/hil/interleave.py): the next window's
request on the line while the board works takes the decisions of the launches one after
another, in less board time, on both MCUs; the refusals; a stop with windows on the board."""

import dataclasses
import shutil

import pytest

from snan_hil.calibration.control import ControlledClient
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.inprocess import emulator_of
from snan_hil.host.hil.runner import run_scenario
from snan_hil.host.hil.testing import make_weights, program_set, small_hil_config
from snan_hil.protocol import messages as m
from snan_hil.records.control import StopRequested
from snan_hil.tools.ports import open_client

HIL = small_hil_config(max_steps=12)


@pytest.fixture(scope="module")
def programmed(tmp_path_factory):
    """One weight set programmed on a fresh chip: (folder, weights, state file, layout)."""
    folder = tmp_path_factory.mktemp("interleave")
    wpath = make_weights(folder / "w.npz", sets=1, cycles=2, hil=HIL)
    client = open_client("emu", state_file=str(folder / "chip.npz"), seed=0)
    try:
        layout = program_set(client, wpath, 0, folder / "layout.json")
    finally:
        client.close()
    w, _ = load_weight_set(wpath, 0)
    return folder, w, folder / "chip.npz", layout


def _client(programmed, tag, mcu="model"):
    folder, _w, state, _layout = programmed
    copy = folder / f"chip-{tag}-{mcu}.npz"
    shutil.copy(state, copy)
    return open_client("emu", 115200, state_file=str(copy), seed=0, mcu=mcu)


def _run(programmed, client, interleave, launches=3, **kw):
    _folder, w, _state, layout = programmed
    return [run_scenario(s, w, HIL, launches=launches, seed=3, client=client, layout=layout,
                         mode="on_board", baud=115200, interleave=interleave, **kw)
            for s in ("hw_noastro", "hw_astro")]


@pytest.mark.parametrize("mcu", ["model", "firmware"])
def test_interleaved_launches_take_the_decisions_they_take_one_after_another(programmed, mcu):
    if mcu == "firmware":
        pytest.importorskip("unicorn")
        from snan_hil.firmware_emu import mik32_native
        from snan_hil.firmware_emu.fw_image import default_elf_path
        if not default_elf_path().is_file() or mik32_native.load() is None:
            pytest.skip("firmware ELF or native MCU core not built ('make firmware')")
    runs, handed = {}, {}
    for inter in (False, True):
        client = _client(programmed, f"i{inter}", mcu)
        seen = []
        try:
            runs[inter] = _run(programmed, client, inter,
                               on_launch=lambda r, seen=seen: seen.append(r.launch))
            emu = emulator_of(client.transport)
            if emu.backend is not None:
                assert emu.backend.mcu.faults == {}        # no host byte lost on the chip
            assert client.counters_dict()["retries"] == 0
        finally:
            client.close()
        handed[inter] = seen
    one, two = runs[False], runs[True]
    assert [[r.path for r in s.launches] for s in two] == \
        [[r.path for r in s.launches] for s in one]
    decisions = sum(r.decisions for s in one for r in s.launches)
    assert decisions > 10
    # the board's clock (wire included) over the scenario: shorter interleaved
    t_one = sum(r.virtual_us for s in one for r in s.launches)
    t_two = sum(r.virtual_us for s in two for r in s.launches)
    assert t_two < 0.95 * t_one
    assert handed[True] == handed[False] == [0, 1, 2, 0, 1, 2]   # in launch order


def test_interleaving_needs_the_pipeline_and_the_lean_plan(programmed):
    client = _client(programmed, "refuse")
    try:
        with pytest.raises(UserError, match="lean read plan"):
            _run(programmed, client, True, launches=1, conversions=0)
        # the standard reads run one after another by default
        assert _run(programmed, client, None, launches=2, conversions=0)[0].launches
        inner = client.inner if hasattr(client, "inner") else client
        inner.info = dataclasses.replace(inner.info, capabilities=inner.info.capabilities
                                         & ~int(m.Capability.PIPELINE))
        with pytest.raises(UserError, match="PIPELINE"):
            _run(programmed, client, True, launches=1)
        assert _run(programmed, client, None, launches=2)[0].launches   # an older board
    finally:
        client.close()


def test_a_stop_with_windows_on_the_board_collects_them(programmed):
    client = _client(programmed, "stop")
    submits = []

    def check():
        submits.append(1)
        if len(submits) == 7:
            raise StopRequested("stop requested")

    try:
        controlled = ControlledClient(client, check)
        _folder, w, _state, layout = programmed
        with pytest.raises(StopRequested):
            run_scenario("hw_astro", w, HIL, launches=4, seed=3, client=controlled,
                         layout=layout, mode="on_board", baud=115200)
        link = client.inner if hasattr(client, "inner") else client
        assert link.outstanding == 0 and not link.pipelined   # nothing left on the board
        assert client.status().spikes_applied > 0             # the link goes on
    finally:
        client.close()
