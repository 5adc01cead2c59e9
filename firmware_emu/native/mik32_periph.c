/* The MIK32 peripheral models of the instruction-level MCU - the fast (native) core.
 *
 * The same models as the reference core firmware_emu/mik32_periph.py, function for function,
 * on the same state (mcu_state.h, generated from firmware_emu/mik32_state.py). unicorn calls
 * mik32_block (UC_HOOK_BLOCK), mik32_apbm_* and mik32_apbp_* (uc_mmio_map) directly, so a
 * register access or a translated block costs no Python call. What touches the board - an SPI
 * frame handed to its chip, the LDAC pin, drawing ADC samples - calls back into Python through
 * s->event (an event handler of snan_hil.firmware_emu.mcu_isa.IsaMcu).
 *
 * One addition over the reference core (emulation shortcuts that change neither timing nor
 * results): a full 16-clock TLC3541 frame does not call Python. In a column circuit its
 * conversion is computed here (sample_column: the arithmetic of the analog front end's
 * sample_code and the crossbar's column_current, with numpy's own normal generator,
 * random_standard_normal from numpy's libnpyrandom, drawing from the array's and the front
 * end's random streams in the order Python would); in other circuits it comes from samples
 * drawn ahead by Python (EV_ADC_PREFETCH), unused draws being returned. Python accounts the
 * frames (device counters, trace) before anything else on the board moves (docs/firmware.md).
 * Built with -ffp-contract=off: no fused multiply-add, the same roundings as numpy.
 *
 * Built for the host with the pip-installed Zig toolchain by firmware_emu/native/build.py. */
#include <math.h>
#include <stdint.h>
#include "mcu_state.h"

typedef int (*emu_stop_fn)(void *uc);
typedef int (*event_fn)(int kind);

/* numpy's bit generator interface (numpy/random/bitgen.h) and its normal generator
 * (libnpyrandom, the code behind Generator.standard_normal) */
typedef struct bitgen {
    void *state;
    uint64_t (*next_uint64)(void *st);
    uint32_t (*next_uint32)(void *st);
    double (*next_double)(void *st);
    uint64_t (*next_raw)(void *st);
} bitgen_t;
double random_standard_normal(bitgen_t *bitgen_state);

#define MCU_HZ 32000000.0
#define WDT_SLOW_HZ 32768.0

/* APB_M page 0x5_0000 (offsets in the page) */
#define EPIC_OFF 0x400u
#define TIMER32_0_OFF 0x800u
#define PAD_OFF 0xC00u
/* APB_P window from 0x8_1000 */
#define UART0_OFF 0x0400u
#define TIMER32_1_OFF 0x1800u
#define SPI0_OFF 0x2000u
#define GPIO0_OFF 0x3000u

#define APB_M_PAD_CONFIG (1u << 3)
#define APB_P_WDT (1u << 0)
#define APB_P_UART0 (1u << 1)
#define APB_P_TIMER32_1 (1u << 6)
#define APB_P_SPI0 (1u << 8)
#define PAD_SERIAL 1u
#define UART_ON 0xDu            /* CONTROL1: UE, RE, TE */
#define TIM_CH_COMPARE_ON 0xA0u /* CH_CNTRL: ENABLE, MODE = 2 (compare) */
#define CS_PORT 1
#define N_CS 8
#define LDAC_PIN 8

static const uint32_t WDT_PRESCALE[8] = {1, 2, 4, 16, 64, 256, 1024, 4096};

int mik32_state_size(void) { return (int)sizeof(mcu_state); }
const char *mik32_state_layout(void) { return MCU_STATE_LAYOUT; }
const char *mik32_numpy_version(void) { return NUMPY_VERSION; }

static void stop(mcu_state *s, int reason)
{
    if (!s->stop_reason)
        s->stop_reason = reason;
    ((emu_stop_fn)(uintptr_t)s->emu_stop)((void *)(uintptr_t)s->uc);
}

static int event(mcu_state *s, int kind)
{
    return ((event_fn)(uintptr_t)s->event)(kind);
}

static void fault(mcu_state *s, int f) { s->faults[f]++; }

/* Count fault f if the peripheral's APB clock bit is off (the access goes on, as on the chip). */
static void apb_clocked(mcu_state *s, uint32_t clock_bit, int f)
{
    if (!(s->pm_p & clock_bit))
        fault(s, f);
}

/* apb_clocked(), and the access ends a run of empty UART FLAGS polls. */
static void apb_access(mcu_state *s, uint32_t clock_bit, int f)
{
    apb_clocked(s, clock_bit, f);
    s->prev_flags_read = 0;
    s->uart_poll = 0;
}

/* ------------------------------------------------------------------ time */
void mik32_block(void *uc, uint64_t address, uint32_t size, void *ud)
{
    (void)uc;
    mcu_state *s = (mcu_state *)ud;
    uint64_t n;
    s->block_pc = address;
    if (address >= s->text_base && address + size <= s->text_end) {
        const uint32_t *istart = (const uint32_t *)(uintptr_t)s->istart;
        uint64_t off = address - s->text_base;
        n = istart[(off + size) >> 1] - istart[off >> 1];
    } else {
        n = size >> 2;
        if (n < 1)
            n = 1;
    }
    s->cycles += n;
    s->instructions += n;
    s->acc[CAT_MCU] += n;
    if (s->instructions >= s->budget_end)
        stop(s, STOP_BUDGET);
    else if (s->wdt_enabled && (double)s->cycles >= s->wdt_deadline)
        stop(s, STOP_WATCHDOG);
}

static void wait_until(mcu_state *s, double target, int cat)
{
    if (target <= (double)s->cycles)
        return;
    uint64_t t = (uint64_t)ceil(target);
    if (s->wdt_enabled && (double)t > s->wdt_deadline) {
        uint64_t d = (uint64_t)ceil(s->wdt_deadline);
        t = d > s->cycles ? d : s->cycles;
        stop(s, STOP_WATCHDOG);
    }
    s->acc[cat] += t - s->cycles;
    s->cycles = t;
}

static double wdt_timeout_cycles(uint32_t con, uint32_t clk_mux)
{
    double ticks = (double)(4096u - (con & 0xFFFu));
    double prescale = (double)WDT_PRESCALE[(con >> 12) & 7u];
    double hz = (clk_mux & 3u) < 2u ? MCU_HZ : WDT_SLOW_HZ;
    return ticks * prescale * MCU_HZ / hz;
}

/* ------------------------------------------------------------------ APB_M page */
uint64_t mik32_apbm_read(void *uc, uint64_t off, unsigned size, void *ud)
{
    (void)uc; (void)size;
    mcu_state *s = (mcu_state *)ud;
    if (off < EPIC_OFF) {
        if (off == 0x14) return s->pm_m;
        if (off == 0x1C) return s->pm_p;
        if (off == 0x28) return s->wdt_clk_mux;
        return 0;
    }
    if (off < TIMER32_0_OFF)
        return 0;
    if (off >= PAD_OFF) {
        if (!(s->pm_m & APB_M_PAD_CONFIG))
            fault(s, F_PAD_CLOCK);
        uint64_t r = off - PAD_OFF, port = r / 0x0C, reg = r % 0x0C;
        if (port < 3) {
            if (reg == 0) return s->pad_cfg[port];
            if (reg == 4) return s->pad_ds[port];
            if (reg == 8) return s->pad_pupd[port];
        }
        return 0;
    }
    fault(s, F_UNMODELLED);
    return 0;
}

void mik32_apbm_write(void *uc, uint64_t off, unsigned size, uint64_t value64, void *ud)
{
    (void)uc; (void)size;
    mcu_state *s = (mcu_state *)ud;
    uint32_t value = (uint32_t)value64;
    if (off < EPIC_OFF) {
        if (off == 0x14) s->pm_m |= value;
        else if (off == 0x18) s->pm_m &= ~value;
        else if (off == 0x1C) s->pm_p |= value;
        else if (off == 0x20) s->pm_p &= ~value;
        else if (off == 0x28) s->wdt_clk_mux = value & 3u;
        return;
    }
    if (off < TIMER32_0_OFF)
        return;
    if (off >= PAD_OFF) {
        if (!(s->pm_m & APB_M_PAD_CONFIG))
            fault(s, F_PAD_CLOCK);
        uint64_t r = off - PAD_OFF, port = r / 0x0C, reg = r % 0x0C;
        if (port < 3) {
            if (reg == 0) s->pad_cfg[port] = value;
            else if (reg == 4) s->pad_ds[port] = value;
            else if (reg == 8) s->pad_pupd[port] = value;
        }
        return;
    }
    fault(s, F_UNMODELLED);
}

/* ------------------------------------------------------------------ WDT */
static uint32_t wdt_read(mcu_state *s, uint64_t off)
{
    apb_clocked(s, APB_P_WDT, F_WDT_CLOCK);
    if (off == 0x84)
        return s->wdt_con;
    if (off == 0x9C)
        return (s->wdt_enabled ? 1u : 0u) | (s->wdt_rst_flag ? 0x100u : 0u);
    return 0;
}

static void wdt_write(mcu_state *s, uint64_t off, uint32_t value)
{
    apb_clocked(s, APB_P_WDT, F_WDT_CLOCK);
    if (off == 0x9C) {
        uint32_t key = value & 0xFFu;
        if (key == 0x1E) {
            s->wdt_unlocked = 1;
            return;
        }
        if (!s->wdt_unlocked) {
            fault(s, F_WDT_LOCKED);
            return;
        }
        s->wdt_unlocked = 0;
        if (key == 0x71) {
            s->wdt_enabled = 1;
            s->wdt_kicks++;
            s->wdt_deadline = (double)s->cycles + wdt_timeout_cycles(s->wdt_con, s->wdt_clk_mux);
        } else if (key == 0xE8) {
            s->wdt_enabled = 0;
        }
    } else if (off == 0x84) {
        if (!s->wdt_unlocked) {
            fault(s, F_WDT_LOCKED);
            return;
        }
        s->wdt_unlocked = 0;
        s->wdt_con = value & 0x7FFFu;
    }
}

/* Spin timing: the flag that becomes true at `target` reads "not yet" (counted). */
static int spin(mcu_state *s, double target)
{
    if (s->poll_spin && target - (double)s->cycles > (double)SPIN_SLACK) {
        s->spin_polls++;
        return 1;
    }
    return 0;
}

/* ------------------------------------------------------------------ UART_0 */
static void uart_pads(mcu_state *s)
{
    uint32_t cfg = s->pad_cfg[0];
    if (((cfg >> 10) & 3u) != PAD_SERIAL || ((cfg >> 12) & 3u) != PAD_SERIAL)
        fault(s, F_UART_PADS);
}

static uint32_t uart_read(mcu_state *s, uint64_t off)
{
    apb_clocked(s, APB_P_UART0, F_UART_CLOCK);
    s->uart_poll = 1;
    if (off == 0x1C) {
        if (s->frame_sent) {                    /* pause after a frame (pump); the read */
            s->frame_sent = 0;                  /* runs again on resuming */
            stop(s, STOP_FRAME);
            return 0;
        }
        if ((double)s->cycles < s->tx_hold_free) {  /* waiting to transmit: until the holding */
            double t = s->tx_hold_free;             /* register is free, or a host byte */
            if (s->rx_count) {                      /* arrives (seen at the next poll) */
                if (s->rx_t[s->rx_head] > (double)s->cycles)
                    t = fmin(t, s->rx_t[s->rx_head]);
                else if (s->rx_told != s->rx_head + 1)   /* arrived, not yet seen */
                    t = (double)s->cycles;
            }
            if (!spin(s, t))
                wait_until(s, t, CAT_IDLE);
        }
        uint32_t flags = 0;
        if ((double)s->cycles >= s->tx_hold_free)
            flags |= 1u << 7;
        if ((double)s->cycles >= s->tx_end)
            flags |= 1u << 6;
        if (s->rx_count && s->rx_t[s->rx_head] <= (double)s->cycles) {
            flags |= 1u << 5;                   /* RXNE: a byte has arrived */
            s->rx_told = s->rx_head + 1;
            s->prev_flags_read = 0;
        } else if (s->idle_hi && !(s->idle_lo <= s->block_pc && s->block_pc < s->idle_hi)) {
            s->prev_flags_read = 0;             /* a poll while working */
        } else if (s->prev_flags_read) {        /* the idle loop polled twice, with no */
            if (s->rx_count) {                  /* other access between: it waits for */
                wait_until(s, s->rx_t[s->rx_head], CAT_UART);   /* the next host byte */
                flags |= 1u << 5;
                s->prev_flags_read = 0;
            } else {
                stop(s, STOP_IDLE);             /* idle until the host sends more */
            }
        } else {
            s->prev_flags_read = 1;
        }
        return flags;
    }
    s->prev_flags_read = 0;
    if (off == 0x24) {
        uart_pads(s);
        if (s->rx_count && s->rx_t[s->rx_head] <= (double)s->cycles) {
            if (s->rx_count > 1 && s->rx_t[(s->rx_head + 1) & (RX_CAP - 1)] <= (double)s->cycles)
                fault(s, F_UART_OVERRUN);       /* the next byte came meanwhile */
            uint32_t b = s->rx_b[s->rx_head];
            s->rx_head = (s->rx_head + 1) & (RX_CAP - 1);
            s->rx_count--;
            s->rx_told = s->rx_told_timer = 0;
            return b;
        }
        return 0;
    }
    if (off == 0x00)
        return s->uart_on ? 0xDu : 0u;
    return 0;
}

static void uart_write(mcu_state *s, uint64_t off, uint32_t value)
{
    apb_access(s, APB_P_UART0, F_UART_CLOCK);
    if (off == 0x28) {
        uart_pads(s);
        if (!s->uart_on) {                          /* disabled: nothing goes out */
            fault(s, F_UART_OFF);
            return;
        }
        double start = (double)s->cycles > s->tx_end ? (double)s->cycles : s->tx_end;
        s->tx_hold_free = start;
        s->tx_end = start + s->byte_cycles;
        if (s->tx_len >= TX_CAP)
            event(s, EV_TX_FULL);
        s->tx_out[s->tx_len++] = (uint8_t)value;
        if (s->stop_on_frame && !(value & 0xFFu))   /* a frame sent: the host may answer */
            s->frame_sent = 1;
    } else if (off == 0x00) {
        s->uart_on = (value & UART_ON) == UART_ON;
    }
}

/* ------------------------------------------------------------------ TIMER32_1 */
/* VALUE: counting from tim_start while enabled, else held */
static uint32_t timer_value(const mcu_state *s)
{
    return s->tim_on ? (uint32_t)(s->cycles - s->tim_start) : s->tim_hold;
}

static void timer_arm(mcu_state *s)
{
    uint32_t value = timer_value(s);
    s->oc_target = s->cycles + (uint32_t)(s->ocr - value);
    s->oc_armed = 1;
}

/* A compare poll not yet due, with a host byte queued: "not yet" once for that byte, at its
 * arrival (a loop serving the UART reads it in time; one that does not polls again and jumps
 * to its compare); a byte that arrived before the poll and was not yet answered for: at once
 * (the reference core's _host_byte_first). */
static int host_byte_first(mcu_state *s, uint32_t polled)
{
    double t = ceil(s->rx_t[s->rx_head]);
    double slack = polled ? 0.0 : (double)SPIN_SLACK;
    double now = (double)s->cycles;
    if (now < t) {
        if (t + slack >= (double)s->oc_target)
            return 0;
        wait_until(s, t, CAT_IDLE);
    } else if (s->rx_told_timer == s->rx_head + 1 || now + slack >= (double)s->oc_target) {
        return 0;
    }
    s->rx_told_timer = s->rx_head + 1;
    return 1;
}

static uint32_t timer_read(mcu_state *s, uint64_t off)
{
    uint32_t polled = s->uart_poll;
    apb_access(s, APB_P_TIMER32_1, F_TIMER_CLOCK);
    if (off == 0x00)
        return timer_value(s);
    if (off == 0x1C) {
        if (s->oc_armed && !s->oc_flag && s->tim_on &&
            (s->ch0_cntrl & 0xB0u) == TIM_CH_COMPARE_ON) {
            if (spin(s, (double)s->oc_target))
                return 0;
            if (s->rx_count && host_byte_first(s, polled))
                return 0;
            wait_until(s, (double)s->oc_target, CAT_IDLE);
            s->oc_flag = 1;
        }
        return s->oc_flag ? (1u << 6) : 0u;
    }
    if (off == 0x84)
        return s->ocr;
    return 0;
}

static void timer_write(mcu_state *s, uint64_t off, uint32_t value)
{
    apb_access(s, APB_P_TIMER32_1, F_TIMER_CLOCK);
    if (off == 0x10) {                          /* ENABLE: CLR (bit 1), EN (bit 0) */
        uint32_t now = (value & 2u) ? 0u : timer_value(s);
        s->tim_on = value & 1u;
        if (s->tim_on)
            s->tim_start = s->cycles - now;
        else
            s->tim_hold = now;
        if (s->oc_armed)
            timer_arm(s);
    } else if (off == 0x84) {
        s->ocr = value;                         /* OC0 stays as it is: INT_CLEAR clears it */
        timer_arm(s);
    } else if (off == 0x80) {
        s->ch0_cntrl = value;
    } else if (off == 0x18) {
        if (value & (1u << 6)) {
            s->oc_flag = 0;
            timer_arm(s);
        }
    }
}

/* ------------------------------------------------------------------ SPI_0 */
static int frame_pending(const mcu_state *s)
{
    return s->frame_pin >= 0 && !s->frame_done && s->mosi_len > 0;
}

static void fifo_push(mcu_state *s, uint8_t b)
{
    if (s->fifo_count == FIFO_CAP) {                 /* overflow: the oldest byte is lost */
        s->fifo_head = (s->fifo_head + 1) % FIFO_CAP;
        s->fifo_count--;
    }
    s->fifo[(s->fifo_head + s->fifo_count) % FIFO_CAP] = b;
    s->fifo_count++;
}

/* numpy's summation of n <= 128 doubles (pairwise_sum in numpy's loops: below 8 one by one
 * from 0, else 8 accumulators, combined pairwise, then the rest one by one) */
static double numpy_sum(const double *a, int n)
{
    int i;
    if (n < 8) {
        double res = 0.0;
        for (i = 0; i < n; i++)
            res += a[i];
        return res;
    }
    double r[8];
    for (i = 0; i < 8; i++)
        r[i] = a[i];
    for (i = 8; i < n - (n % 8); i += 8)
        for (int j = 0; j < 8; j++)
            r[j] += a[i + j];
    double res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
    for (; i < n; i++)
        res += a[i];
    return res;
}

/* One ADC sample of the column circuit: AnalogFrontEnd.sample_code with
 * CrossbarArray.column_current, operation for operation. 0: not finite (Python decides). */
static int sample_column(mcu_state *s, uint16_t *code)
{
    int k = (int)s->k_rows;
    double z0[KERNEL_ROWS], z1[KERNEL_ROWS], w[KERNEL_ROWS];
    if (s->k_read_noisy) {
        bitgen_t *gen = (bitgen_t *)(uintptr_t)s->k_gen_read;
        for (int i = 0; i < k; i++)
            z0[i] = random_standard_normal(gen);       /* (2, k) normals: relative first */
        for (int i = 0; i < k; i++)
            z1[i] = random_standard_normal(gen);
    }
    for (int i = 0; i < k; i++) {
        double g = s->k_g[i];
        if (s->k_read_noisy) {
            double t = s->k_rel * z0[i];
            t = 1.0 + t;
            t = g * t;
            double u = s->k_abs * z1[i];
            t = t + u;
            g = (t >= 0.0 || t != t) ? t : 0.0;       /* np.maximum(t, 0.0) */
        }
        double d = g * s->k_r_mac;
        d = 1.0 + d;
        d = g / d;
        w[i] = s->k_v[i] * d;
    }
    double current = numpy_sum(w, k);
    double ideal = s->k_scale * current;
    ideal = ideal * s->k_lsb;
    ideal = ideal / s->k_vref;
    if (s->k_adc_noisy) {
        double z = random_standard_normal((bitgen_t *)(uintptr_t)s->k_gen_adc);
        double noise = 0.0 + s->k_sigma * z;             /* Generator.normal(0, sigma) */
        ideal = ideal + noise;
    }
    double r = floor(ideal + 0.5);
    if (!isfinite(r))
        return 0;
    if (r > (double)s->k_full || r < 0.0) {
        s->k_saturated++;
        r = r < 0.0 ? 0.0 : (double)s->k_full;
    }
    *code = (uint16_t)r;
    return 1;
}

/* A full TLC3541 frame without Python (the conversion it shifts out is the previous one; its
 * own conversion is computed here or the next sample drawn ahead). 0: Python takes it. */
static int adc_frame_fast(mcu_state *s)
{
    uint16_t code;
    if (s->k_on && s->adc_mode != ADC_AHEAD) {
        if (s->adc_used >= ADC_CAP)
            event(s, EV_ADC_SETTLE);                   /* log full: Python accounts it */
        if (!sample_column(s, &code))
            return 0;
        s->adc_mode = ADC_KERNEL;
        s->adc_codes[s->adc_used] = code;
    } else {
        if (s->adc_mode == ADC_KERNEL || s->adc_used >= s->adc_n) {
            event(s, EV_ADC_PREFETCH);                 /* account, then draw a reading */
            if (s->adc_mode != ADC_AHEAD || s->adc_n == 0)
                return 0;
        }
        code = s->adc_codes[s->adc_used];
    }
    uint64_t st = s->frame_start;
    if (s->adc_have_last && st < s->adc_last_start + s->adc_cycle)
        s->adc_early++;
    s->adc_last_start = st;
    s->adc_have_last = 1;
    uint32_t r = s->adc_result;
    fifo_push(s, (uint8_t)((r >> 6) & 0xFFu));
    fifo_push(s, (uint8_t)((r & 0x3Fu) << 2));
    s->adc_result = code;
    s->adc_starts[s->adc_used] = st;
    s->adc_used++;
    s->frame_done = 1;
    return 1;
}

static void deliver(mcu_state *s)
{
    if (s->adc_fast && s->frame_pin == s->adc_pin && s->mosi_len == 2 && s->mosi[0] == 0 &&
        s->mosi[1] == 0 && adc_frame_fast(s))
        return;
    event(s, EV_DELIVER);
}

static uint32_t spi_read(mcu_state *s, uint64_t off)
{
    apb_access(s, APB_P_SPI0, F_SPI_CLOCK);
    if (off == 0x04) {
        if (s->byte_end > s->cycles) {
            if (spin(s, (double)s->byte_end)) {     /* shifting: ACTIVE; TX FIFO full when */
                uint64_t per_byte = 8u * s->spi_div;    /* FIFO_CAP bytes wait behind */
                uint64_t queued = (s->byte_end - s->cycles + per_byte - 1) / per_byte - 1;
                uint32_t st = (1u << 15) | (queued < FIFO_CAP ? 1u << 2 : 0u);
                return st | ((s->fifo_count || frame_pending(s)) ? 1u << 4 : 0u);
            }
            wait_until(s, (double)s->byte_end, CAT_SPI);
        }
        uint32_t st = 1u << 2;
        if (s->fifo_count || frame_pending(s))
            st |= 1u << 4;
        return st;
    }
    if (off == 0x20) {
        if (frame_pending(s)) {
            if (s->byte_end > s->cycles)
                wait_until(s, (double)s->byte_end, CAT_SPI);
            deliver(s);
        }
        if (s->fifo_count) {
            uint8_t b = s->fifo[s->fifo_head];
            s->fifo_head = (s->fifo_head + 1) % FIFO_CAP;
            s->fifo_count--;
            return b;
        }
        return 0;
    }
    if (off == 0x00)
        return s->spi_config;
    return 0;
}

static void spi_write(mcu_state *s, uint64_t off, uint32_t value)
{
    apb_access(s, APB_P_SPI0, F_SPI_CLOCK);
    if (off == 0x1C) {
        uint32_t cfg = s->pad_cfg[0];
        if ((cfg & 3u) != PAD_SERIAL || ((cfg >> 2) & 3u) != PAD_SERIAL ||
            ((cfg >> 4) & 3u) != PAD_SERIAL)
            fault(s, F_SPI_PADS);
        if (!s->spi_on) {                       /* disabled: nothing shifts */
            fault(s, F_SPI_OFF);
            return;
        }
        if (s->frame_pin < 0) {
            fault(s, F_SPI_NO_CS);
            return;
        }
        if (s->frame_done) {
            fault(s, F_SPI_AFTER_READ);
            return;
        }
        if (s->mosi_len >= MOSI_CAP) {
            fault(s, F_FRAME_TOO_LONG);
            return;
        }
        uint64_t start = s->cycles > s->byte_end ? s->cycles : s->byte_end;
        if (!s->mosi_len)
            s->frame_start = start;
        s->byte_end = start + 8u * s->spi_div;
        s->mosi[s->mosi_len++] = (uint8_t)value;
    } else if (off == 0x00) {
        s->spi_config = value;
        s->spi_div = 2u << ((value >> 3) & 7u);
    } else if (off == 0x14) {
        s->spi_on = value & 1u;
        if (value & (1u << 3))
            s->fifo_count = 0;
    }
}

/* ------------------------------------------------------------------ GPIO */
static void pins_changed(mcu_state *s, uint32_t old, uint32_t new_)
{
    uint32_t rising = new_ & ~old, falling = old & ~new_;
    if (s->frame_pin >= 0 && (rising & (1u << s->frame_pin))) {
        if (s->byte_end > s->cycles)
            fault(s, F_CS_WHILE_SHIFTING);
        if (!s->frame_done && s->mosi_len)
            deliver(s);
        s->frame_pin = -1;
    }
    uint32_t cs_falling = falling & ((1u << N_CS) - 1u);
    if (cs_falling) {
        uint32_t cfg = s->pad_cfg[CS_PORT];
        for (int pin = 0; pin < N_CS; pin++) {
            if (cs_falling & (1u << pin)) {
                if (((cfg >> (2 * pin)) & 3u) != 0 || !(s->gpio_dir[CS_PORT] & (1u << pin)))
                    fault(s, F_CS_PAD);
                if (s->frame_pin >= 0)
                    fault(s, F_TWO_CS);
                s->frame_pin = pin;
                s->mosi_len = 0;
                s->frame_done = 0;
            }
        }
    }
    if (falling & (1u << LDAC_PIN))
        event(s, EV_LDAC);
}

static uint32_t gpio_read(mcu_state *s, int port, uint64_t off)
{
    apb_access(s, 1u << (12 + port), F_GPIO_CLOCK);
    if (off == 0x00 || off == 0x10)
        return s->gpio_out[port];
    if (off == 0x08 || off == 0x0C)
        return s->gpio_dir[port];
    return 0;
}

static void gpio_write(mcu_state *s, int port, uint64_t off, uint32_t value)
{
    apb_access(s, 1u << (12 + port), F_GPIO_CLOCK);
    uint32_t old = s->gpio_out[port], new_;
    if (off == 0x00)
        new_ = old | value;
    else if (off == 0x04)
        new_ = old & ~value;
    else if (off == 0x10)
        new_ = value;
    else {
        if (off == 0x08)
            s->gpio_dir[port] |= value;
        else if (off == 0x0C)
            s->gpio_dir[port] &= ~value;
        return;
    }
    s->gpio_out[port] = new_;
    if (port == CS_PORT)
        pins_changed(s, old, new_);
}

/* ------------------------------------------------------------------ APB_P window */
uint64_t mik32_apbp_read(void *uc, uint64_t off, unsigned size, void *ud)
{
    (void)uc; (void)size;
    mcu_state *s = (mcu_state *)ud;
    if (off < UART0_OFF)
        return wdt_read(s, off);
    if (off < UART0_OFF + 0x400)
        return uart_read(s, off - UART0_OFF);
    if (off >= TIMER32_1_OFF && off < TIMER32_1_OFF + 0x400)
        return timer_read(s, off - TIMER32_1_OFF);
    if (off >= SPI0_OFF && off < SPI0_OFF + 0x400)
        return spi_read(s, off - SPI0_OFF);
    if (off >= GPIO0_OFF && off < GPIO0_OFF + 0xC00)
        return gpio_read(s, (int)((off - GPIO0_OFF) >> 10), (off - GPIO0_OFF) & 0x3FF);
    fault(s, F_UNMODELLED);
    return 0;
}

void mik32_apbp_write(void *uc, uint64_t off, unsigned size, uint64_t value64, void *ud)
{
    (void)uc; (void)size;
    mcu_state *s = (mcu_state *)ud;
    uint32_t value = (uint32_t)value64;
    if (off < UART0_OFF)
        wdt_write(s, off, value);
    else if (off < UART0_OFF + 0x400)
        uart_write(s, off - UART0_OFF, value);
    else if (off >= TIMER32_1_OFF && off < TIMER32_1_OFF + 0x400)
        timer_write(s, off - TIMER32_1_OFF, value);
    else if (off >= SPI0_OFF && off < SPI0_OFF + 0x400)
        spi_write(s, off - SPI0_OFF, value);
    else if (off >= GPIO0_OFF && off < GPIO0_OFF + 0xC00)
        gpio_write(s, (int)((off - GPIO0_OFF) >> 10), (off - GPIO0_OFF) & 0x3FF, value);
    else
        fault(s, F_UNMODELLED);
}
