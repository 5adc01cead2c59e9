"""Compliance prediction of a write pulse from the cell's last reading, in integer arithmetic.

The MCU has no FPU and cannot see the crossbar's true conductance, so the firmware predicts the
current of a write pulse from the most recent single-cell read of that cell: the read chain
(docs/protocol.md, section 5) gives the 1T1R resistance ``X`` from the ADC code ``A`` taken at
row-DAC code ``rc``::

    X + R_sw + R_load = 2^B * gain * R_load * V_read / (A * Vref_adc),  V_read = rc * Vd / (2^D - 1)

and a pulse of write-DAC code ``amp`` drives ``I = V_amp / (X + R_sw)`` (the pulse bypasses the
load resistor; the board's switches stay in series). With voltages in mV this is one exact
ratio of integers::

    I_uA = 1000 * amp * Vw_mV * Vadc_mV * A
           / (2^B * gain * R_load * rc * Vd_mV - R_load * (2^D - 1) * Vadc_mV * A)

A denominator <= 0 means the reading is beyond a short circuit: the current is unbounded and the
pulse is refused (detail 0xFFFFFFFF). A reading at read code 0 (a 0 V read, the calibration's
offset read) has ``rc = 0``, so its denominator is ``-k_adc * A <= 0`` whatever the cell: it would
predict an unbounded current for any cell. Such a reading says nothing about the conductance, so
neither firmware takes it as the basis: the basis is the cell's last reading at a read code above
0 (issue 27, item 3; docs/protocol.md, WRITE_PULSE). Both MCU models
(``firmware_emu.firmware`` and the C firmware, ``firmware/src/ops.c``) use this formula, so they
refuse the same pulses with the same ``detail``. Source of the read chain: the existing host
software (memricore-board.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

UNBOUNDED_UA = 0xFFFF_FFFF
"""``detail`` of a refusal whose reading implies an unbounded current."""


def _int_exact(value: float, what: str) -> int:
    iv = int(round(value))
    if abs(iv - value) > 1e-9:
        raise ValueError(f"{what} = {value} must be an integer for the integer compliance formula")
    return iv


@dataclass(frozen=True)
class ComplianceConstants:
    """The integer constants of the prediction (see the module docstring)."""

    k_num: int          # 1000 * Vw_mV * Vadc_mV          (times amp * A)
    k_rc: int           # 2^B * gain * R_load * Vd_mV      (times rc)
    k_adc: int          # R_load * (2^D - 1) * Vadc_mV     (times A)
    limit_ua: int       # compliance limit in uA

    @classmethod
    def from_config(cls, cfg) -> "ComplianceConstants":
        """From a :class:`~snan_hil.firmware_emu.config.BoardConfig` (or anything with its
        fields). Raises ValueError if a constant is not an integer in V*1000, Ohm or uA."""
        if cfg.write_dac_bits != cfg.dac_bits:
            raise ValueError("the integer compliance formula assumes write and row DACs of the "
                             f"same width ({cfg.write_dac_bits} vs {cfg.dac_bits} bits)")
        vd = _int_exact(cfg.dac_vref_v * 1000, "dac_vref_v [mV]")
        vw = _int_exact(cfg.write_dac_vref_v * 1000, "write_dac_vref_v [mV]")
        va = _int_exact(cfg.adc_vref_v * 1000, "adc_vref_v [mV]")
        # gain and R_load as exact decimal fractions n/d: multiplying numerator and denominator
        # by both d keeps the ratio exact (d = 1 for the MemriCore's integer values).
        gain = Fraction(str(cfg.gain))
        r_load = Fraction(str(cfg.r_load_ohm))
        scale = gain.denominator * r_load.denominator
        limit = _int_exact(cfg.compliance_a * 1e6, "compliance [uA]")
        return cls(k_num=1000 * vw * va * scale,
                   k_rc=(1 << cfg.adc_bits) * gain.numerator * r_load.numerator * vd,
                   k_adc=r_load.numerator * gain.denominator * ((1 << cfg.dac_bits) - 1) * va,
                   limit_ua=limit)

    def ratio(self, amp_code: int, adc: int, read_code: int) -> tuple[int, int]:
        """(numerator, denominator) of the predicted current in uA."""
        return self.k_num * amp_code * adc, self.k_rc * read_code - self.k_adc * adc

    def check(self, amp_code: int, adc: int, read_code: int) -> tuple[bool, int]:
        """(refused, predicted current in uA rounded half up, capped at 0xFFFFFFFF)."""
        num, den = self.ratio(amp_code, adc, read_code)
        if den <= 0:
            return True, UNBOUNDED_UA
        refused = num > self.limit_ua * den
        return refused, min((2 * num + den) // (2 * den), UNBOUNDED_UA)
