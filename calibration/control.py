"""A board client that polls the run's control channel before every request that may change
the chip or take time (:mod:`snan_hil.records.control`): pause, resume and stop from ``snan-hil
watch`` land between pulses, never inside one.

:class:`ControlledClient` wraps any :class:`~snan_hil.protocol.client.BoardClient` (it is one
itself, delegating everything else): ``write_pulse``, ``program_cell``, ``read_cell``,
``read_column``, ``spike_batch``, ``decision_window`` (the on-board decision of a
hardware launch) and ``submit`` (a window sent while another runs: interleaved launches) first
call ``check()``. A stop raises
:class:`~snan_hil.records.control.StopRequested` before the request is sent, so the request
before it was answered and handed on in full.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["ControlledClient"]

_CHECKED = ("write_pulse", "program_cell", "read_cell", "read_column", "spike_batch",
            "decision_window", "submit")


class ControlledClient:
    """``client`` with ``check()`` called before each request of :data:`_CHECKED`."""

    def __init__(self, client: Any, check: Callable[[], None]) -> None:
        self._client = client
        self._check = check

    @property
    def wrapped(self) -> Any:
        return self._client

    @property
    def check(self) -> Callable[[], None]:
        """The run's control check this client calls before each request (a fresh connection
        of the same run is watched by the same check: :meth:`CellBench.reopened`)."""
        return self._check

    @property
    def pipelined(self) -> bool:
        """The wrapped client's (written through: two requests outstanding)."""
        return bool(self._client.pipelined)

    @pipelined.setter
    def pipelined(self, on: bool) -> None:
        self._client.pipelined = on

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._client, name)
        if name in _CHECKED and callable(attr):
            check = self._check

            def checked(*args: Any, **kwargs: Any) -> Any:
                check()
                return attr(*args, **kwargs)
            return checked
        return attr

    def __enter__(self) -> ControlledClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self._client.close()
