/* Board operations: the SPI sequences of reads, pulses, spikes and write-and-verify, with the
 * safety interlocks checked before anything is driven. Portable: uses only hal.h. */
#ifndef OPS_H
#define OPS_H
#include <stdint.h>

typedef struct {
    uint32_t cell_reads, column_reads, pulses_applied, spikes_applied, busy, saturated_reads;
} ops_counters_t;

/* Why a request was refused: ERROR code (0 = not refused), detail and a short text. */
typedef struct {
    uint8_t code;
    uint32_t detail;
    const char *msg;
} refusal_t;

extern ops_counters_t ops_cnt;
extern refusal_t ops_refusal;

uint64_t ops_udiv64(uint64_t n, uint64_t d);
/* One reading of the connected circuit: a dummy conversion, then the rounded average of
 * ADC_AVERAGE conversions (a saturated conversion counts a saturated reading). */
uint16_t ops_adc_read(void);
void ops_boot(void);                /* chips to their start-up state, counters and tables */
int ops_check_cell(unsigned row, unsigned col);
int ops_check_read_code(unsigned code);     /* single-cell read: write-DAC code */
int ops_check_row_code(unsigned code);      /* driven row: row-DAC code */
int ops_read_cell(unsigned row, unsigned col, unsigned code, uint16_t *adc);
int ops_read_column(unsigned col, unsigned n, const uint8_t *codes_le, uint16_t *adc);
int ops_write_pulse(unsigned row, unsigned col, unsigned polarity, unsigned amp,
                    uint32_t width_us, unsigned read_code, uint16_t *adc);
int ops_program_cell(const uint8_t *p, uint8_t *out7);
/* SPIKE_BATCH: payload p (already validated by the protocol layer), n_groups, n_bins,
 * columns bitmask; writes the codes (u16 LE, spike-major) to out. */
int ops_spike_check(const uint8_t *groups, unsigned n_groups, unsigned n_bins, uint32_t bin_us,
                    int paced, uint32_t mask);
int ops_spike_batch(const uint8_t *groups, unsigned n_groups, unsigned n_bins,
                    uint32_t bin_us, uint32_t mask, int paced, uint8_t *out);

#endif
