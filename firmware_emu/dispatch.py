"""Request message -> firmware operation -> reply message (the board side of the protocol).

:class:`Dispatcher` is the handler that :class:`snan_hil.protocol.device.DeviceEndpoint` calls
for every checked, de-duplicated request. Firmware refusals are
:class:`snan_hil.protocol.errors.BoardError` subclasses; they propagate to the endpoint, which
answers with an ERROR reply. Link counters of the STATUS reply are filled by the endpoint.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from snan_hil.firmware_emu.decision_window import DecisionWindowOp
from snan_hil.firmware_emu.firmware import Firmware
from snan_hil.firmware_emu.learn_op import LearnOp
from snan_hil.firmware_emu.spike_group import SpikeGroupSpec
from snan_hil.protocol import learn_messages as lm
from snan_hil.protocol import messages as m
from snan_hil.protocol.errors import (BoardError, ErrorCode, OutOfRangeError,
                                      UnsupportedRequestError)

log = logging.getLogger(__name__)

STATE_CHANGING = (m.WritePulse, m.ProgramCell, lm.LearnApply)
"""Requests that can change the chip's conductances (the state file must be saved after)."""


class Dispatcher:
    """Calls the firmware for each request type; ``on_state_change`` runs after writes."""

    def __init__(self, firmware: Firmware, on_state_change: Callable[[], None] | None = None):
        self.firmware = firmware
        self.on_state_change = on_state_change
        self.window = DecisionWindowOp()    # DECISION_WINDOW and its stored parameters
        # handler per request class (each takes its own class: Any keeps the table one type)
        self._table: dict[type[m.Request], Callable[[Any], m.Reply]] = {
            m.Hello: self._hello,
            m.ReadCell: self._read_cell,
            m.ReadColumn: self._read_column,
            m.WritePulse: self._write_pulse,
            m.SpikeBatch: self._spike_batch,
            m.ProgramCell: self._program_cell,
            m.Status: self._status,
            m.Clock: self._clock,
            m.Reset: self._reset,
            m.DecisionWindow: self._decision_window,
        }
        self.learn = LearnOp()              # on-board learning (issue 34), if the board has it
        if firmware.config.on_board_learning:
            self._table.update({lm.LearnSetup: self._learn_setup,
                                lm.LearnWindow: self._learn_window,
                                lm.LearnApply: self._learn_apply,
                                lm.LearnState: self._learn_state})

    def serves(self, request_type: int) -> bool:
        """Whether this board implements requests of ``request_type`` (the endpoint answers
        UNKNOWN_TYPE for the others: LEARN_* where on-board learning is off)."""
        return any(cls.TYPE == request_type for cls in self._table)

    @property
    def boot_nonce(self) -> int:
        return self.firmware.boot_nonce

    def __call__(self, request: m.Request) -> m.Reply:
        handler = self._table.get(type(request))
        if handler is None:
            raise UnsupportedRequestError(
                f"request type 0x{request.TYPE:02x} is not implemented by the emulator",
                request_type=request.TYPE)
        try:
            reply = handler(request)
        except BoardError as exc:
            if not exc.request_type:
                exc.request_type = request.TYPE
            raise
        if isinstance(request, STATE_CHANGING) and self.on_state_change is not None:
            self.on_state_change()
        return reply

    # -- handlers ---------------------------------------------------------------------------
    def _hello(self, req: m.Hello) -> m.Info:
        if req.protocol_version != m.PROTOCOL_VERSION:
            # docs/protocol.md, HELLO: detail = the version the board speaks
            raise BoardError(f"protocol version {req.protocol_version} not supported "
                             f"(board speaks {m.PROTOCOL_VERSION})", ErrorCode.BAD_VERSION,
                             detail=m.PROTOCOL_VERSION)
        self.window.clear()                 # a new session (the learning state survives it)
        caps = m.BASE_CAPABILITIES
        if self.firmware.config.on_board_learning:
            caps |= int(m.Capability.LEARN)
        return m.Info(protocol_version=m.PROTOCOL_VERSION, max_payload=m.MAX_PAYLOAD,
                      capabilities=caps, **self.firmware.info())

    def _read_cell(self, req: m.ReadCell) -> m.ReadCellReply:
        return m.ReadCellReply(self.firmware.read_cell(req.row, req.col, req.dac_code))

    def _read_column(self, req: m.ReadColumn) -> m.ReadColumnReply:
        return m.ReadColumnReply(self.firmware.read_column(req.row_codes, req.col))

    def _write_pulse(self, req: m.WritePulse) -> m.WritePulseReply:
        adc = self.firmware.write_pulse(req.row, req.col, m.Polarity(req.polarity),
                                        req.amplitude_code, req.width_us, req.read_code)
        return m.WritePulseReply(adc)

    def _spike_batch(self, req: m.SpikeBatch) -> m.SpikeBatchReply:
        n_spikes, n_cols = req.n_spikes(), len(req.columns)
        size = m.spike_batch_reply_size(n_spikes, n_cols)
        if size > m.MAX_PAYLOAD:
            raise OutOfRangeError(
                f"reply of {n_spikes} spikes x {n_cols} columns would be {size} bytes, more "
                f"than the {m.MAX_PAYLOAD}-byte payload limit; split the window",
                detail=size)                # the endpoint's detail (docs/protocol.md, rule 6)
        groups = [SpikeGroupSpec(tuple(g.rows), tuple(g.bins)) for g in req.groups]
        codes = self.firmware.spike_batch(groups, req.columns, req.n_bins, req.bin_us,
                                          req.paced)
        return m.SpikeBatchReply(req.first_bin, n_cols, tuple(map(tuple, codes)))

    def _program_cell(self, req: m.ProgramCell) -> m.ProgramCellReply:
        res = self.firmware.program_cell(
            req.row, req.col, req.target_adc, req.tolerance_adc, req.max_pulses,
            req.amp_start_code, req.amp_stop_code, req.amp_step_code, req.width_us,
            req.read_code, req.fine_tune)
        return m.ProgramCellReply(res.final_adc, res.pulses_stage1, res.pulses_stage2, res.ok)

    def _status(self, req: m.Status) -> m.StatusReply:
        s = self.firmware.status()
        return m.StatusReply(cell_reads=s["cell_reads"], column_reads=s["column_reads"],
                             pulses_applied=s["pulses_applied"],
                             spikes_applied=s["spikes_applied"], busy=s["busy"],
                             saturated_reads=s["saturated_reads"])

    def _clock(self, req: m.Clock) -> m.ClockReply:
        now_us, energy_j = self.firmware.clock_reading()
        return m.ClockReply(int(now_us), float(energy_j))

    def _reset(self, req: m.Reset) -> m.ResetReply:
        old, new = self.firmware.reset()
        self.window.clear()
        self.learn.clear()                  # the learning state is RAM (docs/protocol.md)
        return m.ResetReply(old, new)

    def _decision_window(self, req: m.DecisionWindow) -> m.DecisionWindowReply:
        return self.window.run(self.firmware, req)

    def _learn_setup(self, req: lm.LearnSetup) -> lm.LearnSetupReply:
        return self.learn.setup(self.firmware, req)

    def _learn_window(self, req: lm.LearnWindow) -> lm.LearnWindowReply:
        return self.learn.window(self.firmware, self.window, req)

    def _learn_apply(self, req: lm.LearnApply) -> lm.LearnApplyReply:
        return self.learn.apply(self.firmware, req)

    def _learn_state(self, req: lm.LearnState) -> lm.LearnStateReply:
        return self.learn.read_state(self.firmware, req)
