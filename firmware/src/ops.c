/* Board operations (see ops.h). The sequences are those of the Python model
 * (firmware_emu/firmware.py): the same SPI words in the same order, the same register
 * caching (a register or DAC channel is written only when its value changes), the same
 * settling waits, the same checks in the same order with the same ERROR details. */
#include "ops.h"
#include "hal.h"
#include "snan_constants.h"

ops_counters_t ops_cnt;
refusal_t ops_refusal;

static uint16_t row_code[BOARD_ROWS];      /* row-DAC channel codes as last written */
static uint16_t wdac_code;
static uint8_t sr_row, sr_col;
/* Last single-cell reading per cell at a read code above 0 for the compliance prediction: ADC
 * code and read code; read code 0 = no such reading since boot (a 0 V read is none). */
static uint16_t last_adc[BOARD_ROWS][BOARD_COLS];
static uint16_t last_rc[BOARD_ROWS][BOARD_COLS];

static int refuse(uint8_t code, uint32_t detail, const char *msg)
{
    ops_refusal.code = code;
    ops_refusal.detail = detail;
    ops_refusal.msg = msg;
    return code;
}

/* ------------------------------------------------------------------ drivers */
static void write16(int dev, uint16_t word)
{
    uint8_t b[2] = {(uint8_t)(word >> 8), (uint8_t)word};
    hal_spi_write(dev, b, 2);
}

static void write8(int dev, uint8_t v) { hal_spi_write(dev, &v, 1); }

static void set_sr_row(uint8_t v)
{
    if (v != sr_row) {
        write8(DEV_SR_ROW, v);
        sr_row = v;
    }
}

static void set_sr_col(uint8_t v)
{
    if (v != sr_col) {
        write8(DEV_SR_COL, v);
        sr_col = v;
    }
}

static void set_wdac(uint16_t code)
{
    if (code != wdac_code) {
        write16(DEV_WDAC, (uint16_t)(code & 0x0FFFu));
        wdac_code = code;
    }
}

static void set_row(unsigned row, uint16_t code)
{
    if (row_code[row] != code) {
        write16(DEV_DAC0 + (int)(row / 8u),
                (uint16_t)(((row % 8u) << 12) | (code & 0x0FFFu)));
        row_code[row] = code;
    }
}

static void zero_rows(void)
{
    for (unsigned r = 0; r < BOARD_ROWS; r++)
        if (row_code[r])
            set_row(r, 0);
}

static void settle(uint32_t ticks) { hal_wait_until(hal_now() + ticks); }

static uint8_t row_select(unsigned row)
{
    return (uint8_t)((row & SR_MUX_ADDR_MASK) | (row >= 16 ? SR_MUX_HI_EN : SR_MUX_LO_EN));
}

static uint8_t col_select(unsigned col, int sum, int set_pol, int pulse)
{
    uint8_t v = (uint8_t)((col & SR_WL_ADDR_MASK) | SR_WL_EN);
    if (sum) v |= SR_SUM_PATH;
    if (set_pol) v |= SR_POL_SET;
    if (pulse) v |= SR_PULSE_GATE;
    return v;
}

/* One dummy conversion, then the rounded average of ADC_AVERAGE (TLC3541: each frame returns
 * the previous conversion, value = (b0 << 6) | (b1 >> 2)). The one ADC reading of every
 * operation (window.c's standard read plan too). */
uint16_t ops_adc_read(void)
{
    uint8_t rx[2 * ADC_FRAMES];
    hal_adc_frames(rx, ADC_FRAMES, ADC_CYCLE_TICKS);
    uint32_t sum = 0;
    int saturated = 0;
    for (unsigned k = ADC_DUMMY; k < ADC_FRAMES; k++) {
        uint32_t code = ((uint32_t)rx[2 * k] << 6) | ((uint32_t)rx[2 * k + 1] >> 2);
        if (code >= BOARD_ADC_FULL)
            saturated = 1;
        sum += code;
    }
    if (saturated)
        ops_cnt.saturated_reads++;
    return (uint16_t)((sum + ADC_AVERAGE / 2u) / ADC_AVERAGE);
}

static void idle(void)
{
    set_sr_col(0);
    set_sr_row(0);
    set_wdac(0);
}

static void init_chips(void)
{
    for (int d = DEV_DAC0; d <= DEV_DAC3; d++) {
        write16(d, AD5328_INIT_RESET);
        write16(d, AD5328_INIT_CONTROL);
        write16(d, AD5328_INIT_LDAC);
    }
    write16(DEV_WDAC, 0);
    write8(DEV_SR_ROW, 0);
    write8(DEV_SR_COL, 0);
    for (unsigned r = 0; r < BOARD_ROWS; r++)
        row_code[r] = 0;
    wdac_code = 0;
    sr_row = sr_col = 0;
}

void ops_boot(void)
{
    ops_counters_t zero = {0};
    ops_cnt = zero;
    for (unsigned r = 0; r < BOARD_ROWS; r++)
        for (unsigned c = 0; c < BOARD_COLS; c++)
            last_rc[r][c] = 0;
    init_chips();
}

/* ------------------------------------------------------------------ checks */
int ops_check_cell(unsigned row, unsigned col)
{
    if (row >= BOARD_ROWS)
        return refuse(ERR_OUT_OF_RANGE, row, "row outside the array");
    if (col >= BOARD_COLS)
        return refuse(ERR_OUT_OF_RANGE, col, "column outside the array");
    return 0;
}

/* A read code of a DAC with full-scale code `full`, at most `max_code` (the read limit). */
static int check_dac_read_code(unsigned code, unsigned full, unsigned max_code)
{
    if (code > full)
        return refuse(ERR_OUT_OF_RANGE, code, "DAC code outside the DAC range");
    if (code > max_code)
        return refuse(ERR_SAFETY_LIMIT, code, "read voltage above the read limit");
    return 0;
}

/* A single-cell read code: a write-DAC code (the cell-read path is driven by the write DAC). */
int ops_check_read_code(unsigned code)
{
    return check_dac_read_code(code, BOARD_WDAC_FULL, BOARD_CELL_READ_CODE_MAX);
}

/* A driven row's code (READ_COLUMN, SPIKE_BATCH): a row-DAC code. */
int ops_check_row_code(unsigned code)
{
    return check_dac_read_code(code, BOARD_DAC_FULL, BOARD_ROW_READ_CODE_MAX);
}

/* The cell, and the read after a pulse: *read_code 0 becomes the nominal read code. */
static int check_cell_and_read_code(unsigned row, unsigned col, unsigned *read_code)
{
    int e;
    if ((e = ops_check_cell(row, col)))
        return e;
    if (*read_code == 0)
        *read_code = BOARD_READ_CODE;
    return ops_check_read_code(*read_code);
}

/* 64-bit unsigned division by shift and subtract (freestanding: no compiler runtime). */
uint64_t ops_udiv64(uint64_t n, uint64_t d)
{
    uint64_t q = 0, r = 0;
    for (int i = 63; i >= 0; i--) {
        r = (r << 1) | ((n >> i) & 1u);
        if (r >= d) {
            r -= d;
            q |= (uint64_t)1 << i;
        }
    }
    return q;
}

/* Compliance from the last reading (firmware_emu/compliance.py: the same integer formula). */
static int over_compliance(unsigned row, unsigned col, unsigned amp, uint32_t *ua)
{
    hal_uart_service();          /* a ramp held below the limit checks many amplitudes */
    uint64_t adc = last_adc[row][col], rc = last_rc[row][col];
    uint64_t num = COMPLIANCE_K_NUM * amp * adc;
    uint64_t pos = COMPLIANCE_K_RC * rc, neg = COMPLIANCE_K_ADC * adc;
    if (pos <= neg) {
        *ua = 0xFFFFFFFFu;
        return 1;
    }
    uint64_t den = pos - neg;
    uint64_t r = ops_udiv64(2u * num + den, 2u * den);
    *ua = r > 0xFFFFFFFFull ? 0xFFFFFFFFu : (uint32_t)r;
    return num > COMPLIANCE_LIMIT_UA * den;
}

/* ------------------------------------------------------------------ operations */
static uint16_t read_cell(unsigned row, unsigned col, unsigned vcode)
{
    set_sr_col(col_select(col, 0, 0, 0));
    set_sr_row(row_select(row));
    set_wdac((uint16_t)vcode);
    settle(DAC_SETTLE_TICKS);
    uint16_t adc = ops_adc_read();
    idle();
    ops_cnt.cell_reads++;
    if (vcode) {       /* a 0 V read (the offset) is no compliance basis: keep the last one */
        last_adc[row][col] = adc;
        last_rc[row][col] = (uint16_t)vcode;
    }
    return adc;
}

int ops_read_cell(unsigned row, unsigned col, unsigned code, uint16_t *adc)
{
    int e;
    if ((e = ops_check_cell(row, col)) || (e = ops_check_read_code(code)))
        return e;
    *adc = read_cell(row, col, code);
    return 0;
}

int ops_read_column(unsigned col, unsigned n, const uint8_t *codes_le, uint16_t *adc)
{
    int e;
    if ((e = ops_check_cell(0, col)))
        return e;
    if (n != BOARD_ROWS)
        return refuse(ERR_OUT_OF_RANGE, n, "READ_COLUMN needs one code per row");
    for (unsigned i = 0; i < n; i++)
        if ((e = ops_check_row_code(codes_le[2 * i] | (codes_le[2 * i + 1] << 8))))
            return e;
    set_sr_col(0);
    set_sr_row(SR_ROWDAC_EN);
    for (unsigned i = 0; i < n; i++)
        set_row(i, (uint16_t)(codes_le[2 * i] | (codes_le[2 * i + 1] << 8)));
    set_sr_col(col_select(col, 1, 0, 0));
    settle(SETTLE_TICKS);
    *adc = ops_adc_read();
    set_sr_col(0);
    zero_rows();
    set_sr_row(0);
    ops_cnt.column_reads++;
    return 0;
}

static void pulse(unsigned row, unsigned col, int set_pol, unsigned amp, uint32_t width_us)
{
    set_sr_col(0);
    set_wdac((uint16_t)amp);
    set_sr_row(row_select(row));
    settle(DAC_SETTLE_TICKS);
    hal_pulse(col_select(col, 0, set_pol, 1), width_us * TICKS_PER_US);
    sr_col = 0;
    set_wdac(0);
    ops_cnt.pulses_applied++;
}

static int check_write(unsigned row, unsigned col, unsigned amp, uint32_t width_us,
                       unsigned read_code)
{
    if (amp > BOARD_WDAC_FULL)
        return refuse(ERR_OUT_OF_RANGE, amp, "amplitude code outside the DAC range");
    if (width_us < 1 || width_us > BOARD_MAX_WIDTH_US)
        return refuse(ERR_OUT_OF_RANGE, width_us, "pulse width outside 1..1000000 us");
    if (amp > BOARD_WRITE_CODE_MAX)
        return refuse(ERR_SAFETY_LIMIT, amp, "write amplitude above the write limit");
    if (last_rc[row][col] == 0)
        (void)read_cell(row, col, read_code);      /* no reading since boot: read first */
    uint32_t ua;
    if (over_compliance(row, col, amp, &ua))
        return refuse(ERR_SAFETY_LIMIT, ua, "predicted current above the compliance");
    return 0;
}

int ops_write_pulse(unsigned row, unsigned col, unsigned polarity, unsigned amp,
                    uint32_t width_us, unsigned read_code, uint16_t *adc)
{
    int e;
    if ((e = check_cell_and_read_code(row, col, &read_code)))
        return e;
    if (amp) {
        if ((e = check_write(row, col, amp, width_us, read_code)))
            return e;
        hal_watchdog_kick();
        pulse(row, col, polarity == POL_SET, amp, width_us);
    }
    *adc = read_cell(row, col, read_code);
    return 0;
}

/* ------------------------------------------------------------------ PROGRAM_CELL */
static struct {
    unsigned row, col, read_code;
    int32_t start, stop, step;
    uint32_t width_us;
    int32_t budget;
    int32_t target, tol;
} pc;

enum { DONE_WINDOW_OR_PAST_SET, DONE_WINDOW_OR_PAST_RESET, DONE_LE_TARGET, DONE_GE_TARGET };

static int in_window(int32_t a)
{
    int32_t d = a - pc.target;
    return (d < 0 ? -d : d) <= pc.tol;
}

static int done(int kind, int32_t a)
{
    switch (kind) {
    case DONE_WINDOW_OR_PAST_SET: return in_window(a) || a > pc.target;
    case DONE_WINDOW_OR_PAST_RESET: return in_window(a) || a < pc.target;
    case DONE_LE_TARGET: return a <= pc.target;
    default: return a >= pc.target;
    }
}

/* Pulses of one polarity with a rising amplitude until done (the Python model's ramp()). */
static int32_t ramp(int32_t adc, int set_pol, int kind, uint32_t *used_out)
{
    int32_t amp = pc.start, cap = pc.stop;
    uint32_t used = 0, ua;
    while (!done(kind, adc) && pc.budget > 0) {
        while (amp >= pc.start && over_compliance(pc.row, pc.col, (unsigned)amp, &ua))
            cap = amp = amp - pc.step;               /* hold the ramp below the limit */
        if (amp < pc.start)
            break;
        hal_watchdog_kick();
        pulse(pc.row, pc.col, set_pol, (unsigned)amp, pc.width_us);
        adc = read_cell(pc.row, pc.col, pc.read_code);
        used++;
        pc.budget--;
        amp = amp + pc.step < cap ? amp + pc.step : cap;
    }
    *used_out = used;
    return adc;
}

static unsigned u16le(const uint8_t *p) { return (unsigned)(p[0] | (p[1] << 8)); }
static uint32_t u32le(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
           ((uint32_t)p[3] << 24);
}

int ops_program_cell(const uint8_t *p, uint8_t *out)
{
    /* "<BBHHHHHHIH?": row col target tol max start stop step width read fine */
    unsigned row = p[0], col = p[1];
    int32_t target = (int32_t)u16le(p + 2), tol = (int32_t)u16le(p + 4);
    int32_t max_pulses = (int32_t)u16le(p + 6);
    int32_t start = (int32_t)u16le(p + 8), stop = (int32_t)u16le(p + 10);
    int32_t step = (int32_t)u16le(p + 12);
    uint32_t width = u32le(p + 14);
    unsigned read_code = u16le(p + 18);
    int fine = p[20] != 0;
    int e;
    if ((e = check_cell_and_read_code(row, col, &read_code)))
        return e;
    if (!start) start = PROGRAM_DEFAULT_START;
    if (!stop) stop = PROGRAM_DEFAULT_STOP;
    if (!step) step = PROGRAM_DEFAULT_STEP;
    if (max_pulses < 1 || max_pulses > BOARD_MAX_PROGRAM_PULSES)
        return refuse(ERR_OUT_OF_RANGE, (uint32_t)max_pulses, "max_pulses outside 1..1000");
    if (target > BOARD_ADC_FULL)
        return refuse(ERR_OUT_OF_RANGE, (uint32_t)target, "target outside the ADC range");
    if (!(1 <= start && start <= stop) || step < 1)
        return refuse(ERR_OUT_OF_RANGE, (uint32_t)start, "invalid amplitude ramp");
    if (stop > BOARD_WRITE_CODE_MAX)
        return refuse(ERR_SAFETY_LIMIT, (uint32_t)stop, "ramp end above the write limit");
    if (width < 1 || width > BOARD_MAX_WIDTH_US)
        return refuse(ERR_OUT_OF_RANGE, width, "pulse width outside 1..1000000 us");
    pc.row = row; pc.col = col; pc.read_code = read_code;
    pc.start = start; pc.stop = stop; pc.step = step; pc.width_us = width;
    pc.budget = max_pulses; pc.target = target; pc.tol = tol;

    int32_t adc = read_cell(row, col, read_code);
    uint32_t stage1 = 0, stage2 = 0, used;
    while (!in_window(adc) && pc.budget > 0) {
        int set_pol = adc < target;
        int32_t before = pc.budget;
        adc = ramp(adc, set_pol, set_pol ? DONE_WINDOW_OR_PAST_SET : DONE_WINDOW_OR_PAST_RESET,
                   &used);
        stage1 += used;
        if (pc.budget == before)
            break;                                   /* nothing could be applied */
    }
    if (fine && in_window(adc)) {
        adc = ramp(adc, 0, DONE_LE_TARGET, &used);
        stage2 += used;
        adc = ramp(adc, 1, DONE_GE_TARGET, &used);
        stage2 += used;
    }
    out[0] = (uint8_t)adc; out[1] = (uint8_t)(adc >> 8);
    out[2] = (uint8_t)stage1; out[3] = (uint8_t)(stage1 >> 8);
    out[4] = (uint8_t)stage2; out[5] = (uint8_t)(stage2 >> 8);
    out[6] = (uint8_t)in_window(adc);
    return 0;
}

/* ------------------------------------------------------------------ SPIKE_BATCH */
/* groups: n_groups x [u8 n_rows, n_rows x (u8 row, u16 code), ceil(n_bins/8) bitmap] */
/* The checks of docs/protocol.md (SPIKE_BATCH), in the Python model's order. */
int ops_spike_check(const uint8_t *g, unsigned n_groups, unsigned n_bins, uint32_t bin_us,
                    int paced, uint32_t mask)
{
    int e;
    unsigned nbytes = (n_bins + 7u) / 8u;
    if (n_bins == 0)
        return refuse(ERR_OUT_OF_RANGE, 0, "n_bins 0");
    if (paced && bin_us == 0)
        return refuse(ERR_OUT_OF_RANGE, 0, "bin_us 0 with paced");
    for (unsigned c = 0; c < 32; c++)
        if ((mask >> c) & 1u)
            if ((e = ops_check_cell(0, c)))
                return e;
    for (unsigned k = 0; k < n_groups; k++) {
        unsigned nr = *g++;
        if (nr == 0)
            return refuse(ERR_OUT_OF_RANGE, k, "group drives no row");
        const uint8_t *rows = g;
        for (unsigned i = 0; i < nr; i++, g += 3) {
            if ((e = ops_check_cell(g[0], 0)))
                return e;
            for (unsigned j = 0; j < i; j++)
                if (rows[3 * j] == g[0])
                    return refuse(ERR_OUT_OF_RANGE, g[0], "row repeated in a group");
            if ((e = ops_check_row_code(u16le(g + 1))))
                return e;
        }
        g += nbytes;
    }
    return 0;
}

static void spike(const uint8_t *grp, uint32_t mask, uint8_t **out)
{
    unsigned nr = grp[0];
    const uint8_t *rows = grp + 1;
    for (unsigned i = 0; i < nr; i++)            /* rows are distinct (ops_spike_check) */
        set_row(rows[3 * i], (uint16_t)u16le(rows + 3 * i + 1));
    settle(DAC_SETTLE_TICKS);
    unsigned ncols = 0;
    for (unsigned c = 0; c < 32; c++) {
        if (!((mask >> c) & 1u))
            continue;
        set_sr_col(col_select(c, 1, 0, 0));
        settle(SETTLE_TICKS);
        uint16_t a = ops_adc_read();
        (*out)[0] = (uint8_t)a;
        (*out)[1] = (uint8_t)(a >> 8);
        *out += 2;
        ncols++;
    }
    set_sr_col(0);
    zero_rows();
    ops_cnt.spikes_applied++;
    ops_cnt.column_reads += ncols;
}

int ops_spike_batch(const uint8_t *g, unsigned n_groups, unsigned n_bins, uint32_t bin_us,
                    uint32_t mask, int paced, uint8_t *out)
{
    unsigned nbytes = (n_bins + 7u) / 8u;
    const uint8_t *base = g;
    /* a group is [n_rows, n_rows x (row, code), bitmap]: walked in place (no table of offsets:
     * its 512 B of RAM are the MCU's free RAM) */
#define BITMAP(grp) ((grp) + 1u + 3u * (grp)[0])
    uint64_t t0 = hal_now64();
    uint64_t bin_ticks = (uint64_t)bin_us * TICKS_PER_US;
    set_sr_col(0);
    set_sr_row(SR_ROWDAC_EN);
    for (unsigned byte = 0; byte < nbytes; byte++) {
        int any = 0;
        const uint8_t *grp = base;
        for (unsigned k = 0; k < n_groups && !any; k++) {
            any = BITMAP(grp)[byte] != 0;
            grp = BITMAP(grp) + nbytes;
        }
        if (!any)
            continue;
        for (unsigned bit = 0; bit < 8; bit++) {
            unsigned b = 8u * byte + bit;
            grp = base;
            for (unsigned k = 0; k < n_groups; k++, grp = BITMAP(grp) + nbytes) {
                if (!((BITMAP(grp)[byte] >> bit) & 1u))
                    continue;
                if (paced)
                    hal_wait_long(t0 + b * bin_ticks);
                hal_watchdog_kick();
                spike(grp, mask, &out);
            }
        }
    }
    set_sr_row(0);
    return 0;
}
