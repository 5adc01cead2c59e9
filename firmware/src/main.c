/* Entry point: boot the board, then serve the framed protocol on the UART forever. */
#include "hal.h"
#include "ops.h"
#include "proto.h"
#include "snan_constants.h"

/* the hash of the constants header this ELF was built with: the emulator compares it with the
 * Python definitions on load and refuses a stale ELF (kept by the linker script) */
__attribute__((section(".snan_constants"), used))
const char snan_constants_hash[] = CONSTANTS_HASH;

int main(void)
{
    hal_init();
    ops_boot();
    proto_boot();
    for (;;) {
        int c = hal_uart_getc();
        if (c >= 0)
            proto_rx_byte((uint8_t)c);
        else
            hal_watchdog_kick();        /* idle: between host bytes (long operations kick
                                         * the watchdog themselves) */
    }
}
