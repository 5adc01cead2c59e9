"""Host-side safety limits: an over-limit read or write is refused before anything is sent."""

import pytest

from snan_hil.protocol.device import DeviceEndpoint
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.messages import Info, Polarity, SpikeGroup
from snan_hil.protocol.safety import HostLimits, HostSafetyError
from snan_hil.protocol.testing import FakeBoard
from snan_hil.protocol.transport import CallbackTransport


class CountingTransport(CallbackTransport):
    """Counts the bytes the host writes."""

    def __init__(self, respond):
        super().__init__(respond, name="fake")
        self.written = 0

    def write(self, data: bytes) -> int:
        self.written += len(data)
        return super().write(data)


def test_limits_use_the_largest_code_at_or_below_the_voltage():
    info = Info()
    limits = HostLimits.from_board(info)
    assert (info.dac_volts(limits.max_read_code) <= info.max_read_v
            < info.dac_volts(limits.max_read_code + 1))
    assert (info.write_dac_volts(limits.max_write_code) <= info.max_write_v
            < info.write_dac_volts(limits.max_write_code + 1))


@pytest.mark.parametrize("call", [
    lambda c, lim: c.read_cell(0, 0, lim.max_read_code + 1),
    lambda c, lim: c.read_column(0, [0] * 31 + [lim.max_read_code + 1]),
    lambda c, lim: c.write_pulse(0, 0, Polarity.SET, lim.max_write_code + 1, 100),
    lambda c, lim: c.write_pulse(0, 0, Polarity.SET, 100, 100, read_code=lim.max_read_code + 1),
    lambda c, lim: c.spike_batch([SpikeGroup(((0, lim.max_read_code + 1),), (0,))], [0]),
    lambda c, lim: c.program_cell(0, 0, 5000, 100, amp_stop_code=lim.max_write_code + 1),
])
def test_over_limit_requests_are_not_sent(call):
    board = FakeBoard()
    transport = CountingTransport(DeviceEndpoint(board, boot_nonce=lambda: board.boot_nonce).feed)
    client = LinkClient(transport)
    client.hello()
    sent = transport.written
    with pytest.raises(HostSafetyError, match="not sent"):
        call(client, client.limits)
    assert transport.written == sent


def test_at_limit_requests_pass():
    board = FakeBoard()
    client = LinkClient(CountingTransport(DeviceEndpoint(board,
                                                         boot_nonce=lambda: board.boot_nonce).feed))
    client.hello()
    lim = client.limits
    client.read_cell(0, 0, lim.max_read_code)
    client.write_pulse(0, 0, Polarity.RESET, lim.max_write_code, 100)
