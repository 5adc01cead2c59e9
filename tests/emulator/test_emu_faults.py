"""Faulty emulated boards on purpose (firmware_emu/faults.py): the option's grammar, and each
fault where it lives - the SPI chips, the front end, the UART - on both MCUs."""

from __future__ import annotations

import pytest

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.faults import BoardFaults, parse_faults
from snan_hil.firmware_emu.protocol_emu import EmuUrl, emu_url
from snan_hil.lab.ports import open_client


def test_defaults_and_arguments_parse():
    f = parse_faults(["adc-stuck-bit", "gain:0.9,swap-col-lines:0:3", "slow-dac:DAC3:12.5",
                      "uart-drop:0.1", "dead-cells:1-2:0-7"])
    assert f.adc_stuck_bit == (6, 1) and f.gain_factor == 0.9
    assert f.swapped_col_lines == (0, 3) and f.slow_dac == (3, 12.5)
    assert f.uart_drop == 0.1 and f.dead_cells == (1, 2, 0, 7)
    assert f.analog and f.any and len(f.specs) == 6
    assert not BoardFaults().any


@pytest.mark.parametrize("spec, words", [
    ("nosuch", "unknown fault 'nosuch'"), ("adc-stuck-bit:14:1", "BIT 0..13"),
    ("adc-stuck-bit:3:2", "VALUE 0 or 1"), ("gain:0", "0 < FACTOR"),
    ("swap-col-lines:4:4", "two lines"), ("slow-dac:DAC9", "DAC0"),
    ("uart-drop:1.5", "0 < P < 1"), ("dead-cells:5-40:0-1", "outside 0..31"),
    ("dead-cells:a-b", "range like"),
])
def test_bad_specs_are_one_line(spec, words):
    with pytest.raises(UserError, match=words.replace("(", r"\(").replace("+", r"\+")):
        parse_faults(spec)


def test_the_url_carries_the_faults():
    url = emu_url(seed=1, faults=parse_faults("gain:0.8,uart-drop:0.05"))
    parsed = EmuUrl.parse(url)
    assert parsed.faults.gain_factor == 0.8 and parsed.faults.uart_drop == 0.05
    with pytest.raises(Exception, match="unknown fault"):
        EmuUrl.parse("emu://?fault=bogus")


def _reads(tmp_path, mcu, fault=""):
    url = f"emu://?state={tmp_path}/{fault or 'ok'}.npz&seed=3" + \
        (f"&mcu={mcu}" if mcu != "model" else "") + (f"&fault={fault}" if fault else "")
    client = open_client(url)
    try:
        one = [0] * 32
        one[9] = 245
        return {"zero": client.read_cell(9, 2, 0), "cell": client.read_cell(9, 2),
                "column": client.read_column(2, one), "retries": client.counters_dict()["retries"]}
    finally:
        client.close()


def test_each_fault_changes_what_the_board_measures_on_both_mcus(tmp_path, mcu):
    ok = _reads(tmp_path, mcu)
    assert ok["zero"] <= 2 and ok["retries"] == 0
    assert _reads(tmp_path, mcu, "adc-stuck-bit:6:1")["zero"] == 64 + ok["zero"]
    assert _reads(tmp_path, mcu, "gain:0.8")["cell"] == pytest.approx(0.8 * ok["cell"], rel=0.02)
    swapped = _reads(tmp_path, mcu, "swap-col-lines")            # SUM_PATH <-> POL_SET
    assert swapped["cell"] == pytest.approx(ok["cell"], rel=0.02)
    assert swapped["column"] == pytest.approx(ok["column"] * 3000 / 330, rel=0.05)
    assert _reads(tmp_path, mcu, "slow-dac:DAC1:40")["column"] < 0.8 * ok["column"]
    dead = _reads(tmp_path, mcu, "dead-cells:8-15:2-3")
    assert dead["cell"] <= 2 and dead["column"] <= 2
    assert _reads(tmp_path, mcu, "uart-drop:0.05")["retries"] > 0
