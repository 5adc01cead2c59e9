"""The board as one instrument: :class:`BoardSession`, what every job on a board receives.

A session holds what a job needs of a board and would otherwise re-derive: the client (wrapped
in :class:`~snan_hil.protocol.retry.RetryingClient` here, the one place read retries are
switched on: reads are resent after a lost reply, pulses never), the board's INFO, the host's
safety limits (:class:`~snan_hil.protocol.safety.HostLimits`, decided once from INFO and the
user's ``--max-write-v``), the board's identity, its files (:class:`~snan_hil.board.files.
BoardFiles`), the protocol, how to open it again (an injected callable: every set of a
comparison starts from a fresh boot of the board) and, for an emulated chip, how to save and
put back the chip (:class:`ChipSnapshots`). :meth:`BoardSession.snapshot` is the provenance
record every report embeds (the QCoDeS ``snapshot`` idea: one dict that says what instrument,
in what state, produced a result).

The session is built by :func:`snan_hil.lab.opener.plan_board` (outputs checked, history,
emulator state, client, HELLO, in that order) from a port string or URL; tests and benches that
hold a client already build one with :meth:`BoardSession.attach`. A closed session still
describes its board (identity, files, snapshot) and can be reopened.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, Self

from snan_hil.common.version import __version__
from snan_hil.board.files import BoardFiles
from snan_hil.board.identity import BoardIdentity
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.legacy_client import LegacyClient
from snan_hil.protocol.messages import Info
from snan_hil.protocol.retry import RetryingClient
from snan_hil.protocol.safety import HostLimits
from snan_hil.protocol.transport import DEFAULT_BAUD

__all__ = ["BoardSession", "ChipSnapshots", "Closing", "SESSION_FORMAT", "with_read_retries"]

SESSION_FORMAT = "snan-hil-session/1"
"""Marker of :meth:`BoardSession.snapshot`."""


class ChipSnapshots(Protocol):
    """What an emulated board holds at a boundary of a run, saved and put back (a real chip
    cannot be put back, so real boards have none)."""

    def save(self, dest: Path) -> None:
        """Save the chip as it is now to ``dest``."""

    def check(self, src: Path) -> None:
        """UserError (one line naming ``src``) unless ``src`` can be put back; changes
        nothing."""

    def restore(self, src: Path) -> None:
        """Put the chip saved in ``src`` back."""


def with_read_retries(client: BoardClient) -> RetryingClient:
    """``client`` with its safe requests resent after a lost reply (:class:`RetryingClient`;
    a client that is one already is returned as is): the one place read retries are
    switched on (the session's client, and the opener's HELLO)."""
    return client if isinstance(client, RetryingClient) else RetryingClient(client)


class Closing:
    """``with x:`` closes ``x`` on the way out (``close()`` is the class's own)."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class BoardSession(Closing):
    """One board, opened: see the module docstring. ``client`` is connected (HELLO done) and
    retrying where retries are safe; ``options`` are the command-line options that reach this
    board again (for hints such as "program it first: snan-hil program-weights ...")."""

    client: BoardClient
    info: Info
    limits: HostLimits
    identity: BoardIdentity
    files: BoardFiles
    port: str
    protocol: str = "framed"
    baud: int = DEFAULT_BAUD
    mcu: str | None = None
    options: str = ""
    reopen_with: Callable[[], BoardSession] | None = None
    snapshots: ChipSnapshots | None = None

    @classmethod
    def attach(cls, client: BoardClient, *, port: str | None = None,
               files: BoardFiles | None = None, baud: int = DEFAULT_BAUD,
               mcu: str | None = None, options: str | None = None,
               reopen_with: Callable[[], BoardSession] | None = None,
               snapshots: ChipSnapshots | None = None) -> BoardSession:
        """The session of a connected ``client`` (HELLO is sent, and resent when lost, if it
        has none yet). ``port`` defaults to the client's transport name; the protocol is the
        client's; ``files`` default to none. The client is wrapped in a
        :class:`RetryingClient` unless it is one."""
        inner = client.inner if isinstance(client, RetryingClient) else client
        retrying = with_read_retries(client)
        info = retrying.info or retrying.hello()
        protocol = "legacy" if isinstance(inner, LegacyClient) else "framed"
        port = port if port is not None else retrying.transport.name
        limits = inner.limits               # the one write limit: derived by the client
        if options is None:
            options = f"--port {port}" + (" --protocol legacy" if protocol == "legacy" else "")
        return cls(retrying, info, limits, BoardIdentity.from_info(info), files or BoardFiles(),
                   port, protocol, baud, mcu, options, reopen_with, snapshots)

    # -- what a job asks of it --------------------------------------------------------------
    def with_files(self, **changes: Path | None) -> BoardSession:
        """This session (the same client) with some of its files replaced (e.g. the program
        report of one set of a comparison: ``report=..., previous_report=...``)."""
        return dataclasses.replace(self, files=dataclasses.replace(self.files, **changes))

    def reopen(self) -> BoardSession:
        """A new session on the same board (a fresh connection: on the in-process emulator a
        fresh boot of the saved chip). RuntimeError when the session cannot be reopened."""
        if self.reopen_with is None:
            raise RuntimeError(f"the session on {self.port} cannot be reopened")
        return self.reopen_with()

    def open(self) -> BoardSession:
        """:meth:`reopen` (a session is a source of fresh sessions of its board)."""
        return self.reopen()

    def snapshot(self) -> dict[str, Any]:
        """The provenance record of this session (JSON-ready): format, snan-hil version,
        port, protocol, baud, MCU (the in-process emulator's; None otherwise), identity (board
        id, chip id, firmware version), the host's limits (V and DAC codes), the board's files
        and its INFO."""
        lim = self.limits
        return {"format": SESSION_FORMAT, "snan_hil_version": __version__, "port": self.port,
                "protocol": self.protocol, "baud": self.baud, "mcu": self.mcu,
                "identity": self.identity.to_dict(chip_id=self.identity.chip_id),
                "host_limits": {"max_read_v": lim.max_read_v, "max_write_v": lim.max_write_v,
                                "max_cell_read_code": lim.max_cell_read_code,
                                "max_row_read_code": lim.max_row_read_code,
                                "max_write_code": lim.max_write_code},
                "files": self.files.to_dict(), "info": self.info.to_dict()}

    def close(self) -> None:
        """Close the connection (the session still describes the board)."""
        self.client.close()
