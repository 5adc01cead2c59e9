/* Board side of the framed protocol (docs/protocol.md sections 2-5): COBS framing,
 * CRC-16/CCITT-FALSE, checks in the documented order, the reply cache, the messages. */
#ifndef PROTO_H
#define PROTO_H
#include <stdint.h>

void proto_boot(void);          /* new boot nonce, counters and cache cleared */
void proto_rx_byte(uint8_t b);  /* feed one received UART byte */
uint16_t crc16_ccitt_false(const uint8_t *p, unsigned n);

#endif
