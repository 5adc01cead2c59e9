"""Link retries above the link: :class:`RetryingClient` sends a lost read again as a new request.

The link itself (:class:`~snan_hil.protocol.link.LinkClient`) retransmits a request with the
same sequence number; when it gives up it raises
:class:`~snan_hil.protocol.errors.LinkTimeoutError`. A request whose command is declared safe
to resend (``resend=True`` beside its definition in :mod:`snan_hil.protocol.client`: HELLO,
READ_CELL, READ_COLUMN, SPIKE_BATCH, DECISION_WINDOW, STATUS, CLOCK - they change nothing on
the chip) is then
sent again as a new request, up to ``tries`` requests, when the failure is one that asking
again can cure (``LinkTimeoutError.retryable``: a damaged line), not when the board is silent,
the line stalled beyond the user's patience, the port echoes or the board floods stale
replies, nor when it is busy (:class:`~snan_hil.protocol.errors.BoardBusyError`). WRITE_PULSE,
PROGRAM_CELL and RESET pass through unchanged: a lost pulse must be reconciled from the
board's pulse counter (calibration's ``BoardCellIO``), never blindly resent.
"""

from __future__ import annotations

import logging
from typing import Any, TypeVar

from snan_hil.protocol.client import BoardClient, command_of
from snan_hil.protocol.errors import LinkTimeoutError, UnsupportedError
from snan_hil.protocol.messages import DecisionParams, Info, Reply, Request
from snan_hil.protocol.transport import Transport

__all__ = ["RetryingClient", "DEFAULT_READ_TRIES"]

log = logging.getLogger(__name__)

DEFAULT_READ_TRIES = 6
"""Requests (each with the link's own retransmissions) before a read is given up."""

ReplyT = TypeVar("ReplyT", bound=Reply)


class RetryingClient(BoardClient):
    """A :class:`BoardClient` around another one whose safe requests are sent again after a
    retryable :class:`LinkTimeoutError`, up to ``tries`` requests in all (``lost_requests``
    counts the requests given up on). Other attributes (counters, ``timeout``, ...) are the
    inner client's."""

    def __init__(self, client: BoardClient, tries: int = DEFAULT_READ_TRIES):
        self._client = client
        self._tries = max(1, int(tries))
        self.lost_requests = 0

    @property
    def inner(self) -> BoardClient:
        """The wrapped client."""
        return self._client

    # the inner client's state, read and written through
    @property
    def transport(self) -> Transport:
        return self._client.transport

    @transport.setter
    def transport(self, value: Transport) -> None:
        self._client.transport = value

    @property
    def info(self) -> Info | None:
        return self._client.info

    @info.setter
    def info(self, value: Info | None) -> None:
        self._client.info = value

    @property
    def host_max_write_v(self) -> float | None:
        return self._client.host_max_write_v

    @host_max_write_v.setter
    def host_max_write_v(self, value: float | None) -> None:
        self._client.host_max_write_v = value

    @property
    def window_params(self) -> DecisionParams | None:
        return self._client.window_params

    @window_params.setter
    def window_params(self, value: DecisionParams | None) -> None:
        self._client.window_params = value

    @property
    def payload_limit(self) -> int:
        return self._client.payload_limit

    def unsupported(self, what: str) -> UnsupportedError:
        return self._client.unsupported(what)

    def request(self, req: Request[ReplyT]) -> ReplyT:
        """``req`` through the inner client; sent again as a new request after a retryable
        link failure when its command may be resent."""
        spec = command_of(req)
        if spec is None or not spec.resend:
            return self._client.request(req)
        for attempt in range(self._tries):
            try:
                return self._client.request(req)
            except LinkTimeoutError as exc:
                self.lost_requests += 1
                if attempt == self._tries - 1 or not exc.retryable:
                    raise
                if exc.kind == "garbled" and not getattr(self._client, "answered", 1):
                    raise       # nothing intact ever came back: a wrong baud, not damage
                log.info("%s lost on the link (%s); sending it again", spec.name, exc.kind)
        raise AssertionError("unreachable")  # pragma: no cover - the loop returns or raises

    @property
    def pipelined(self) -> bool:
        return self._client.pipelined

    @pipelined.setter
    def pipelined(self, on: bool) -> None:
        self._client.pipelined = on

    def pipelinable(self, req: Request[Reply]) -> bool:
        return self._client.pipelinable(req)

    def submit(self, req: Request[ReplyT]) -> Any:
        """``req`` submitted through the inner client (see :meth:`collect`)."""
        return (req, self._client.submit(req))

    def collect(self, ticket: Any) -> Any:
        """The reply of a :meth:`submit` ticket; after a retryable link failure a resendable
        request is sent again as a new request, as :meth:`request` does."""
        req, inner = ticket
        spec = command_of(req)
        try:
            return self._client.collect(inner)
        except LinkTimeoutError as exc:
            self.lost_requests += 1
            if spec is None or not spec.resend or not exc.retryable or self._tries < 2:
                raise
            log.info("%s lost on the link (%s); sending it again", spec.name, exc.kind)
        for attempt in range(1, self._tries):
            try:
                return self._client.request(req)
            except LinkTimeoutError as exc:
                self.lost_requests += 1
                if attempt == self._tries - 1 or not exc.retryable:
                    raise
        raise AssertionError("unreachable")  # pragma: no cover - the loop returns or raises

    def counters_dict(self) -> dict[str, int]:
        return self._client.counters_dict()

    def close(self) -> None:
        self._client.close()

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("_client", "_tries"):
            raise AttributeError(name)
        return getattr(self._client, name)
