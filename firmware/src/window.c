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
    uint8_t conversions;       /* the read plan: 0 standard, 1..ADC_AVERAGE lean (flag READ_PLAN) */
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

/* the block at b; its read plan byte follows it when the request has flag READ_PLAN */
static void parse_params(const uint8_t *b, params_t *q, unsigned flags)
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
    q->conversions = (flags & DW_FLAG_READ_PLAN) ? b[76] : 0;
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
    if (flags & ~(unsigned)(DW_FLAG_PARAMS | DW_FLAG_MOTOR_SPIKES | DW_FLAG_TRACE | DW_FLAG_PACED |
                            DW_FLAG_READ_PLAN))
        return 1;
    if ((flags & DW_FLAG_READ_PLAN) && !(flags & DW_FLAG_PARAMS))
        return 1;                                    /* a read plan belongs to a block */
    if (flags & DW_FLAG_PARAMS) {
        if (pos + DW_PARAMS_SIZE > n || (p[pos + 8] & ~(unsigned)DW_LIF_INTEGRATE))
            return 1;
        pos += DW_PARAMS_SIZE;
        if (flags & DW_FLAG_READ_PLAN) {
            if (pos + 1 > n || p[pos] == 0)
                return 1;                            /* a plan of 0 conversions */
            pos += 1;
        }
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
    if (q->conversions > ADC_AVERAGE)
        return refuse(ERR_OUT_OF_RANGE, DW_PARAMS_SIZE, "conversions outside 1..ADC_AVERAGE");
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
    while (t < n) {
        uint32_t end = (t | 31u) + 1u;          /* 32 steps (~45 us), then the UART served */
        if (end > n)
            end = n;
        for (; t < end; t++) {
            s += GOLDEN;
            uint64_t z = s;
            z = (z ^ (z >> 30)) * MUL1;
            z = (z ^ (z >> 27)) * MUL2;
            z ^= z >> 31;
            if ((z >> 11) < threshold)
                goto found;
        }
        hal_uart_service();
    }
found:
    *state = s;
    return t;
}

/* ------------------------------------------------------------------ drivers (from idle) */
static uint8_t sr_col, sr_row;

static void write16(int dev, uint16_t w)
{
    uint8_t b[2] = {(uint8_t)(w >> 8), (uint8_t)w};
    hal_spi_write(dev, b, 2);
}

/* the shift registers, written when their value changes; 1 if it was written */
static int set_sr_col(uint8_t v)
{
    if (v == sr_col)
        return 0;
    hal_spi_write(DEV_SR_COL, &v, 1);
    sr_col = v;
    return 1;
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

/* ------------------------------------------------------------------ the motor neurons */
/* The window's lane state and reply being written; the events of every lane at a step. */
typedef struct {
    const params_t *q;
    const uint8_t *p;                 /* the request: interneuron gaps are decoded as they come */
    uint8_t *out;
    unsigned n_c, stride, motor_spikes, n_spk, trace_at, spikes_at;
    int integ;
    int64_t u[DW_MAX_CANDIDATES];
    int32_t t_u[DW_MAX_CANDIDATES], ref_end[DW_MAX_CANDIDATES], check[DW_MAX_CANDIDATES];
    int32_t next_inh[DW_MAX_CANDIDATES];
    unsigned ipos[DW_MAX_CANDIDATES], left[DW_MAX_CANDIDATES];
    uint32_t count[DW_MAX_CANDIDATES];
    int32_t next_evt;                 /* the next step with a lane event besides input spikes */
    uint32_t next_trace;              /* the next trace point (NONE: no trace) */
} lanes_t;

#define NONE 0xFFFFFFFFu

/* every lane's events at step t: the input spike (spike: drives drv[k]), its interneuron
 * spike, the end of an integrating refractory period; then next_evt (lif_fixed.integrate) */
static void lanes_at(lanes_t *w, uint32_t t, int spike, const int64_t *drv)
{
    const params_t *q = w->q;
    w->next_evt = -1;
    for (unsigned k = 0; k < w->n_c; k++) {
        int inhibited = w->next_inh[k] == (int32_t)t;
        if (spike || inhibited || w->check[k] == (int32_t)t) {
            int64_t cur = spike ? drv[k] : 0;
            if (inhibited) {
                cur -= q->inh;
                w->next_inh[k] = w->left[k] ? w->next_inh[k] + 1 + (int32_t)varint(w->p, &w->ipos[k])
                                            : -1;
                if (w->left[k])
                    w->left[k]--;
            }
            int freed = (int32_t)t > w->ref_end[k];
            if (freed || w->integ) {
                int64_t v = decay(q, w->u[k], (uint32_t)((int32_t)t - w->t_u[k])) + cur;
                int32_t hi = (int32_t)(v >> 32);         /* saturate at +-2^62 */
                if (hi >= (1 << 30))
                    v = POT_LIMIT;
                else if (hi < -(1 << 30))
                    v = -POT_LIMIT;
                w->t_u[k] = (int32_t)t;
                if (freed && v > q->thr) {
                    v = q->reset;
                    w->ref_end[k] = (int32_t)(t + q->ref_steps);
                    if (w->integ)
                        w->check[k] = w->ref_end[k] + 1;
                    else
                        w->t_u[k] = w->ref_end[k];
                    w->count[k]++;
                    if (w->motor_spikes)
                        p16(w->out + w->spikes_at + 2u * w->n_spk, t | (k << 14));
                    w->n_spk++;
                }
                w->u[k] = v;
            }
        }
        int32_t e = w->next_inh[k];
        if (w->check[k] > (int32_t)t && (e < 0 || w->check[k] < e))
            e = w->check[k];
        if (e > (int32_t)t && (w->next_evt < 0 || e < w->next_evt))
            w->next_evt = e;
    }
}

/* the potentials at trace point t (lif_fixed.integrate's trace) */
static void trace_at(lanes_t *w, uint32_t t)
{
    w->next_trace += w->stride;
    for (unsigned k = 0; k < w->n_c; k++) {
        int64_t x = decay(w->q, w->u[k], (uint32_t)((int32_t)t - w->t_u[k] > 0
                                                    ? (int32_t)t - w->t_u[k] : 0)) >> 16;
        if (x < -((int64_t)1 << 31))
            x = -((int64_t)1 << 31);
        else if (x > ((int64_t)1 << 31) - 1)
            x = ((int64_t)1 << 31) - 1;
        p32(w->out + w->trace_at, (uint32_t)(int32_t)x);
        w->trace_at += 4u;
    }
}

/* the events of the steps before `end` that are no input spike (interneuron spikes,
 * refractory ends, trace points), in step order */
static void lanes_until(lanes_t *w, uint32_t end)
{
    for (;;) {
        uint32_t t = w->next_evt >= 0 ? (uint32_t)w->next_evt : NONE;
        if (w->next_trace < t)
            t = w->next_trace;
        if (t >= end)
            return;
        hal_uart_service();                     /* a long run of events: the UART served */
        if ((int32_t)t == w->next_evt)
            lanes_at(w, t, 0, 0);
        if (t == w->next_trace)
            trace_at(w, t);
    }
}

/* the input spike at step t (drives drv) after every earlier event */
static void lanes_spike(lanes_t *w, uint32_t t, const int64_t *drv)
{
    lanes_until(w, t);
    lanes_at(w, t, 1, drv);
    if (t == w->next_trace)
        trace_at(w, t);
}

/* ------------------------------------------------------------------ standard reads */
/* Per spike each row alone at the row code, the union of the candidates' columns read in
 * ascending order with ops_adc_read: the SPI sequence of a SPIKE_BATCH of one group per row
 * (firmware_emu/decision_window.py). */
static unsigned run_standard(lanes_t *w, const uint8_t *rows, unsigned n_rows,
                             const uint8_t *col, const uint8_t *ri, uint64_t key, int paced)
{
    const params_t *q = w->q;
    const unsigned n_c = w->n_c;
    uint32_t ucols = 0;
    for (unsigned k = 0; k < n_c; k++)
        ucols |= 1u << col[k];
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
    unsigned n_in = 0;
    uint64_t s = key, t0 = hal_now64(), bin_ticks = (uint64_t)q->bin_us * TICKS_PER_US;
    int enabled = 0;
    const uint32_t n_bins = q->n_bins;
    uint32_t t = next_spike(&s, 0, n_bins, q->threshold);
    for (;;) {
        lanes_until(w, t);                          /* the events before the spike */
        if (t >= n_bins)
            break;
        int64_t drv[DW_MAX_CANDIDATES];
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
            set_row(rows[r], q->row_code);
            settle(DAC_SETTLE_TICKS);
            for (unsigned j = 0; j < n_u; j++) {
                set_sr_col(ucol_sr[j]);
                settle(SETTLE_TICKS);
                uint16_t a = ops_adc_read();
                unsigned m = cand_at[r][j];
                if (m) {
                    int64_t dv = drive_of(q, a);
                    for (unsigned k = 0; m; k++, m >>= 1)
                        if (m & 1u)
                            drv[k] = dv;
                }
            }
            set_sr_col(0);
            set_row(rows[r], 0);
            ops_cnt.spikes_applied++;
            ops_cnt.column_reads += n_u;
        }
        lanes_at(w, t, 1, drv);
        if (t == w->next_trace)
            trace_at(w, t);
        t = next_spike(&s, t + 1, n_bins, q->threshold);
    }
    if (enabled)
        set_sr_row(0);
    return n_in;
}

/* ------------------------------------------------------------------ the lean read plan */
/* One read of a spike: its row, the column register byte, the lanes whose synapse it is. */
typedef struct {
    uint8_t row, sr, lanes;
} read_t;

/* Draw up to DW_DRAW_CHUNK steps of the search for the next input spike from *t; 1 when the
 * search has ended (*next = the spike's step, or n_bins when none is left). */
static int draw_chunk(uint64_t *s, uint32_t *t, uint32_t *next, const params_t *q)
{
    uint32_t end = *t + DW_DRAW_CHUNK;
    if (end >= q->n_bins)
        end = q->n_bins;
    uint32_t found = next_spike(s, *t, end, q->threshold);
    if (found < end || end == q->n_bins) {
        *next = found;
        return 1;
    }
    *t = end;
    return 0;
}

/* the ADC code of one frame's bytes (TLC3541: the previous conversion) */
static uint32_t adc_code(const uint8_t *rx)
{
    return ((uint32_t)rx[0] << 6) | ((uint32_t)rx[1] >> 2);
}

/* Reads of the lean plan (docs/protocol.md "Read plan"): per input spike the reads r_list
 * (each row's own candidates' columns; every other spike in reverse order, so a spike starts
 * where the last one ended), each `conversions` conversions of the TLC3541's
 * pipeline - a frame returns the previous conversion, so a read's last conversion comes with
 * the next read's first frame (the window's last with one frame at its end) and no dummy is
 * taken; a read's column settles from its select to its first sample while the ADC converts
 * the previous read; a row or column that does not change is not written again (nor waited
 * for). The arithmetic runs in the waits: before a read's first frame the previous spike's
 * motor neurons (once its reads are converted), then chunks of the search for the next input
 * spike (DW_DRAW_CHUNK steps) while the wait leaves room for one (DW_DRAW_FIT_TICKS; the rest
 * of the search after the spike's last read); after the first frame the read it completed is
 * converted. The Python MCU (firmware_emu/window_reads.py) times the same sequence. */
/* (out of line: the emulator keys the window's noise around it, docs/emulator.md) */
__attribute__((noinline)) static unsigned run_lean(lanes_t *w, const read_t *rd,
                                                   unsigned n_reads, unsigned n_read_rows,
                                                   uint64_t key, int paced)
{
    const params_t *q = w->q;
    const uint32_t n_bins = q->n_bins, conv = q->conversions;
    uint64_t s = key;
    unsigned n_in = 0;
    uint32_t t_next = next_spike(&s, 0, n_bins, q->threshold);
    if (!n_reads || t_next >= n_bins) { /* no candidates or no spike: nothing is read */
        static const int64_t none[DW_MAX_CANDIDATES];
        for (; t_next < n_bins; t_next = next_spike(&s, t_next + 1, n_bins, q->threshold)) {
            n_in++;
            lanes_spike(w, t_next, none);
        }
        lanes_until(w, n_bins);
        return n_in;
    }
    int64_t drv[2][DW_MAX_CANDIDATES];
    uint64_t t0 = hal_now64(), bin_ticks = (uint64_t)q->bin_us * TICKS_PER_US;
    uint32_t deadline = hal_now(), adc_next = deadline;
    int driven = -1, prev = -1;         /* the row driven; the read the next frame completes */
    unsigned prev_par = 0, lif_par = 0, prev_last = 0;
    uint32_t prev_t = 0, lif_t = 0, acc_prev = 0;
    int sat_prev = 0, lif_pending = 0;
    uint8_t rx[2];
    set_sr_row(SR_ROWDAC_EN);
    for (unsigned k = 0; t_next < n_bins; k++) {
        const uint32_t t_cur = t_next;
        const unsigned par = k & 1u;
        uint32_t draw_t = t_cur + 1;
        int found = 0;
        n_in++;
        if (paced)
            hal_wait_long(t0 + t_cur * bin_ticks);
        hal_watchdog_kick();
        for (unsigned i = 0; i < n_reads; i++) {
            /* every other spike reads in reverse: it starts where the last one ended, so that
             * read needs no select and no settling, and a two-row neuron one row change */
            const unsigned j = par ? n_reads - 1u - i : i;
            int changed = 0;
            hal_uart_service();         /* a read is shorter than a UART byte */
            if ((int)rd[j].row != driven) {
                if (driven >= 0)
                    set_row((unsigned)driven, 0);
                set_row(rd[j].row, q->row_code);
                driven = rd[j].row;
                changed = 1;
            }
            changed |= set_sr_col(rd[j].sr);
            if (changed)
                deadline = hal_now() + SETTLE_TICKS;
            /* before the first frame: the previous spike's motor neurons, the next spike */
            if (lif_pending) {
                lanes_spike(w, lif_t, drv[lif_par]);
                lif_pending = 0;
            }
            /* then the search for the next spike while the wait leaves room for a chunk */
            const uint32_t target = (int32_t)(deadline - adc_next) > 0 ? deadline : adc_next;
            while (!found && (int32_t)(target - hal_now()) >= (int32_t)DW_DRAW_FIT_TICKS)
                found = draw_chunk(&s, &draw_t, &t_next, q);
            uint32_t start = hal_adc_frame(rx, target);
            adc_next = start + ADC_CYCLE_TICKS;
            if (prev >= 0) {            /* this frame completed the previous read: convert it */
                uint32_t code = adc_code(rx);
                acc_prev += code;
                sat_prev |= code >= BOARD_ADC_FULL;
                if (sat_prev)
                    ops_cnt.saturated_reads++;
                int64_t dv = drive_of(q, (acc_prev + conv / 2u) / conv);
                for (unsigned m = rd[prev].lanes, l = 0; m; l++, m >>= 1)
                    if (m & 1u)
                        drv[prev_par][l] = dv;
                if (prev_last) {
                    lif_pending = 1;
                    lif_par = prev_par;
                    lif_t = prev_t;
                }
            }
            uint32_t acc = 0;
            int sat = 0;
            for (unsigned i = 1; i < conv; i++) {
                start = hal_adc_frame(rx, adc_next);
                adc_next = start + ADC_CYCLE_TICKS;
                uint32_t code = adc_code(rx);
                acc += code;
                sat |= code >= BOARD_ADC_FULL;
            }
            prev = (int)j;
            prev_last = i == n_reads - 1u;
            prev_par = par;
            prev_t = t_cur;
            acc_prev = acc;
            sat_prev = sat;
        }
        ops_cnt.spikes_applied += n_read_rows;
        ops_cnt.column_reads += n_reads;
        if (!found)
            t_next = next_spike(&s, draw_t, n_bins, q->threshold);
        if (paced)
            set_sr_col(0);              /* the word line off while waiting for the next bin */
    }
    set_sr_col(0);
    if (driven >= 0)
        set_row((unsigned)driven, 0);
    set_sr_row(0);
    if (prev >= 0) {                    /* one frame more: the last read's last conversion */
        hal_adc_frame(rx, adc_next);
        uint32_t code = adc_code(rx);
        acc_prev += code;
        if (sat_prev || code >= BOARD_ADC_FULL)
            ops_cnt.saturated_reads++;
        int64_t dv = drive_of(q, (acc_prev + conv / 2u) / conv);
        for (unsigned m = rd[prev].lanes, l = 0; m; l++, m >>= 1)
            if (m & 1u)
                drv[prev_par][l] = dv;
        if (lif_pending)
            lanes_spike(w, lif_t, drv[lif_par]);
        lanes_spike(w, prev_t, drv[prev_par]);
    }
    lanes_until(w, n_bins);
    return n_in;
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
        parse_params(p + pos, &incoming, flags);
        hal_uart_service();         /* (the checks below take longer than a UART byte) */
        pos += DW_PARAMS_SIZE + ((flags & DW_FLAG_READ_PLAN) ? 1u : 0u);
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
    lanes_t w;
    uint8_t col[DW_MAX_CANDIDATES], ri[DW_MAX_CANDIDATES];
    for (unsigned k = 0; k < n_c; k++) {
        uint8_t cell = p[pos++];
        col[k] = cell & 0x1Fu;
        ri[k] = (cell >> 5) & 0x03u;
        w.left[k] = 0;
        w.next_inh[k] = -1;
        if ((e = (unsigned)ops_check_cell(0, col[k])))
            return (int)e;
        if (ri[k] >= n_rows)
            return refuse(ERR_OUT_OF_RANGE, ri[k], "candidate row index beyond the rows");
        if (cell & 0x80u) {
            unsigned m = p[pos++];
            w.ipos[k] = pos;
            w.left[k] = m;
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
    hal_uart_service();
    if (q == &incoming) {
        parse_params(p + 1, &prm, flags);          /* (a struct copy would call memcpy) */
        hal_uart_service();
        have_prm = 1;
        q = &prm;
    }
    w.q = q;
    w.p = p;
    w.out = out;
    w.n_c = n_c;
    w.stride = stride;
    w.motor_spikes = (flags & DW_FLAG_MOTOR_SPIKES) != 0;
    w.integ = (q->lif_flags & DW_LIF_INTEGRATE) != 0;
    w.n_spk = 0;
    for (unsigned k = 0; k < n_c; k++)               /* first interneuron spike per lane */
        if (w.left[k]) {
            w.next_inh[k] = (int32_t)varint(p, &w.ipos[k]);
            w.left[k]--;
        }
    w.trace_at = w.spikes_at = 3u + 2u * n_c;
    if (stride) {
        p16(out + w.trace_at, points);
        w.trace_at += 2u;
        w.spikes_at = w.trace_at + 4u * n_c * points;
    }
    for (unsigned k = 0; k < DW_MAX_CANDIDATES; k++) {
        w.u[k] = 0;
        w.t_u[k] = -1;
        w.ref_end[k] = -1;
        w.check[k] = -1;
        w.count[k] = 0;
    }
    w.next_evt = -1;
    for (unsigned k = 0; k < n_c; k++)
        if (w.next_inh[k] >= 0 && (w.next_evt < 0 || w.next_inh[k] < w.next_evt))
            w.next_evt = w.next_inh[k];
    w.next_trace = stride ? 0 : NONE;
    sr_col = 0;
    sr_row = 0;
    unsigned n_in;
    if (q->conversions) {
        /* the reads of one spike: rows in request order, each row's candidate columns
         * ascending, a cell two candidates share read once */
        read_t rd[DW_MAX_CANDIDATES];
        unsigned n_reads = 0, n_read_rows = 0;
        for (unsigned r = 0; r < n_rows; r++) {
            unsigned before = n_reads;
            uint32_t cols = 0;
            for (unsigned k = 0; k < n_c; k++)
                if (ri[k] == r)
                    cols |= 1u << col[k];
            for (unsigned c = 0; cols; c++, cols >>= 1) {
                if (!(cols & 1u))
                    continue;
                unsigned m = 0;
                for (unsigned k = 0; k < n_c; k++)
                    if (ri[k] == r && col[k] == c)
                        m |= 1u << k;
                rd[n_reads].row = rows[r];
                rd[n_reads].sr = (uint8_t)((c & SR_WL_ADDR_MASK) | SR_WL_EN | SR_SUM_PATH);
                rd[n_reads].lanes = (uint8_t)m;
                n_reads++;
            }
            n_read_rows += n_reads > before;
        }
        hal_uart_service();
        n_in = run_lean(&w, rd, n_reads, n_read_rows, key, paced);
    } else {
        n_in = run_standard(&w, rows, n_rows, col, ri, key, paced);
    }
    out[0] = (uint8_t)(n_c | (stride ? 0x08u : 0u) | (w.motor_spikes ? 0x10u : 0u));
    p16(out + 1, n_in);
    for (unsigned k = 0; k < n_c; k++)
        p16(out + 3u + 2u * k, w.count[k]);
    *len = w.motor_spikes ? w.spikes_at + 2u * w.n_spk : w.spikes_at;
    return 0;
}
