/* DECISION_WINDOW: one decision window on the board (see window.h). The same checks, SPI
 * sequence and integer arithmetic as the Python model (firmware_emu/decision_window.py,
 * firmware_emu/lif_fixed.py), streamed: each read becomes a drive at once, nothing of the
 * window is buffered (the parameter block, four lanes of state and the reply being written).
 *
 * Between requests the board is idle: every row DAC at 0, both shift registers 0, the write
 * DAC at 0 (ops.c leaves it so after every operation). The drivers here start from that
 * state and end in it, so ops.c's register caches stay true. */
#include "window.h"
#include "hal.h"
#include "ops.h"
#include "snan_constants.h"

#define GOLDEN 0x9E3779B97F4A7C15ull
#define MUL1 0xBF58476D1CE4E5B9ull
#define MUL2 0x94D049BB133111EBull
#define LIM56 ((int64_t)1 << 56)
#define POT_LIMIT ((int64_t)1 << 62)
#define HALF ((uint64_t)1 << 31)

typedef struct {
    uint16_t n_bins, bin_us, row_code, ref_steps;
    uint8_t lif_flags, num_shift, den_shift, q_shift;
    uint64_t threshold;
    uint32_t a_hi[DW_ALPHA_TABLE], a_lo[DW_ALPHA_TABLE];   /* alpha^1 .. alpha^16, Q0.64 */
    int64_t thr, reset, inh, offset, d, k1, k0;
} params_t;

static params_t prm;           /* the stored block */
static uint8_t have_prm;

void window_clear(void) { have_prm = 0; }

static uint32_t g16(const uint8_t *p) { return (uint32_t)(p[0] | (p[1] << 8)); }
static uint32_t g32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static uint64_t g64(const uint8_t *p) { return (uint64_t)g32(p) | ((uint64_t)g32(p + 4) << 32); }
static void p16(uint8_t *p, uint32_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void p32(uint8_t *p, uint32_t v) { p16(p, v); p16(p + 2, v >> 16); }

static void parse_params(const uint8_t *b, params_t *q)
{
    q->n_bins = (uint16_t)g16(b);
    q->bin_us = (uint16_t)g16(b + 2);
    q->row_code = (uint16_t)g16(b + 4);
    q->ref_steps = (uint16_t)g16(b + 6);
    q->lif_flags = b[8];
    q->num_shift = b[9];
    q->den_shift = b[10];
    q->q_shift = b[11];
    q->threshold = g64(b + 12);
    for (unsigned k = 0; k < DW_ALPHA_TABLE; k++) {
        q->a_lo[k] = g32(b + 20 + 8 * k);
        q->a_hi[k] = g32(b + 24 + 8 * k);
    }
    b += 8 * DW_ALPHA_TABLE;                         /* the fields after the table */
    q->thr = (int64_t)g64(b + 20);
    q->reset = (int64_t)g64(b + 28);
    q->inh = (int64_t)g64(b + 36);
    q->offset = (int64_t)g64(b + 44);
    q->d = (int64_t)g64(b + 52);
    q->k1 = (int64_t)g64(b + 60);
    q->k0 = (int64_t)g64(b + 68);
}

/* one unsigned LEB128 gap of at most DW_VARINT_BYTES bytes; *pos advances */
static uint32_t varint(const uint8_t *p, unsigned *pos)
{
    uint32_t v = 0;
    for (unsigned i = 0; i < DW_VARINT_BYTES; i++) {
        uint8_t b = p[(*pos)++];
        v |= (uint32_t)(b & 0x7Fu) << (7u * i);
        if (!(b & 0x80u))
            break;
    }
    return v;
}

/* ------------------------------------------------------------------ decoding */
int window_malformed(const uint8_t *p, unsigned n)
{
    unsigned pos = 0;
    if (n < 1)
        return 1;
    uint8_t flags = p[pos++];
    if (flags & ~(unsigned)(DW_FLAG_PARAMS | DW_FLAG_MOTOR_SPIKES | DW_FLAG_TRACE | DW_FLAG_PACED))
        return 1;
    if (flags & DW_FLAG_PARAMS) {
        if (pos + DW_PARAMS_SIZE > n || (p[pos + 8] & ~(unsigned)DW_LIF_INTEGRATE))
            return 1;
        pos += DW_PARAMS_SIZE;
    }
    pos += 8;                                        /* key */
    if (flags & DW_FLAG_TRACE) {
        if (pos + 2 > n || g16(p + pos) == 0)
            return 1;                                /* a stride of 0 */
        pos += 2;
    }
    if (pos + 1 > n)
        return 1;
    uint8_t layout = p[pos++];
    if (layout & 0x88u)
        return 1;
    pos += layout & 0x07u;                           /* rows */
    for (unsigned k = 0; k < (layout >> 4); k++) {
        if (pos + 1 > n)
            return 1;
        uint8_t cell = p[pos++];
        if (!(cell & 0x80u))
            continue;
        if (pos + 1 > n)
            return 1;
        unsigned m = p[pos++];
        if (m == 0)
            return 1;
        for (unsigned j = 0; j < m; j++) {
            unsigned i = 0;
            for (;;) {
                if (pos + 1 > n)
                    return 1;
                uint8_t b = p[pos++];
                if (!(b & 0x80u))
                    break;
                if (++i == DW_VARINT_BYTES)
                    return 1;                        /* a gap longer than 3 bytes */
            }
        }
    }
    return pos != n;
}

/* ------------------------------------------------------------------ checks */
static int refuse(uint8_t code, uint32_t detail, const char *msg)
{
    ops_refusal.code = code;
    ops_refusal.detail = detail;
    ops_refusal.msg = msg;
    return code;
}

static int conversion_fits(const params_t *q)
{
    if (!(q->d > 0 && q->d < ((int64_t)1 << 62) && q->den_shift <= 62 && q->num_shift <= 17))
        return 0;
    if (((uint64_t)q->d >> q->den_shift) >= ((uint64_t)1 << 32))
        return 0;
    int64_t x_max = ((int64_t)BOARD_ADC_FULL << 32) - q->offset;
    if (x_max <= 0)
        return 1;
    int64_t den_min = (q->d - x_max) >> q->den_shift;
    return den_min >= 1 && ((((uint64_t)x_max << q->num_shift) >> 32) < (uint64_t)den_min);
}

static int out_of(int64_t v, int64_t lo, int64_t hi) { return v < lo || v > hi; }

/* the new block's fields in the documented order; detail = the field's byte offset */
static int check_params(const params_t *q)
{
    int e;
    if (q->n_bins < 1 || q->n_bins > DW_MAX_BINS)
        return refuse(ERR_OUT_OF_RANGE, q->n_bins, "n_bins outside 1..16384");
    if (q->row_code == 0)
        return refuse(ERR_OUT_OF_RANGE, 0, "row code 0");
    if ((e = ops_check_row_code(q->row_code)))
        return e;
    if (q->num_shift > 17)
        return refuse(ERR_OUT_OF_RANGE, 9, "num_shift > 17");
    if (q->den_shift > 62)
        return refuse(ERR_OUT_OF_RANGE, 10, "den_shift > 62");
    if (q->q_shift > 31)
        return refuse(ERR_OUT_OF_RANGE, 11, "q_shift > 31");
    if (q->threshold > ((uint64_t)1 << 53))
        return refuse(ERR_OUT_OF_RANGE, 12, "spike threshold above 2^53");
    if (out_of(q->thr, 1, LIM56))
        return refuse(ERR_OUT_OF_RANGE, 148, "threshold outside 1..2^56");
    if (out_of(q->reset, -LIM56, LIM56) || q->reset >= q->thr)
        return refuse(ERR_OUT_OF_RANGE, 156, "reset beyond 2^56 or not below the threshold");
    if (out_of(q->inh, 0, LIM56))
        return refuse(ERR_OUT_OF_RANGE, 164, "inhibition outside 0..2^56");
    if (out_of(q->offset, 0, ((int64_t)1 << 46) - 1))
        return refuse(ERR_OUT_OF_RANGE, 172, "offset outside 0..2^46");
    if (!conversion_fits(q))
        return refuse(ERR_OUT_OF_RANGE, 180, "code conversion out of range");
    if (out_of(q->k1, 0, LIM56))
        return refuse(ERR_OUT_OF_RANGE, 188, "k1 outside 0..2^56");
    if (out_of(q->k0, -LIM56, LIM56))
        return refuse(ERR_OUT_OF_RANGE, 196, "k0 beyond 2^56");
    return 0;
}

/* ------------------------------------------------------------------ arithmetic */
/* floor(n / d) for (n >> 32) < d: RV32M divides 32 by 32 bits only, so the 64-by-32-bit
 * division is done in two 16-bit quotient digits on a normalised divisor, each estimated with
 * DIVU and corrected (Knuth's algorithm D for two digits, as in Hacker's Delight "divlu") */
static uint32_t div64_32(uint64_t n, uint32_t v)
{
    uint32_t u1 = (uint32_t)(n >> 32), u0 = (uint32_t)n;
    unsigned s = 0;
    while (!(v & 0x80000000u)) {
        v <<= 1;
        s++;
    }
    if (s) {
        u1 = (u1 << s) | (u0 >> (32u - s));
        u0 <<= s;
    }
    uint32_t vn1 = v >> 16, vn0 = v & 0xFFFFu;
    uint32_t un1 = u0 >> 16, un0 = u0 & 0xFFFFu;
    uint32_t q1 = u1 / vn1, rhat = u1 - q1 * vn1;
    while (q1 >= 0x10000u || q1 * vn0 > ((rhat << 16) | un1)) {
        q1--;
        rhat += vn1;
        if (rhat >= 0x10000u)
            break;
    }
    uint32_t un21 = (u1 << 16) + un1 - q1 * v;
    uint32_t q0 = un21 / vn1;
    rhat = un21 - q0 * vn1;
    while (q0 >= 0x10000u || q0 * vn0 > ((rhat << 16) | un0)) {
        q0--;
        rhat += vn1;
        if (rhat >= 0x10000u)
            break;
    }
    return (q1 << 16) | q0;
}

/* drive of one read, Q32.32 (firmware_emu/lif_fixed.py, drive_ref) */
static int64_t drive_of(const params_t *q, unsigned code)
{
    int64_t x = ((int64_t)code << 32) - q->offset;
    uint32_t quo = 0;
    if (x > 0) {
        uint32_t den = (uint32_t)((q->d - x) >> q->den_shift);
        quo = div64_32((uint64_t)x << q->num_shift, den);
    }
    /* k1 <= 2^56: its high word fits int32 */
    int64_t a = (int64_t)(int32_t)(q->k1 >> 32) * (int64_t)quo
                + (int64_t)(((uint64_t)(uint32_t)q->k1 * quo) >> 32);
    return (a >> q->q_shift) - q->k0;
}

/* round(u a_h / 2^32) + round'(u a_l / 2^64) (lif_fixed.mul_alpha_ref) */
static int64_t mul_alpha(int64_t u, uint32_t ah, uint32_t al)
{
    /* |u| <= 2^62, so its high word fits int32: 32 x 32 -> 64-bit products (mul, mulhsu) */
    int32_t uh = (int32_t)(u >> 32);
    uint32_t ul = (uint32_t)u;
    int64_t p1 = (int64_t)uh * (int64_t)ah + (int64_t)(((uint64_t)ul * ah + HALF) >> 32);
    int64_t p2 = ((int64_t)uh * (int64_t)al + (int64_t)(((uint64_t)ul * al) >> 32)
                  + (int64_t)HALF) >> 32;
    return p1 + p2;
}

/* alpha^m u for m >= 0: alpha^16 while more than 16 steps are left, then alpha^m
 * (lif_fixed.decay_ref) */
static int64_t decay(const params_t *q, int64_t u, uint32_t m)
{
    while (m > DW_ALPHA_TABLE) {
        u = mul_alpha(u, q->a_hi[DW_ALPHA_TABLE - 1], q->a_lo[DW_ALPHA_TABLE - 1]);
        m -= DW_ALPHA_TABLE;
    }
    return m ? mul_alpha(u, q->a_hi[m - 1], q->a_lo[m - 1]) : u;
}

/* The first step >= t with an input spike (n if none), drawing every step on the way: step t's
 * draw is mix(key + (t + 1) GOLDEN); *state holds key + t GOLDEN on entry and the state of the
 * returned step on return. A tight loop: it runs every step of the window. */
__attribute__((noinline))   /* its own registers: the constants stay in them */
static uint32_t next_spike(uint64_t *state, uint32_t t, uint32_t n, uint64_t threshold)
{
    uint64_t s = *state;
    for (; t < n; t++) {
        s += GOLDEN;
        uint64_t z = s;
        z = (z ^ (z >> 30)) * MUL1;
        z = (z ^ (z >> 27)) * MUL2;
        z ^= z >> 31;
        if ((z >> 11) < threshold)
            break;
    }
    *state = s;
    return t;
}

/* ------------------------------------------------------------------ drivers (from idle) */
static uint8_t sr_col, sr_row;
static unsigned driven_row;

static void write16(int dev, uint16_t w)
{
    uint8_t b[2] = {(uint8_t)(w >> 8), (uint8_t)w};
    hal_spi_write(dev, b, 2);
}

static void set_sr_col(uint8_t v)
{
    if (v != sr_col) {
        hal_spi_write(DEV_SR_COL, &v, 1);
        sr_col = v;
    }
}

static void set_sr_row(uint8_t v)
{
    if (v != sr_row) {
        hal_spi_write(DEV_SR_ROW, &v, 1);
        sr_row = v;
    }
}

static void set_row(unsigned row, uint16_t code)
{
    write16(DEV_DAC0 + (int)(row / 8u), (uint16_t)(((row % 8u) << 12) | (code & 0x0FFFu)));
}

static void settle(uint32_t ticks) { hal_wait_until(hal_now() + ticks); }

/* one dummy conversion, then the rounded average (ops.c adc_read) */
static uint16_t adc_read(void)
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

/* ------------------------------------------------------------------ the window */
int window_run(const uint8_t *p, unsigned n, uint8_t *out, unsigned *len)
{
    params_t incoming;
    const params_t *q = &prm;
    unsigned pos = 0, e;
    (void)n;
    uint8_t flags = p[pos++];
    if (flags & DW_FLAG_PARAMS) {
        parse_params(p + pos, &incoming);
        pos += DW_PARAMS_SIZE;
        q = &incoming;
    } else if (!have_prm) {
        return refuse(ERR_OUT_OF_RANGE, 0, "no window parameters stored: send them (PARAMS)");
    }
    uint64_t key = g64(p + pos);
    pos += 8;
    unsigned stride = 0;
    if (flags & DW_FLAG_TRACE) {
        stride = g16(p + pos);
        pos += 2;
    }
    uint8_t layout = p[pos++];
    unsigned n_rows = layout & 0x07u, n_c = layout >> 4;
    const uint8_t *rows = p + pos;
    pos += n_rows;
    int paced = (flags & DW_FLAG_PACED) != 0;

    if ((flags & DW_FLAG_PARAMS) && (e = (unsigned)check_params(q)))
        return (int)e;
    if (paced && q->bin_us == 0)
        return refuse(ERR_OUT_OF_RANGE, 2, "bin_us 0 with PACED");
    if (n_rows > DW_MAX_ROWS)
        return refuse(ERR_OUT_OF_RANGE, n_rows, "more than 4 rows");
    for (unsigned i = 0; i < n_rows; i++) {
        if ((e = (unsigned)ops_check_cell(rows[i], 0)))
            return (int)e;
        for (unsigned j = 0; j < i; j++)
            if (rows[j] == rows[i])
                return refuse(ERR_OUT_OF_RANGE, rows[i], "row named twice");
    }
    if (n_c > DW_MAX_CANDIDATES)
        return refuse(ERR_OUT_OF_RANGE, n_c, "more than 4 candidates");
    uint8_t col[DW_MAX_CANDIDATES], ri[DW_MAX_CANDIDATES];
    unsigned ipos[DW_MAX_CANDIDATES], left[DW_MAX_CANDIDATES];
    int32_t next_inh[DW_MAX_CANDIDATES];
    uint32_t ucols = 0;
    for (unsigned k = 0; k < n_c; k++) {
        uint8_t cell = p[pos++];
        col[k] = cell & 0x1Fu;
        ri[k] = (cell >> 5) & 0x03u;
        left[k] = 0;
        next_inh[k] = -1;
        if ((e = (unsigned)ops_check_cell(0, col[k])))
            return (int)e;
        if (ri[k] >= n_rows)
            return refuse(ERR_OUT_OF_RANGE, ri[k], "candidate row index beyond the rows");
        ucols |= 1u << col[k];
        if (cell & 0x80u) {
            unsigned m = p[pos++];
            ipos[k] = pos;
            left[k] = m;
            int32_t t = -1;
            for (unsigned j = 0; j < m; j++) {
                t += (int32_t)varint(p, &pos) + 1;
                if (t >= (int32_t)q->n_bins)
                    return refuse(ERR_OUT_OF_RANGE, (uint32_t)t, "interneuron spike after the window");
            }
        }
    }
    unsigned points = stride ? ((unsigned)q->n_bins + stride - 1u) / stride : 0;
    uint32_t size = 3u + 2u * n_c;
    if (stride)
        size += 2u + 4u * n_c * points;
    if (flags & DW_FLAG_MOTOR_SPIKES)
        size += 2u * n_c * (((uint32_t)q->n_bins + q->ref_steps) / ((uint32_t)q->ref_steps + 1u));
    if (size > PROTO_MAX_PAYLOAD)
        return refuse(ERR_OUT_OF_RANGE, size, "reply could exceed the max payload");

    /* accepted: keep the block, run the window */
    if (q == &incoming) {
        parse_params(p + 1, &prm);                 /* (a struct copy would call memcpy) */
        have_prm = 1;
        q = &prm;
    }
    for (unsigned k = 0; k < n_c; k++)               /* first interneuron spike per lane */
        if (left[k]) {
            next_inh[k] = (int32_t)varint(p, &ipos[k]);
            left[k]--;
        }
    unsigned trace_at = 3u + 2u * n_c, spikes_at = trace_at;
    if (stride) {
        p16(out + trace_at, points);
        trace_at += 2u;
        spikes_at = trace_at + 4u * n_c * points;
    }
    int64_t u[DW_MAX_CANDIDATES];
    int32_t t_u[DW_MAX_CANDIDATES], ref_end[DW_MAX_CANDIDATES], check[DW_MAX_CANDIDATES];
    uint32_t count[DW_MAX_CANDIDATES];
    for (unsigned k = 0; k < DW_MAX_CANDIDATES; k++) {
        u[k] = 0;
        t_u[k] = -1;
        ref_end[k] = -1;
        check[k] = -1;
        count[k] = 0;
    }
    /* the columns read per row, in ascending order (as SPIKE_BATCH reads them), their shift
     * register bytes, and per (row, column) the candidates whose synapse it is */
    uint8_t ucol_sr[DW_MAX_CANDIDATES], cand_at[DW_MAX_ROWS][DW_MAX_CANDIDATES];
    unsigned n_u = 0;
    for (unsigned c = 0; c < 32; c++) {
        if (!((ucols >> c) & 1u))
            continue;
        ucol_sr[n_u] = (uint8_t)((c & SR_WL_ADDR_MASK) | SR_WL_EN | SR_SUM_PATH);
        for (unsigned r = 0; r < DW_MAX_ROWS; r++) {
            unsigned m = 0;
            for (unsigned k = 0; k < n_c; k++)
                if (ri[k] == r && col[k] == c)
                    m |= 1u << k;
            cand_at[r][n_u] = (uint8_t)m;
        }
        n_u++;
    }
    int integ = (q->lif_flags & DW_LIF_INTEGRATE) != 0;
    unsigned n_in = 0, n_spk = 0;
    uint64_t s = key, t0 = hal_now64(), bin_ticks = (uint64_t)q->bin_us * TICKS_PER_US;
    sr_col = 0;
    sr_row = 0;
    int enabled = 0;
    /* the next step at which some lane has an event besides the input spikes */
    int32_t next_evt = -1;
    for (unsigned k = 0; k < n_c; k++)
        if (next_inh[k] >= 0 && (next_evt < 0 || next_inh[k] < next_evt))
            next_evt = next_inh[k];
    /* the window visits only the steps where something happens: an input spike (the next one
     * found by next_spike), a lane's event (next_evt) or a trace point (next_trace) */
    const uint32_t n_bins = q->n_bins, none = 0xFFFFFFFFu;
    uint32_t next_in = next_spike(&s, 0, n_bins, q->threshold);
    uint32_t next_trace = stride ? 0 : none;
    for (;;) {
        uint32_t t = next_in;
        if (next_evt >= 0 && (uint32_t)next_evt < t)
            t = (uint32_t)next_evt;
        if (next_trace < t)
            t = next_trace;
        if (t >= n_bins)
            break;
        int64_t drv[DW_MAX_CANDIDATES];
        int spike = t == next_in;
        if (spike) {
            n_in++;
            for (unsigned k = 0; k < n_c; k++)
                drv[k] = 0;
            if (n_rows && !enabled) {
                set_sr_col(0);
                set_sr_row(SR_ROWDAC_EN);
                enabled = 1;
            }
            for (unsigned r = 0; r < n_rows; r++) {
                if (paced)
                    hal_wait_long(t0 + t * bin_ticks);
                hal_watchdog_kick();
                driven_row = rows[r];
                set_row(driven_row, q->row_code);
                settle(DAC_SETTLE_TICKS);
                for (unsigned j = 0; j < n_u; j++) {
                    set_sr_col(ucol_sr[j]);
                    settle(SETTLE_TICKS);
                    uint16_t a = adc_read();
                    unsigned m = cand_at[r][j];
                    if (m) {
                        int64_t dv = drive_of(q, a);
                        for (unsigned k = 0; m; k++, m >>= 1)
                            if (m & 1u)
                                drv[k] = dv;
                    }
                }
                set_sr_col(0);
                set_row(driven_row, 0);
                ops_cnt.spikes_applied++;
                ops_cnt.column_reads += n_u;
            }
        }
        if (spike || (int32_t)t == next_evt) {
            next_evt = -1;
            for (unsigned k = 0; k < n_c; k++) {
                int inhibited = next_inh[k] == (int32_t)t;
                if (spike || inhibited || check[k] == (int32_t)t) {
                    int64_t cur = spike ? drv[k] : 0;
                    if (inhibited) {
                        cur -= q->inh;
                        next_inh[k] = left[k] ? next_inh[k] + 1 + (int32_t)varint(p, &ipos[k]) : -1;
                        if (left[k])
                            left[k]--;
                    }
                    int freed = (int32_t)t > ref_end[k];
                    if (freed || integ) {
                        int64_t v = decay(q, u[k], (uint32_t)((int32_t)t - t_u[k])) + cur;
                        int32_t hi = (int32_t)(v >> 32);         /* saturate at +-2^62 */
                        if (hi >= (1 << 30))
                            v = POT_LIMIT;
                        else if (hi < -(1 << 30))
                            v = -POT_LIMIT;
                        t_u[k] = (int32_t)t;
                        if (freed && v > q->thr) {
                            v = q->reset;
                            ref_end[k] = (int32_t)(t + q->ref_steps);
                            if (integ)
                                check[k] = ref_end[k] + 1;
                            else
                                t_u[k] = ref_end[k];
                            count[k]++;
                            if (flags & DW_FLAG_MOTOR_SPIKES)
                                p16(out + spikes_at + 2u * n_spk, t | (k << 14));
                            n_spk++;
                        }
                        u[k] = v;
                    }
                }
                int32_t e = next_inh[k];
                if (check[k] > (int32_t)t && (e < 0 || check[k] < e))
                    e = check[k];
                if (e > (int32_t)t && (next_evt < 0 || e < next_evt))
                    next_evt = e;
            }
        }
        if (spike)
            next_in = next_spike(&s, t + 1, n_bins, q->threshold);
        if (t == next_trace) {
            next_trace += stride;
            for (unsigned k = 0; k < n_c; k++) {
                int64_t x = decay(q, u[k], (uint32_t)((int32_t)t - t_u[k] > 0
                                                      ? (int32_t)t - t_u[k] : 0)) >> 16;
                if (x < -((int64_t)1 << 31))
                    x = -((int64_t)1 << 31);
                else if (x > ((int64_t)1 << 31) - 1)
                    x = ((int64_t)1 << 31) - 1;
                p32(out + trace_at, (uint32_t)(int32_t)x);
                trace_at += 4u;
            }
        }
    }
    if (enabled)
        set_sr_row(0);
    out[0] = (uint8_t)(n_c | (stride ? 0x08u : 0u) | ((flags & DW_FLAG_MOTOR_SPIKES) ? 0x10u : 0u));
    p16(out + 1, n_in);
    for (unsigned k = 0; k < n_c; k++)
        p16(out + 3u + 2u * k, count[k]);
    *len = (flags & DW_FLAG_MOTOR_SPIKES) ? spikes_at + 2u * n_spk : spikes_at;
    return 0;
}
