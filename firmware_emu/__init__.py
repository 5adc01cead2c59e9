"""Board emulator: MCU firmware behaviour, SPI peripherals, virtual clock, serial server.

* :mod:`.config` — board constants, limits and timing (:class:`BoardConfig`, :class:`TimingConfig`).
* :mod:`.clock` — virtual time (us) and array energy (J).
* :mod:`.spi_devices` — AD5328 row DACs, write DAC, TLC3541 ADC, 74HC595s, the SPI bus + trace.
* :mod:`.registers` — chip selects and the bit map of the two shift registers.
* :mod:`.analog` — front end: latched state -> crossbar currents, ADC samples, pulses, power.
* :mod:`.board` — the hardware wired around a crossbar array.
* :mod:`.firmware` — the MCU operations and safety interlocks.
* :mod:`.legacy_firmware` — the existing firmware's rules (no interlocks) for the legacy protocol.
* :mod:`.spike_fastpath` — SPIKE_BATCH in one pass (numba clock kernel, vectorised samples),
  bit-identical to the frame-by-frame path.
* :mod:`.dispatch` — protocol request -> firmware -> reply.
* :mod:`.emulator` — one board behind ``feed(bytes) -> bytes`` (framed or legacy protocol).
* :mod:`.server` — pty and TCP servers (replies paced in wall time); :mod:`.inprocess` —
  ``--port emu``.
* :mod:`.state` — the chip state file; :mod:`.testing` — helpers for tests and benchmarks.

Design and timing model: ``docs/emulator.md``.
"""
