/* Framed protocol v1, board side. Mirrors snan_hil.protocol.device.DeviceEndpoint (order of
 * checks, counters, cache) and firmware_emu.dispatch (messages). */
#include "proto.h"
#include "hal.h"
#include "ops.h"
#include "snan_constants.h"
#include "window.h"

#define RAW_MAX (PROTO_HEADER_SIZE + PROTO_MAX_PAYLOAD + PROTO_CRC_SIZE)
/* The longest INFO this firmware sends: its version text and its board id with the longest
 * chip serial the EEPROM record may hold ("MC-4D430001/" + 27 characters: 175 raw bytes). */
#define INFO_RAW_MAX (PROTO_HEADER_SIZE + SIZE_INFO_FIXED + sizeof INFO_FIRMWARE_VERSION - 1u + \
                      sizeof INFO_BOARD_ID - 1u + 1u + CHIP_ID_MAX_SERIAL + PROTO_CRC_SIZE)
/* The longest ERROR (a 64-byte text) and the other small replies (STATUS: 78 raw bytes). */
#define ERROR_RAW_MAX (PROTO_HEADER_SIZE + 7u + PROTO_MAX_TEXT + PROTO_CRC_SIZE)
#define MAX2(a, b) ((a) > (b) ? (a) : (b))
/* Every reply but SPIKE_BATCH's is built in small_buf and kept in a cache slot of this size.
 * (It was 152, sized for an INFO without the chip serial: a 12-character serial made INFO 160
 * raw bytes, which overran small_buf into the register cache (sr_col, sr_row, wdac_code) and
 * the next cache slot - issue 27, item 4.) */
#define SMALL_MAX MAX2(INFO_RAW_MAX, ERROR_RAW_MAX)
_Static_assert(SMALL_MAX >= PROTO_HEADER_SIZE + SIZE_STATUS_REPLY + PROTO_CRC_SIZE,
               "small_buf holds a STATUS reply");
_Static_assert(SMALL_MAX >= PROTO_HEADER_SIZE + PROTO_PIPELINE_REPLY_MAX + PROTO_CRC_SIZE,
               "a cache slot holds every reply of up to PIPELINE_REPLY_MAX payload bytes");

/* receive buffer: COBS bytes of the frame being received, decoded in place */
static uint8_t rx_buf[PROTO_MAX_ENCODED];
static uint16_t rx_len;
static uint8_t rx_skipping;

/* replies: small ones (and every ERROR) are built in small_buf, large ones in big_buf */
static uint8_t big_buf[RAW_MAX];
static uint8_t small_buf[SMALL_MAX];

typedef struct {
    uint8_t used, in_big, type;
    uint16_t seq, len_raw;
    uint16_t plen;
    uint32_t nonce, hash;
    uint32_t order;                    /* insertion order (least recent evicted first) */
    uint8_t raw[SMALL_MAX];
} cache_slot_t;
static cache_slot_t cache[PROTO_CACHE_SIZE];
static uint32_t cache_clock;
static uint32_t big_owner_order;       /* order stamp of the slot whose reply is in big_buf */

static uint32_t boot_nonce;
static uint32_t link[10];              /* STATUS link counters, in StatusReply order */
static uint64_t t_boot;

static const uint16_t crc_table[256] = {
#define C1(c) (((c) & 0x8000u) ? (uint16_t)(((c) << 1) ^ 0x1021u) : (uint16_t)((c) << 1))
#define C8(c) C1(C1(C1(C1(C1(C1(C1(C1((uint16_t)((c) << 8)))))))))
#define R4(i) C8(i), C8(i + 1), C8(i + 2), C8(i + 3)
#define R16(i) R4(i), R4(i + 4), R4(i + 8), R4(i + 12)
#define R64(i) R16(i), R16(i + 16), R16(i + 32), R16(i + 48)
    R64(0), R64(64), R64(128), R64(192)
};

/* (The loops over a frame serve the UART every 64 bytes, ~0.03 ms: a frame takes longer than
 * a UART byte (0.087 ms), and the host may be sending the next request meanwhile.) */
uint16_t crc16_ccitt_false(const uint8_t *p, unsigned n)
{
    uint16_t crc = 0xFFFFu;
    while (n--) {
        crc = (uint16_t)((crc << 8) ^ crc_table[((crc >> 8) ^ *p++) & 0xFFu]);
        if (!(n & 0x3Fu))
            hal_uart_service();
    }
    return crc;
}

static uint32_t fnv1a(const uint8_t *p, unsigned n)
{
    uint32_t h = 2166136261u;
    while (n--) {
        h ^= *p++;
        h *= 16777619u;
        if (!(n & 0x3Fu))
            hal_uart_service();
    }
    return h;
}

static void put16(uint8_t *p, uint32_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static void put64(uint8_t *p, uint64_t v) { put32(p, (uint32_t)v); put32(p + 4, (uint32_t)(v >> 32)); }
static uint32_t get16(const uint8_t *p) { return (uint32_t)(p[0] | (p[1] << 8)); }
static uint32_t get32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

enum { L_FRAMES_IN, L_FRAMES_OUT, L_CRC, L_FRAMING, L_MALFORMED, L_UNKNOWN, L_DUPLICATES,
       L_REFUSALS, L_NONCE, L_EXECUTED };

static uint32_t new_nonce(uint32_t old)
{
    uint32_t n;
    do {
        n = hal_entropy();
    } while (n == 0 || n == old);
    return n;
}

/* INFO's board id: INFO_BOARD_ID, then "/<chip serial>" when the EEPROM names the chip */
static char board_id[PROTO_MAX_TEXT + 1];

static void make_board_id(void)
{
    unsigned n = 0;
    for (const char *s = INFO_BOARD_ID; *s && n < PROTO_MAX_TEXT; s++)
        board_id[n++] = *s;
    if (n + 2 <= PROTO_MAX_TEXT) {
        unsigned m = hal_chip_serial(board_id + n + 1, PROTO_MAX_TEXT - n - 1);
        if (m) {
            board_id[n] = '/';
            n += 1 + m;
        }
    }
    board_id[n] = 0;
}

void proto_boot(void)
{
    make_board_id();
    for (unsigned i = 0; i < 10; i++)
        link[i] = 0;
    for (unsigned i = 0; i < PROTO_CACHE_SIZE; i++)
        cache[i].used = 0;
    rx_len = 0;
    rx_skipping = 0;
    boot_nonce = new_nonce(boot_nonce);
    t_boot = hal_now64();
    window_clear();
}

/* ------------------------------------------------------------------ sending */
/* COBS-encode raw[0..n) onto the UART followed by the 0x00 delimiter (canonical form: a final
 * run of exactly 254 non-zero bytes ends with its 0xFF group). */
static void send_cobs(const uint8_t *raw, unsigned n)
{
    unsigned i = 0;
    for (;;) {
        unsigned j = i;
        while (j < n && raw[j] != 0 && j - i < 254u)
            j++;
        unsigned len = j - i;
        if (len == 254u) {
            hal_uart_putc(0xFF);
            for (unsigned k = i; k < j; k++)
                hal_uart_putc(raw[k]);
            i = j;
            if (i == n)
                break;            /* canonical: no trailing empty group */
            continue;             /* the run goes on (or a zero follows: next group) */
        }
        hal_uart_putc((uint8_t)(len + 1u));
        for (unsigned k = i; k < j; k++)
            hal_uart_putc(raw[k]);
        if (j >= n)
            break;
        i = j + 1;                /* skip the zero that ended the group */
        if (i == n) {             /* a trailing zero: one empty group */
            hal_uart_putc(1);
            break;
        }
    }
    hal_uart_putc(0);
    link[L_FRAMES_OUT]++;
}

static unsigned frame_header(uint8_t *raw, uint8_t flags, uint8_t type, uint16_t seq,
                             unsigned plen, uint32_t nonce)
{
    raw[0] = PROTO_VERSION;
    raw[1] = flags;
    raw[2] = type;
    raw[3] = 0;
    put16(raw + 4, seq);
    put16(raw + 6, plen);
    put32(raw + 8, nonce);
    return PROTO_HEADER_SIZE + plen;
}

static unsigned frame_finish(uint8_t *raw, unsigned plen)
{
    unsigned n = PROTO_HEADER_SIZE + plen;
    put16(raw + n, crc16_ccitt_false(raw, n));
    return n + PROTO_CRC_SIZE;
}

/* An ERROR reply, built in small_buf; returns its raw length. Counts a refusal. */
static unsigned build_error(uint16_t seq, uint8_t code, uint8_t req_type, uint32_t detail,
                            const char *msg)
{
    link[L_REFUSALS]++;
    uint8_t *p = small_buf + PROTO_HEADER_SIZE;
    unsigned m = 0;
    while (msg[m] && m < PROTO_MAX_TEXT)
        m++;
    p[0] = code;
    p[1] = req_type;
    put32(p + 2, detail);
    p[6] = (uint8_t)m;
    for (unsigned k = 0; k < m; k++)
        p[7 + k] = (uint8_t)msg[k];
    frame_header(small_buf, 0, MSG_ERROR_REPLY, seq, 7u + m, boot_nonce);
    return frame_finish(small_buf, 7u + m);
}

static void send_error(uint16_t seq, uint8_t code, uint8_t req_type, uint32_t detail,
                       const char *msg)
{
    send_cobs(small_buf, build_error(seq, code, req_type, detail, msg));
}

/* NAK of a damaged frame (docs/protocol.md): ERROR BAD_FRAME, seq 0, request type 0, detail =
 * the reason; nothing of the damaged header is trusted. */
static void send_nak(unsigned reason)
{
    if (reason == NAK_CRC)
        link[L_CRC]++;
    else
        link[L_FRAMING]++;
    send_error(0, ERR_BAD_FRAME, 0, reason,
               reason == NAK_CRC ? "damaged frame: CRC mismatch" :
               reason == NAK_COBS ? "damaged frame: bad COBS encoding" :
                                    "damaged frame: wrong length");
}

/* ------------------------------------------------------------------ the reply cache */
static cache_slot_t *cache_find(uint16_t seq)
{
    for (unsigned i = 0; i < PROTO_CACHE_SIZE; i++)
        if (cache[i].used && cache[i].seq == seq)
            return &cache[i];
    return 0;
}

static void cache_store(uint16_t seq, uint8_t type, uint32_t nonce, uint32_t hash,
                        unsigned plen, const uint8_t *raw, unsigned n, int in_big)
{
    cache_slot_t *s = cache_find(seq);
    if (!s) {
        unsigned used = 0;
        for (unsigned i = 0; i < PROTO_CACHE_SIZE; i++)
            used += cache[i].used;
        if (used < PROTO_CACHE_SIZE) {
            for (unsigned i = 0; i < PROTO_CACHE_SIZE; i++)
                if (!cache[i].used) { s = &cache[i]; break; }
        } else {
            s = &cache[0];
            for (unsigned i = 1; i < PROTO_CACHE_SIZE; i++)
                if (cache[i].order < s->order)
                    s = &cache[i];
        }
    }
    s->used = 1;
    s->seq = seq;
    s->type = type;
    s->nonce = nonce;
    s->hash = hash;
    s->plen = (uint16_t)plen;
    s->order = ++cache_clock;
    s->len_raw = (uint16_t)n;
    s->in_big = (uint8_t)in_big;
    if (in_big)
        big_owner_order = s->order;
    else
        for (unsigned k = 0; k < n; k++)
            s->raw[k] = raw[k];
}

static void cache_clear(void)
{
    for (unsigned i = 0; i < PROTO_CACHE_SIZE; i++)
        cache[i].used = 0;
}

/* ------------------------------------------------------------------ requests */
/* Payload validation (the Python decoders): 0 = well formed. */
static int malformed(uint8_t type, const uint8_t *p, unsigned n)
{
    switch (type) {
    case MSG_HELLO: return n != SIZE_HELLO;
    case MSG_READ_CELL: return n != SIZE_READ_CELL;
    case MSG_READ_COLUMN: return n < 2 || n != 2u + 2u * p[1];
    case MSG_WRITE_PULSE: return n != SIZE_WRITE_PULSE || p[2] > 1;
    case MSG_PROGRAM_CELL: return n != SIZE_PROGRAM_CELL || p[20] > 1;   /* bool: 0 or 1 */
    case MSG_STATUS: return n != SIZE_STATUS;
    case MSG_CLOCK: return n != SIZE_CLOCK;
    case MSG_RESET: return n != SIZE_RESET;
    case MSG_DECISION_WINDOW: return window_malformed(p, n);
    case MSG_SPIKE_BATCH: {
        if (n < 14)
            return 1;
        unsigned n_bins = get16(p + 4), flags = p[12], ng = p[13];
        if (flags & ~1u)
            return 1;
        unsigned nbytes = (n_bins + 7u) / 8u, pos = 14;
        for (unsigned k = 0; k < ng; k++) {
            if (pos + 1u > n)
                return 1;
            unsigned nr = p[pos];
            pos += 1u + 3u * nr;
            if (pos > n || pos + nbytes > n)
                return 1;
            if ((n_bins % 8u) && (p[pos + nbytes - 1u] >> (n_bins % 8u)))
                return 1;
            pos += nbytes;
        }
        return pos != n;
    }
    default: return 1;
    }
}

static unsigned spike_count(const uint8_t *p)
{
    unsigned n_bins = get16(p + 4), ng = p[13], nbytes = (n_bins + 7u) / 8u, pos = 14;
    unsigned count = 0;
    for (unsigned k = 0; k < ng; k++) {
        pos += 1u + 3u * p[pos];
        for (unsigned b = 0; b < nbytes; b++) {
            uint8_t v = p[pos + b];
            while (v) { count += v & 1u; v >>= 1; }
        }
        pos += nbytes;
    }
    return count;
}

static unsigned popcount32(uint32_t v)
{
    unsigned c = 0;
    while (v) { c += v & 1u; v >>= 1; }
    return c;
}

static unsigned put_text(uint8_t *p, const char *s)
{
    unsigned m = 0;
    while (s[m])
        m++;
    p[0] = (uint8_t)m;
    for (unsigned k = 0; k < m; k++)
        p[1 + k] = (uint8_t)s[k];
    return 1u + m;
}

static unsigned info_payload(uint8_t *p)
{
    unsigned o = 0;
    p[o++] = PROTO_VERSION;
    o += put_text(p + o, INFO_FIRMWARE_VERSION);
    o += put_text(p + o, board_id);
    p[o++] = BOARD_ROWS;
    p[o++] = BOARD_COLS;
    p[o++] = BOARD_DAC_BITS;
    put64(p + o, INFO_DAC_VREF_BITS); o += 8;
    p[o++] = BOARD_WDAC_BITS;
    put64(p + o, INFO_WDAC_VREF_BITS); o += 8;
    p[o++] = BOARD_ADC_BITS;
    put64(p + o, INFO_ADC_VREF_BITS); o += 8;
    p[o++] = ADC_AVERAGE;
    /* the float64 constants after the averaging byte, in wire order (docs/protocol.md) */
    static const uint64_t analog_bits[] = {
        INFO_R_LOAD_BITS, INFO_R_SWITCH_BITS, INFO_GAIN_BITS, INFO_SUM_GAIN_BITS,
        INFO_V_READ_BITS, INFO_MAX_READ_V_BITS, INFO_MAX_WRITE_V_BITS, INFO_COMPLIANCE_BITS};
    for (unsigned k = 0; k < sizeof analog_bits / sizeof analog_bits[0]; k++, o += 8)
        put64(p + o, analog_bits[k]);
    put16(p + o, PROTO_MAX_PAYLOAD); o += 2;
    put32(p + o, CAP_ALL); o += 4;
    put32(p + o, boot_nonce); o += 4;
    put16(p + o, BOARD_READ_CODE); o += 2;
    return o;
}

/* Execute a decoded request. Returns the reply payload length (>= 0) written at out with
 * *rtype set, or -1 if refused (ops_refusal / *err set). */
static int execute(uint8_t type, const uint8_t *p, unsigned n, uint8_t *out, uint8_t *rtype,
                   uint8_t *err, uint32_t *detail, const char **msg)
{
    int e = 0;
    uint16_t adc = 0;
    (void)n;
    *rtype = (uint8_t)(type | 0x80u);
    switch (type) {
    case MSG_HELLO:
        if (p[0] != PROTO_VERSION) {      /* detail: the version this board speaks */
            *err = ERR_BAD_VERSION; *detail = PROTO_VERSION; *msg = "protocol version not supported";
            return -1;
        }
        return (int)info_payload(out);
    case MSG_READ_CELL:
        e = ops_read_cell(p[0], p[1], get16(p + 2), &adc);
        break;
    case MSG_READ_COLUMN:
        e = ops_read_column(p[0], p[1], p + 2, &adc);
        break;
    case MSG_WRITE_PULSE:
        e = ops_write_pulse(p[0], p[1], p[2], get16(p + 3), get32(p + 5), get16(p + 9), &adc);
        break;
    case MSG_PROGRAM_CELL:
        if ((e = ops_program_cell(p, out)) == 0)
            return SIZE_PROGRAM_CELL_REPLY;
        break;
    case MSG_SPIKE_BATCH: {
        uint32_t mask = get32(p + 8);
        unsigned ns = spike_count(p), nc = popcount32(mask);
        if (ns > 0xFFFFu) {
            *err = ERR_OUT_OF_RANGE; *detail = ns; *msg = "more than 65535 spikes";
            return -1;
        }
        if ((e = ops_spike_check(p + 14, p[13], get16(p + 4), get16(p + 6), p[12] & 1u, mask)))
            break;
        put32(out, get32(p));
        put16(out + 4, ns);
        out[6] = (uint8_t)nc;
        ops_spike_batch(p + 14, p[13], get16(p + 4), get16(p + 6), mask, p[12] & 1u, out + 7);
        return (int)(7u + 2u * ns * nc);
    }
    case MSG_STATUS: {
        for (unsigned i = 0; i < 10; i++)
            put32(out + 4 * i, link[i]);
        put32(out + 4 * ST_CELL_READS, ops_cnt.cell_reads);
        put32(out + 4 * ST_COLUMN_READS, ops_cnt.column_reads);
        put32(out + 4 * ST_PULSES_APPLIED, ops_cnt.pulses_applied);
        put32(out + 4 * ST_SPIKES_APPLIED, ops_cnt.spikes_applied);
        put32(out + 4 * ST_BUSY, ops_cnt.busy);
        put32(out + 4 * ST_SATURATED_READS, ops_cnt.saturated_reads);
        return SIZE_STATUS_REPLY;
    }
    case MSG_CLOCK:
        /* time since boot/RESET in us; the firmware cannot measure the array energy: 0 */
        put64(out, ops_udiv64(hal_now64() - t_boot, TICKS_PER_US));
        put64(out + 8, 0);
        return SIZE_CLOCK_REPLY;
    case MSG_RESET: {
        uint32_t old = boot_nonce;
        ops_boot();
        window_clear();
        boot_nonce = new_nonce(old);
        t_boot = hal_now64();
        put32(out, old);
        put32(out + 4, boot_nonce);
        return SIZE_RESET_REPLY;
    }
    case MSG_DECISION_WINDOW: {
        unsigned len = 0;
        if ((e = window_run(p, n, out, &len)))
            break;
        return (int)len;
    }
    default:
        *err = ERR_UNSUPPORTED; *detail = 0; *msg = "not implemented";
        return -1;
    }
    if (e) {
        *err = ops_refusal.code; *detail = ops_refusal.detail; *msg = ops_refusal.msg;
        return -1;
    }
    put16(out, adc);
    return 2;
}

static int is_request(uint8_t type)
{
    return (type >= MSG_HELLO && type <= MSG_RESET) || type == MSG_DECISION_WINDOW;
}

/* One checked frame (raw, CRC verified). */
static void handle_frame(uint8_t *raw, unsigned plen)
{
    uint8_t version = raw[0], type = raw[2];
    uint16_t seq = (uint16_t)get16(raw + 4);
    uint32_t nonce = get32(raw + 8);
    const uint8_t *p = raw + PROTO_HEADER_SIZE;
    link[L_FRAMES_IN]++;
    if (version != PROTO_VERSION) {
        send_error(seq, ERR_BAD_VERSION, type, PROTO_VERSION, "protocol version not supported");
        return;
    }
    uint32_t hash = fnv1a(p, plen);
    cache_slot_t *s = cache_find(seq);
    if (s && s->type == type && s->nonce == nonce && s->plen == plen && s->hash == hash &&
        (!s->in_big || s->order == big_owner_order)) {
        link[L_DUPLICATES]++;
        uint8_t *r = s->in_big ? big_buf : s->raw;
        r[1] |= PROTO_FLAG_FROM_CACHE;
        unsigned body = s->len_raw - PROTO_CRC_SIZE;
        put16(r + body, crc16_ccitt_false(r, body));
        send_cobs(r, s->len_raw);
        r[1] &= (uint8_t)~PROTO_FLAG_FROM_CACHE;
        put16(r + body, crc16_ccitt_false(r, body));
        return;
    }
    if (!is_request(type)) {
        link[L_UNKNOWN]++;
        send_error(seq, ERR_UNKNOWN_TYPE, type, type, "unknown request type");
        return;
    }
    if (nonce != 0 && nonce != boot_nonce && type != MSG_HELLO) {
        link[L_NONCE]++;
        send_error(seq, ERR_NONCE_MISMATCH, type, nonce, "request from before the last reset");
        return;
    }
    if (malformed(type, p, plen)) {
        link[L_MALFORMED]++;
        send_error(seq, ERR_MALFORMED, type, plen, "payload does not decode");
        return;
    }
    if (type == MSG_SPIKE_BATCH) {
        uint32_t size = 7u + 2u * spike_count(p) * popcount32(get32(p + 8));
        if (size > PROTO_MAX_PAYLOAD) {
            send_error(seq, ERR_OUT_OF_RANGE, type, size,
                       "reply would exceed the max payload; split the window");
            return;
        }
    }
    if (type == MSG_HELLO) {
        cache_clear();
        window_clear();                /* a new session: no stored window parameters */
    }
    link[L_EXECUTED]++;
    uint8_t rtype, err = 0;
    uint32_t detail = 0;
    const char *msg = "";
    int big = (type == MSG_SPIKE_BATCH || type == MSG_DECISION_WINDOW);
    uint8_t *rbuf = big ? big_buf : small_buf;
    int len = execute(type, p, plen, rbuf + PROTO_HEADER_SIZE, &rtype, &err, &detail, &msg);
    unsigned n;
    if (len < 0) {
        big = 0;
        n = build_error(seq, err, type, detail, msg);
        rbuf = small_buf;
    } else {
        frame_header(rbuf, 0, rtype, seq, (unsigned)len, boot_nonce);
        n = frame_finish(rbuf, (unsigned)len);
    }
    if (big && n <= SMALL_MAX)
        big = 0;                       /* a short reply (a window's counts): its own slot */
    if (!(len < 0 && err == ERR_BUSY))
        cache_store(seq, type, nonce, hash, plen, rbuf, n, big);
    if (type == MSG_RESET && len >= 0)
        for (unsigned i = 0; i < 10; i++)
            link[i] = 0;
    send_cobs(rbuf, n);
}

/* A complete COBS frame in rx_buf[0..n): decode in place, check, handle. */
static void frame_received(unsigned n)
{
    unsigned i = 0, o = 0;
    while (i < n) {
        unsigned code = rx_buf[i];
        unsigned end = i + code;
        hal_uart_service();                   /* a group of up to 254 bytes */
        if (end > n) {                    /* COBS group runs past the end */
            send_nak(NAK_COBS);
            return;
        }
        for (unsigned k = i + 1; k < end; k++)
            rx_buf[o++] = rx_buf[k];
        i = end;
        if (code < 0xFFu && i < n)
            rx_buf[o++] = 0;
    }
    if (o < PROTO_HEADER_SIZE + PROTO_CRC_SIZE) {
        send_nak(NAK_LENGTH);
        return;
    }
    unsigned plen = get16(rx_buf + 6);
    if (plen != o - PROTO_HEADER_SIZE - PROTO_CRC_SIZE || plen > PROTO_MAX_PAYLOAD) {
        send_nak(NAK_LENGTH);
        return;
    }
    unsigned body = PROTO_HEADER_SIZE + plen;
    if (get16(rx_buf + body) != crc16_ccitt_false(rx_buf, body)) {
        send_nak(NAK_CRC);
        return;
    }
    handle_frame(rx_buf, plen);
}

void proto_rx_byte(uint8_t b)
{
    if (b == 0) {
        if (rx_skipping) {
            rx_skipping = 0;
            rx_len = 0;
            return;
        }
        if (rx_len) {
            unsigned n = rx_len;
            rx_len = 0;
            frame_received(n);
        }
        return;
    }
    if (rx_skipping)
        return;
    if (rx_len >= PROTO_MAX_ENCODED) {    /* longer than the largest frame: drop to next 0 */
        rx_len = 0;
        rx_skipping = 1;
        send_nak(NAK_LENGTH);
        return;
    }
    rx_buf[rx_len++] = b;
}
