/* MIK32 implementation of hal.h: UART_0 to the host, SPI_0 (master, manual chip selects on
 * GPIO_1 pins 0-7, LDAC on GPIO_1 pin 8) to the board's chips, TIMER32_1 as the tick counter
 * and compare for waits, the watchdog armed at 2 s. Register facts: mik32_regs.h. Board wiring
 * (which GPIO pin selects which chip) is this project's assumption, the same as the
 * emulator's (docs/firmware.md). */
#include "hal.h"
#include "mik32_regs.h"
#include "snan_constants.h"

#define UART(off) REG32(MIK_UART0_BASE + (off))
#define SPI(off)  REG32(MIK_SPI0_BASE + (off))
#define GPIO(off) REG32(MIK_GPIO1_BASE + (off))
#define TIM(off)  REG32(MIK_TIMER32_1_BASE + (off))

#define WDT8(off) (*(volatile uint8_t *)(uintptr_t)(MIK_WDT_BASE + (off)))
#define WDT(off)  REG32(MIK_WDT_BASE + (off))

#define GPIO_LDAC_PIN 8u          /* AD5328 LDAC, held high (outputs follow each write) */
/* watchdog: LSI32K / 64 = 512 Hz, 1024 ticks = 2 s (> the longest pulse, 1 s) */
#define WDT_TIMEOUT_TICKS 1024u
#define WDT_SAFE_TICKS (MCU_HZ / 2u)   /* long waits kick at least every 0.5 s */
#define SPI_FIFO_DEPTH 8u         /* ASSUMPTION: the SDK names FIFO flags, not the depth */
#define UART_BAUD 115200u
#define PULSE_TAIL_TICKS 64u      /* a pulse's last ticks: the exact loop alone */

/* Uninitialised RAM: its power-up contents seed the boot nonce (not cleared at start-up). */
__attribute__((section(".noinit"))) static volatile uint32_t noinit_entropy[16];

static uint32_t now_hi, now_last;

static void wdt_key(uint8_t key)
{
    WDT8(WDT_KEY) = WDT_KEY_UNLOCK;
    WDT8(WDT_KEY) = key;
}

void hal_init(void)
{
    REG32(PM_CLK_APB_M_SET) = PM_APB_M_EPIC | PM_APB_M_PAD_CONFIG;
    REG32(PM_CLK_APB_P_SET) = PM_APB_P_WDT | PM_APB_P_UART0 | PM_APB_P_SPI0 | PM_APB_P_GPIO1 |
                              PM_APB_P_TIMER32_1;
    /* watchdog first: LSI32K, prescaler 64, reset 2 s after the last kick */
    REG32(PM_WDT_CLK_MUX) = PM_WDT_CLK_LSI32K;
    WDT8(WDT_KEY) = WDT_KEY_UNLOCK;
    WDT(WDT_CON) = (WDT_PRESCALE_64 << WDT_CON_PRESCALE_S) | (4096u - WDT_TIMEOUT_TICKS);
    wdt_key(WDT_KEY_START);
    /* pads: SPI0 MISO/MOSI/CLK (port 0 pins 0-2) and UART0 RX/TX (pins 5-6) in their
     * peripheral mode; chip selects and LDAC (port 1 pins 0-8) GPIO; other pins untouched */
    uint32_t p0 = REG32(PAD_PORT0_CFG);
    p0 &= ~(PAD_FIELD(0, 3u) | PAD_FIELD(1, 3u) | PAD_FIELD(2, 3u) | PAD_FIELD(5, 3u) |
            PAD_FIELD(6, 3u));
    p0 |= PAD_FIELD(0, PAD_MODE_FUNC1) | PAD_FIELD(1, PAD_MODE_FUNC1) |
          PAD_FIELD(2, PAD_MODE_FUNC1) | PAD_FIELD(5, PAD_MODE_FUNC1) |
          PAD_FIELD(6, PAD_MODE_FUNC1);
    REG32(PAD_PORT0_CFG) = p0;
    REG32(PAD_PORT1_CFG) &= ~((1u << (2u * (GPIO_LDAC_PIN + 1u))) - 1u);
    /* chip selects high (idle), LDAC high, then make them outputs */
    uint32_t pins = ((1u << DEV_COUNT) - 1u) | (1u << GPIO_LDAC_PIN);
    GPIO(GPIO_SET) = pins;
    GPIO(GPIO_DIR_OUT) = pins;
    /* timer: free-running up-counter at the system clock, no prescaler, top = 2^32 - 1 */
    TIM(TIM_ENABLE) = 0;
    TIM(TIM_TOP) = 0xFFFFFFFFu;
    TIM(TIM_PRESCALER) = 0;
    TIM(TIM_CONTROL) = 0;
    TIM(TIM_CH0_CNTRL) = TIM_CH_MODE_COMPARE | TIM_CH_ENABLE;
    TIM(TIM_ENABLE) = TIM_ENABLE_CLR | TIM_ENABLE_EN;
    /* SPI_0: master, mode 0 (CPOL 0, CPHA 0), divider 2, manual CS (chips on GPIO) */
    SPI(SPI_ENABLE) = 0;
    SPI(SPI_CONFIG) = SPI_CONFIG_MASTER | (0u << SPI_CONFIG_DIV_S) | SPI_CONFIG_CS_NONE |
                      SPI_CONFIG_MANUAL_CS;
    SPI(SPI_ENABLE) = SPI_ENABLE_EN | SPI_ENABLE_CLR_TX | SPI_ENABLE_CLR_RX;
    /* UART_0: 8N1 */
    UART(UART_DIVIDER) = (MCU_HZ + UART_BAUD / 2u) / UART_BAUD;
    UART(UART_CONTROL1) = UART_CONTROL1_UE | UART_CONTROL1_RE | UART_CONTROL1_TE;
    now_hi = 0;
    now_last = TIM(TIM_VALUE);
}

uint32_t hal_now(void)
{
    uint32_t v = TIM(TIM_VALUE);
    if (v < now_last)
        now_hi++;
    now_last = v;
    return v;
}

uint64_t hal_now64(void)
{
    uint32_t lo = hal_now();
    return ((uint64_t)now_hi << 32) | lo;
}

/* Host bytes that arrive while the firmware is busy: the UART has one receive register, so
 * every wait (hal_wait_until) and every byte sent (hal_uart_putc) moves an arrived byte into
 * this ring, and hal_uart_getc returns the ring's bytes first (a byte is lost only when the
 * ring is full; the frame it belonged to then fails its CRC and is resent). */
static uint8_t rx_ring[HAL_RX_RING];
static uint8_t rx_head, rx_tail;              /* free running, mod 256 (HAL_RX_RING | 256) */

/* Out of line: the only UART poll inside hal_uart_getc is then the idle loop's (the emulator
 * recognises the main loop waiting for the host by two empty polls there, docs/emulator.md). */
__attribute__((noinline)) void hal_uart_service(void)
{
    if (UART(UART_FLAGS) & UART_FLAGS_RXNE) {
        uint8_t b = (uint8_t)UART(UART_RXDATA);
        if ((uint8_t)(rx_tail - rx_head) < HAL_RX_RING)
            rx_ring[rx_tail++ % HAL_RX_RING] = b;
    }
}

/* wait for tick t; `serve`: the UART served meanwhile (waits of more than a byte time) */
static void wait_until(uint32_t t, int serve)
{
    if ((int32_t)(hal_now() - t) >= 0)
        return;
    TIM(TIM_CH0_OCR) = t;
    TIM(TIM_INT_CLEAR) = TIM_INT_OC0;
    if ((int32_t)(hal_now() - t) >= 0)
        return;
    if (serve)
        while (!(TIM(TIM_INT_FLAGS) & TIM_INT_OC0))
            hal_uart_service();
    else
        while (!(TIM(TIM_INT_FLAGS) & TIM_INT_OC0)) {
        }
    (void)hal_now();
}

void hal_wait_until(uint32_t t)
{
    hal_uart_service();
    wait_until(t, 1);
}

static inline void cs_low(int dev) { GPIO(GPIO_CLEAR) = 1u << dev; }
static inline void cs_high(int dev) { GPIO(GPIO_SET) = 1u << dev; }

static inline void spi_wait_idle(void)
{
    while (SPI(SPI_INT_STATUS) & SPI_ST_ACTIVE) {
    }
}

void hal_spi_write(int dev, const uint8_t *tx, unsigned n)
{
    cs_low(dev);
    for (unsigned i = 0; i < n; i++) {
        if (i >= SPI_FIFO_DEPTH)
            while (!(SPI(SPI_INT_STATUS) & SPI_ST_TX_NOT_FULL)) {
            }
        SPI(SPI_TXDATA) = tx[i];
    }
    spi_wait_idle();
    cs_high(dev);
}

void hal_adc_frames(uint8_t *rx, unsigned count, uint32_t spacing)
{
    hal_uart_service();                     /* one reading is shorter than a UART byte, */
    SPI(SPI_ENABLE) = SPI_ENABLE_EN | SPI_ENABLE_CLR_RX;    /* drop MISO of write frames */
    uint32_t t = hal_now() - spacing;       /* frame k starts >= spacing after frame k-1 */
    for (unsigned k = 0; k < count; k++) {
        wait_until(t + spacing, 0);
        t = hal_now();
        cs_low(DEV_ADC);
        SPI(SPI_TXDATA) = 0;
        SPI(SPI_TXDATA) = 0;
        spi_wait_idle();
        rx[2 * k] = (uint8_t)SPI(SPI_RXDATA);
        rx[2 * k + 1] = (uint8_t)SPI(SPI_RXDATA);
        cs_high(DEV_ADC);
    }
    hal_uart_service();     /* and after it: the caller's work that follows needs its byte */
}

uint32_t hal_adc_frame(uint8_t *rx, uint32_t not_before)
{
    SPI(SPI_ENABLE) = SPI_ENABLE_EN | SPI_ENABLE_CLR_RX;    /* drop MISO of write frames */
    wait_until(not_before, 0);              /* short: the caller serves the UART */
    uint32_t t = hal_now();
    cs_low(DEV_ADC);
    SPI(SPI_TXDATA) = 0;
    SPI(SPI_TXDATA) = 0;
    spi_wait_idle();
    rx[0] = (uint8_t)SPI(SPI_RXDATA);
    rx[1] = (uint8_t)SPI(SPI_RXDATA);
    cs_high(DEV_ADC);
    return t;
}

/* The pulse gate opens and closes at the 74HC595's latch (CS rising). Both latches are a
 * single GPIO store issued right after a timer access in the same straight-line block, so the
 * gate stays open for exactly `width` ticks: the close store follows the compare flag by the
 * same fixed number of instructions as the open store follows the timer read (2). The
 * functions are aligned so that the two sequences never straddle a page. A long pulse
 * (`serve`) waits with the UART served until its last PULSE_TAIL_TICKS, then ends exactly as
 * a short one (whose code has no branch for it: a constant at compile time). */
static inline __attribute__((always_inline)) void pulse_body(uint8_t open_byte, uint32_t width,
                                                             const int serve)
{
    uint32_t mask = 1u << DEV_SR_COL;
    uint32_t t_open;
    cs_low(DEV_SR_COL);
    SPI(SPI_TXDATA) = open_byte;
    spi_wait_idle();
    __asm__ volatile(
        "lw   %0, %c2(%1)\n\t"
        "sw   %3, %c5(%4)\n\t"
        : "=&r"(t_open)
        : "r"(MIK_TIMER32_1_BASE), "i"(TIM_VALUE), "r"(mask), "r"(MIK_GPIO1_BASE),
          "i"(GPIO_SET)
        : "memory");
    /* shift the closing byte in now; it reaches the outputs only at the next latch */
    cs_low(DEV_SR_COL);
    SPI(SPI_TXDATA) = 0;
    spi_wait_idle();
    uint32_t target = t_open + width - 2u;
    if (serve)
        hal_wait_until(target - PULSE_TAIL_TICKS);
    TIM(TIM_CH0_OCR) = target;
    TIM(TIM_INT_CLEAR) = TIM_INT_OC0;
    uint32_t tmp;
    __asm__ volatile(
        "1: lw   %0, %c2(%1)\n\t"
        "   andi %0, %0, %3\n\t"
        "   beqz %0, 1b\n\t"
        "   sw   %4, %c6(%5)\n\t"
        "   j    2f\n\t"
        "2:\n\t"
        : "=&r"(tmp)
        : "r"(MIK_TIMER32_1_BASE), "i"(TIM_INT_FLAGS), "i"(TIM_INT_OC0), "r"(mask),
          "r"(MIK_GPIO1_BASE), "i"(GPIO_SET)
        : "memory");
    (void)hal_now();
}

__attribute__((aligned(256), noinline)) static void pulse_short(uint8_t open_byte,
                                                                uint32_t width)
{
    pulse_body(open_byte, width, 0);
}

__attribute__((aligned(256), noinline)) static void pulse_long(uint8_t open_byte,
                                                               uint32_t width)
{
    pulse_body(open_byte, width, 1);
}

void hal_pulse(uint8_t open_byte, uint32_t width)
{
    if (width > 2u * PULSE_TAIL_TICKS)
        pulse_long(open_byte, width);
    else
        pulse_short(open_byte, width);
}

int hal_uart_getc(void)
{
    if (rx_head != rx_tail) {           /* the ring first; the UART served meanwhile */
        hal_uart_service();
        return rx_ring[rx_head++ % HAL_RX_RING];
    }
    uint32_t flags = UART(UART_FLAGS);
    if (!(flags & UART_FLAGS_RXNE))
        return -1;
    return (int)(UART(UART_RXDATA) & 0xFFu);
}

void hal_uart_putc(uint8_t b)
{
    for (;;) {                                  /* the host may send while we answer */
        uint32_t flags = UART(UART_FLAGS);
        if ((flags & UART_FLAGS_RXNE) && (uint8_t)(rx_tail - rx_head) < HAL_RX_RING)
            rx_ring[rx_tail++ % HAL_RX_RING] = (uint8_t)UART(UART_RXDATA);
        if (flags & UART_FLAGS_TXE)
            break;
    }
    UART(UART_TXDATA) = b;
}

uint32_t hal_entropy(void)
{
    uint32_t h = 2166136261u;                 /* FNV-1a over uninitialised RAM + timer */
    for (unsigned i = 0; i < sizeof noinit_entropy / sizeof noinit_entropy[0]; i++) {
        uint32_t w = noinit_entropy[i];
        for (int b = 0; b < 4; b++) {
            h ^= (w >> (8 * b)) & 0xFFu;
            h *= 16777619u;
        }
    }
    uint32_t t = hal_now();
    h ^= t;
    h *= 16777619u;
    noinit_entropy[h & 15u] ^= h;             /* the next boot draws another nonce */
    return h;
}

void hal_wait_long(uint64_t t)
{
    uint64_t now = hal_now64();
    while (now < t) {
        uint64_t left = t - now;
        hal_wait_until((uint32_t)now + (uint32_t)(left > WDT_SAFE_TICKS ? WDT_SAFE_TICKS : left));
        hal_watchdog_kick();
        now = hal_now64();
    }
}

void hal_watchdog_kick(void) { wdt_key(WDT_KEY_START); }

int hal_watchdog_caused_reset(void) { return (WDT(WDT_STA) & WDT_STA_RST_FLAG) != 0; }

unsigned hal_chip_serial(char *out, unsigned max)
{
    /* the EEPROM is read over the bus like memory (the MCU can execute from it) */
    const volatile uint8_t *rec = (const volatile uint8_t *)(uintptr_t)CHIP_ID_RECORD_ADDR;
    uint32_t magic = (uint32_t)rec[0] | (uint32_t)rec[1] << 8 | (uint32_t)rec[2] << 16 |
                     (uint32_t)rec[3] << 24;
    unsigned n = rec[4];
    if (magic != CHIP_ID_MAGIC || n == 0 || n > CHIP_ID_MAX_SERIAL || n > max)
        return 0;
    for (unsigned k = 0; k < n; k++) {
        uint8_t c = rec[5 + k];
        if (!((c >= '0' && c <= '9') || (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') ||
              c == '-' || c == '_' || c == '.'))
            return 0;
        out[k] = (char)c;
    }
    return n;
}
