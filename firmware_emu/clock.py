"""Virtual clock of the emulated board: time (us) and array energy (J) since reset.

Nothing here sleeps. Every modelled operation (an SPI byte at 15 MHz, a DAC settling wait, an
ADC conversion cycle, a UART byte, a write pulse) advances the clock by its duration, filed
under a category so the cost of a request can be broken down. The analog front end sets the
power dissipated in the crossbar cells (sum of V^2 * G); every advance integrates it, so the
energy is sum(V^2 * G * t) over reads and pulses.
"""

from __future__ import annotations

from collections import defaultdict

from snan_hil.firmware_emu.config import TimingConfig

CATEGORIES = ("spi", "mcu", "settle", "adc", "pulse", "uart")
"""Categories of virtual time: SPI bits, MCU per-transaction overhead, analog settling waits,
waiting for ADC conversion cycles, write-pulse widths, UART bytes."""


class VirtualClock:
    """Board time in us and crossbar energy in J, advanced only by modelled operations."""

    def __init__(self, timing: TimingConfig | None = None, baud: int = 115200):
        self.timing = timing or TimingConfig()
        self.baud = int(baud)
        self.now_us = 0.0
        self.energy_j = 0.0
        self.power_w = 0.0
        self.breakdown_us: dict[str, float] = defaultdict(float)

    # -- core -------------------------------------------------------------------------------
    def advance(self, us: float, category: str) -> None:
        """Let ``us`` microseconds pass; integrates the present array power into the energy."""
        if us <= 0.0:
            return
        self.now_us += us
        self.energy_j += self.power_w * us * 1e-6
        self.breakdown_us[category] += us

    def advance_parts(self, parts: list[tuple[float, str]]) -> None:
        """:meth:`advance` for each ``(us, category)`` in turn, in one call (the same float
        operations in the same order; the power does not change in between)."""
        now, energy, power = self.now_us, self.energy_j, self.power_w
        breakdown = self.breakdown_us
        for us, category in parts:
            if us <= 0.0:
                continue
            now += us
            energy += power * us * 1e-6
            breakdown[category] += us
        self.now_us, self.energy_j = now, energy

    def wait_until(self, t_us: float, category: str) -> None:
        """Advance to time ``t_us`` if it lies in the future."""
        if t_us > self.now_us:
            self.advance(t_us - self.now_us, category)

    def advance_frames(self, count: int, overhead_us: float, bits_us: float, ready_us: float,
                       cycle_us: float) -> list[float]:
        """Time ``count`` SPI frames to one device in one call; returns their start times (us).

        Per frame, exactly what :meth:`SpiBus.transfer` does: ``advance(overhead_us, "mcu")``,
        ``wait_until(ready_us, "adc")``, start, ``advance(bits_us, "spi")``, then the device is
        ready again ``cycle_us`` after the start. The same float operations run in the same
        order, so time, energy and breakdown end bit for bit where ``count`` transfers would
        leave them (the power must not change in between: nothing but the clock moves).
        """
        now, energy, power = self.now_us, self.energy_j, self.power_w
        breakdown = self.breakdown_us
        mcu, adc = breakdown.get("mcu", 0.0), breakdown.get("adc", 0.0)
        spi = breakdown.get("spi", 0.0)
        # The energy of a fixed step is the same float every time: power * us * 1e-6.
        e_overhead, e_bits = power * overhead_us * 1e-6, power * bits_us * 1e-6
        waited = False
        starts = []
        for _ in range(count):
            if overhead_us > 0.0:
                now += overhead_us
                energy += e_overhead
                mcu += overhead_us
            if ready_us > now:
                wait = ready_us - now              # > 0 whenever ready_us > now
                now += wait
                energy += power * wait * 1e-6
                adc += wait
                waited = True
            start = now
            starts.append(start)
            if bits_us > 0.0:
                now += bits_us
                energy += e_bits
                spi += bits_us
            ready_us = start + cycle_us
        self.now_us, self.energy_j = now, energy
        if count and overhead_us > 0.0:
            breakdown["mcu"] = mcu
        if waited:
            breakdown["adc"] = adc
        if count and bits_us > 0.0:
            breakdown["spi"] = spi
        return starts

    def set_power(self, watts: float) -> None:
        """Power dissipated in the array from now on (W); set by the analog front end."""
        self.power_w = float(watts)

    def reset(self) -> None:
        """Zero time, energy and breakdown (board RESET)."""
        self.now_us = 0.0
        self.energy_j = 0.0
        self.breakdown_us.clear()

    # -- unit costs -------------------------------------------------------------------------
    def spi_bits_us(self, nbytes: int) -> float:
        """Duration of ``nbytes`` clocked at the SPI rate (us)."""
        return nbytes * 8 / self.timing.spi_hz * 1e6

    def uart_us(self, nbytes: int) -> float:
        """Duration of ``nbytes`` on the UART at the configured baud, 10 bits per byte (us)."""
        return nbytes * self.timing.uart_bits_per_byte / self.baud * 1e6

    @property
    def adc_cycle_us(self) -> float:
        """Shortest time between two ADC conversion starts (us): 5 us at 200 kS/s."""
        return 1e6 / self.timing.adc_rate_sps

    def uart(self, nbytes: int) -> None:
        """Account ``nbytes`` sent or received over the UART."""
        self.advance(self.uart_us(nbytes), "uart")

    def snapshot(self) -> dict[str, float]:
        """Time, energy and per-category breakdown, for logs and benchmarks."""
        return {"now_us": self.now_us, "energy_j": self.energy_j,
                **{f"{k}_us": self.breakdown_us.get(k, 0.0) for k in CATEGORIES}}
