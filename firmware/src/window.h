/* DECISION_WINDOW (docs/protocol.md, "0x0A DECISION_WINDOW"): one decision window on the
 * board - the input spikes drawn from the host's stream state, the synapses read per spike,
 * the candidates' LIF motor neurons integrated in fixed point. Portable: uses hal.h and the
 * counters / checks of ops.h. The Python model is firmware_emu/decision_window.py. */
#ifndef WINDOW_H
#define WINDOW_H
#include <stdint.h>

void window_clear(void);                               /* forget the parameter block */
int window_malformed(const uint8_t *p, unsigned n);     /* 1: the payload does not decode */
/* Check and run the request p[0..n) (well formed); the reply payload goes to out, its length
 * to *len. Returns 0, or the ERROR code of a refusal (ops_refusal holds detail and text). */
int window_run(const uint8_t *p, unsigned n, uint8_t *out, unsigned *len);

#endif
