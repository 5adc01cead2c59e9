"""The existing host software's traffic, replayed unchanged against ``snan-hil emu --protocol
legacy`` on a pty.

The traffic is written from the facts in shared/reference/memricore-board.md (nothing of the
existing host's code): pyserial at 115200 baud with its 75 ms read timeout; the connect probe
``7,0,0,0,0,0,0,0`` sent until a line of integers comes back (at most 20 times); the
board-information request ``100``; a map of every cell with mode 9 at code 246 (its "0.3 V");
then on a set of cells a RESET ramp and a SET ramp from 0.3 to 1.7 V in 0.01 V steps, each
volt value rounded to the nearest write-DAC code as the existing host does, 100 us pulses;
ids counting 1...4096, then 0, 1, ...; after a mode-7 pulse it reads a line, and if none came
within its timeout it waits the pulse's t_ms and reads once more.
"""

import os
import re
import signal
import subprocess
import sys
import time

import pytest
import serial

from snan_hil.protocol.board import MEMRICORE

TIMEOUT_S = 0.075                         # the existing host's read timeout
RAMP_V = [round(0.30 + 0.01 * k, 2) for k in range(141)]        # 0.30 ... 1.70 V
BAD_CELLS = {(12, 4), (21, 1), (24, 2)}   # stuck cells of the default chip (seed 0)


def host_code(volts: float) -> int:
    """The existing host's volts -> write-DAC code: nearest code, 5 V reference, 12 bits."""
    return int(round(volts * 4095 / 5.0))


class ExistingHost:
    """The existing host's side of the line, as the reference describes it."""

    def __init__(self, port: str):
        self.serial = serial.Serial(port, 115200, timeout=TIMEOUT_S)
        self.request_id = 0
        self.ids_sent: list[int] = []

    def pull(self) -> tuple[int, ...]:
        line = self.serial.readline()
        try:
            return tuple(int(x) for x in line.decode().strip().split(","))
        except ValueError:
            return ()

    def kick(self, attempts: int = 20) -> bool:
        for _ in range(attempts):
            self.serial.write(b"7,0,0,0,0,0,0,0\n")
            if self.pull():
                return True
        return False

    def tech_info(self) -> list[str]:
        self.serial.write(b"100\n")
        return self.serial.readline().decode().strip().split(",")

    def _next_id(self) -> int:
        self.request_id = (self.request_id + 1) % 4097
        self.ids_sent.append(self.request_id)
        return self.request_id

    def read(self, wl: int, bl: int) -> tuple[int, ...]:
        self.serial.write(f"9,246,{self._next_id()},{wl},{bl}\n".encode())
        return self.pull()

    def pulse(self, vol: int, t_ms: int, t_us: int, sign: int, wl: int, bl: int):
        self.serial.write(f"7,{vol},{t_ms},{t_us},{sign},{self._next_id()},{wl},{bl}\n"
                          .encode())
        res = self.pull()
        if not res:
            time.sleep(t_ms / 1000)
            res = self.pull()
        return res


@pytest.fixture
def served_legacy(tmp_path):
    env = dict(os.environ, SNAN_HIL_EMU_STATE=str(tmp_path / "unused.npz"))
    proc = subprocess.Popen([sys.executable, "-m", "snan_hil.tools.cli", "emu", "--protocol",
                             "legacy", "--state", str(tmp_path / "chip.npz"), "--seed", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    line = proc.stdout.readline()
    match = re.search(r"serving on (\S+)", line)
    try:
        assert match, line
        yield match.group(1)
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 0 and "Traceback" not in err, err


def test_existing_hosts_traffic_works_unchanged(served_legacy):
    host = ExistingHost(served_legacy)
    try:
        assert host.kick()
        info = host.tech_info()
        assert info[0].startswith("EMU-") and "legacy" in info[1]
        # the map of every cell (mode 9 at "0.3 V" = code 246)
        before = {}
        for wl in range(8):
            for bl in range(32):
                adc, id_ = host.read(wl, bl)
                assert id_ == host.request_id and 0 <= adc <= MEMRICORE.adc_full_scale_code
                before[(bl, wl)] = adc
        ramp = [host_code(v) for v in RAMP_V]
        assert (ramp[0], ramp[-1]) == (246, 1392)          # the host's 0.3 V and 1.7 V
        cells = [(bl, wl) for bl in range(15) for wl in range(8)
                 if (bl, wl) not in BAD_CELLS][:15]
        g = MEMRICORE.cell_conductance
        for bl, wl in cells:
            reset = [host.pulse(code, 0, 100, 0, wl, bl) for code in ramp]
            set_ = [host.pulse(code, 0, 100, 1, wl, bl) for code in ramp]
            for seq in (reset, set_):
                assert all(len(r) == 2 for r in seq)
            ids = host.ids_sent[-2 * len(ramp):]
            assert [r[1] for r in reset + set_] == ids       # every reply carries its id
            g0 = g(before[(bl, wl)], MEMRICORE.legacy_read_code)
            g_reset = g(reset[-1][0], MEMRICORE.legacy_read_code)
            g_set = g(set_[-1][0], MEMRICORE.legacy_read_code)
            assert g_reset < g0                              # RESET: conductance falls
            assert g_set > 4 * g_reset and g_set > g0        # SET: it rises again
            assert reset[-1][0] < reset[0][0] and set_[-1][0] > set_[0][0]
        # the ids went 1..4096 and wrapped to 0, and the board followed
        assert host.ids_sent[:3] == [1, 2, 3]
        wrap = host.ids_sent.index(4096)
        assert host.ids_sent[wrap + 1:wrap + 3] == [0, 1]
        assert host.read(0, 0)[1] == host.request_id
    finally:
        host.serial.close()
