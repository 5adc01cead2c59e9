"""Board emulator: MCU firmware behaviour, SPI peripherals, virtual clock, serial server,
and the built C firmware run on an instruction-level MCU.

* :mod:`.config` — board constants, limits and timing (:class:`BoardConfig`, :class:`TimingConfig`).
* :mod:`.clock` — virtual time (us) and array energy (J).
* :mod:`.spi_devices` — AD5328 row DACs, write DAC, TLC3541 ADC, 74HC595s, the SPI bus + trace.
* :mod:`.registers` — chip selects and the bit map of the two shift registers.
* :mod:`.analog` — front end: latched state -> crossbar currents, ADC samples, pulses, power.
* :mod:`.board` — the hardware wired around a crossbar array.
* :mod:`.firmware` — the MCU operations and safety interlocks (the Python firmware model);
  :mod:`.compliance` — its integer compliance prediction of a write pulse;
  :mod:`.chip_identity` — the chip serial in the MIK32 EEPROM.
* :mod:`.legacy_firmware` — the existing firmware's rules (no interlocks) for the legacy protocol.
* :mod:`.spike_fastpath` — SPIKE_BATCH in one pass (numba clock kernel, vectorised samples),
  bit-identical to the frame-by-frame path.
* :mod:`.dispatch` — protocol request -> firmware -> reply.
* :mod:`.emulator` — one board behind ``feed(bytes) -> bytes`` (framed or legacy protocol).
* :mod:`.mcu` — which MCU runs it (``--mcu model`` or ``firmware``); :mod:`.mcu_isa` — the
  firmware ELF (:mod:`.fw_image`) executed by a RISC-V CPU emulator; its peripherals in
  :mod:`.mik32_periph` (readable reference core) and :mod:`.mik32_native` (the native core,
  built from ``native/``), one state layout in :mod:`.mik32_state`.
* :mod:`.server` — pty and TCP servers (replies paced in wall time); :mod:`.inprocess` —
  ``--port emu``; :mod:`.protocol_emu` — ``emu://`` as a pyserial URL.
* :mod:`.state` — the chip state file; :mod:`.durable` — snapshot + write-ahead
  :mod:`.journal`, so a returned request survives a kill.
* :mod:`.twin` — the two MCUs on one chip, compared; :mod:`.differential` — generated
  request sequences sent to both; :mod:`.testing` — helpers for tests and benchmarks.

Design and timing model: ``docs/emulator.md``.
"""
