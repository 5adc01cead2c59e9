/* Entry point: boot the board, then serve the framed protocol on the UART forever. */
#include "hal.h"
#include "ops.h"
#include "proto.h"

int main(void)
{
    hal_init();
    ops_boot();
    proto_boot();
    for (;;) {
        int c = hal_uart_getc();
        if (c >= 0)
            proto_rx_byte((uint8_t)c);
        hal_watchdog_kick();
    }
}
