"""One board command surface (issue 21, point 4): every command is defined once, in
``protocol.client.BoardClient``, with its resend policy beside it; the framed, legacy and
retrying clients share it and implement only ``request()``, which is generic in the reply."""

import pytest

from snan_hil.protocol import learn_messages as lm
from snan_hil.protocol import messages as m
from snan_hil.protocol.client import COMMANDS, BoardClient, command_of
from snan_hil.protocol.device import DeviceEndpoint
from snan_hil.protocol.errors import LinkTimeoutError, UnsupportedError
from snan_hil.protocol.legacy_client import LegacyClient
from snan_hil.protocol.legacy_device import LegacyDevice
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.retry import RetryingClient
from snan_hil.protocol.testing import FakeBoard
from snan_hil.protocol.transport import CallbackTransport

METHODS = ("hello", "read_cell", "read_column", "write_pulse", "spike_batch", "program_cell",
           "decision_window", "status", "clock", "reset", "learn_setup", "learn_window",
           "learn_apply", "learn_state")


def test_every_request_type_has_one_command_defined_once():
    assert set(COMMANDS) == set(m.REQUEST_TYPES.values())
    assert sorted(spec.method for spec in COMMANDS.values()) == sorted(METHODS)
    for spec in COMMANDS.values():
        assert spec.method in BoardClient.__dict__              # defined on the surface
        assert spec.request.REPLY.TYPE == spec.request.TYPE | 0x80
    for cls in (LinkClient, LegacyClient, RetryingClient):
        assert not set(METHODS) & set(vars(cls)), cls           # ... and nowhere else


def test_resend_policy_is_declared_per_command():
    resent = {spec.name for spec in COMMANDS.values() if spec.resend}
    assert resent == {"HELLO", "READ_CELL", "READ_COLUMN", "SPIKE_BATCH", "DECISION_WINDOW",
                      "STATUS", "CLOCK", "LEARN_SETUP", "LEARN_WINDOW", "LEARN_STATE"}
    # LEARN_APPLY pulses: never resent as a new request (a repeat is answered ALREADY anyway)
    assert command_of(lm.LearnApply()).resend is False
    assert command_of(m.WritePulse()).resend is False
    assert command_of(m.ProgramCell()).capability == m.Capability.PROGRAM_CELL
    # the link waits for a command's execution time: a 1 s pulse is waited for
    assert command_of(m.WritePulse(width_us=1_000_000)).exec_s(
        m.WritePulse(width_us=1_000_000)) >= 1.0


def test_request_is_generic_in_the_reply():
    board = FakeBoard()
    client = LinkClient(CallbackTransport(DeviceEndpoint(board).feed), timeout=0.05)
    info = client.request(m.Hello())
    assert isinstance(info, m.Info) and client.info == info       # the client learns INFO
    reply = client.request(m.ReadCell(1, 2, 245))
    assert type(reply) is m.ReadCellReply and reply.adc == 1012
    assert m.ReadCell().accept(m.WritePulseReply(3)) is None


class _Flaky(LinkClient):
    """A link that loses the first try of every request (a retryable failure)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.sent: list[str] = []

    def request(self, req, **kwargs):
        self.sent.append(type(req).__name__)
        if self.sent.count(type(req).__name__) % 2:
            raise LinkTimeoutError("damaged", "corrupting")
        return super().request(req, **kwargs)


def test_retrying_client_resends_only_what_its_command_allows():
    board = FakeBoard()
    inner = _Flaky(CallbackTransport(DeviceEndpoint(board).feed), timeout=0.05)
    client = RetryingClient(inner)
    client.hello()
    assert client.read_cell(0, 0) == 1000
    assert client.status().pulses_applied == 0
    with pytest.raises(LinkTimeoutError):
        client.write_pulse(0, 0, m.Polarity.SET, 100, 10)        # never resent
    assert inner.sent.count("WritePulse") == 1 and board.pulses == 0
    assert inner.sent.count("ReadCell") == 2 and client.lost_requests == 3   # not the pulse
    assert client.info is inner.info and client.limits == inner.limits


def test_silent_failures_are_not_resent():
    board = FakeBoard()
    inner = _Flaky(CallbackTransport(DeviceEndpoint(board).feed), timeout=0.05)
    inner.request = lambda req, **kw: (_ for _ in ()).throw(LinkTimeoutError("gone", "silent"))
    with pytest.raises(LinkTimeoutError):
        RetryingClient(inner).status()
    assert not LinkTimeoutError("x", "silent").retryable
    assert LinkTimeoutError("x", "garbled").retryable


def test_legacy_client_shares_the_surface_and_refuses_what_lines_cannot_do():
    board = FakeBoard(interlocks=False)
    device = LegacyDevice(board)
    client = LegacyClient(CallbackTransport(device.feed, name="old"), timeout=0.02)
    client.hello()
    assert client.read_cell(3, 4) == 1000 + 34
    assert client.write_pulse(3, 4, m.Polarity.SET, 100, 10) == 1000 + 34 + 10
    for call in (lambda: client.status(), lambda: client.read_column(0, [245] * 32),
                 lambda: client.program_cell(0, 0, 1000, 10), lambda: client.reset(),
                 lambda: client.spike_batch([m.SpikeGroup(((0, 245),), (1,))], [0], 8)):
        with pytest.raises(UnsupportedError, match="not available over the legacy line"):
            call()
    assert board.pulses == 1
