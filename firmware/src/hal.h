/* Hardware abstraction: the only interface between the portable firmware core (proto.c,
 * ops.c) and the MCU. hal_mik32.c implements it with MIK32 registers; a host build for unit
 * tests could implement it in plain C. Times are timer ticks of the MCU clock (MCU_HZ). */
#ifndef HAL_H
#define HAL_H
#include <stdint.h>

/* SPI devices (board wiring; chip selects on GPIO_0 pins, see docs/firmware.md) */
enum { DEV_DAC0 = 0, DEV_DAC1, DEV_DAC2, DEV_DAC3, DEV_WDAC, DEV_ADC, DEV_SR_ROW, DEV_SR_COL,
       DEV_COUNT };

void hal_init(void);
uint32_t hal_now(void);                     /* free-running tick counter (wraps) */
uint64_t hal_now64(void);                   /* the same, extended to 64 bits */
void hal_wait_until(uint32_t t);            /* busy wait until now - t >= 0 (signed) */
void hal_wait_long(uint64_t t);             /* wait until hal_now64() >= t, kicking the
                                               watchdog (any length) */
void hal_spi_write(int dev, const uint8_t *tx, unsigned n);   /* one chip-select frame */
/* count ADC frames of 16 clocks (zeros out), frame k starting no earlier than
 * t0 + k * spacing ticks; rx gets 2 * count bytes */
void hal_adc_frames(uint8_t *rx, unsigned count, uint32_t spacing);
/* one ADC frame of 16 clocks whose chip select falls no earlier than tick not_before (the
 * TLC3541 samples then); rx gets its 2 bytes (the previous conversion); returns its start.
 * The wait does not serve the UART (it is shorter than a byte: the caller serves it) */
uint32_t hal_adc_frame(uint8_t *rx, uint32_t not_before);
/* SR_COL: latch open_byte, keep it exactly width ticks, then latch 0 */
void hal_pulse(uint8_t open_byte, uint32_t width);
int hal_uart_getc(void);                    /* -1 when no byte is waiting (ring first) */
void hal_uart_service(void);                /* an arrived host byte into the receive ring */
void hal_uart_putc(uint8_t b);
uint32_t hal_entropy(void);                 /* boot-time randomness for the nonce */
void hal_watchdog_kick(void);               /* restart the watchdog (2 s) */
int hal_watchdog_caused_reset(void);        /* the last reset came from the watchdog */
/* the chip serial of the board's EEPROM identity record into out (not terminated); returns
 * its length, 0 when the record is absent or invalid (docs/firmware.md, "Board identity") */
unsigned hal_chip_serial(char *out, unsigned max);

#endif
