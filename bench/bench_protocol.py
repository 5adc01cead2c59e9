"""Protocol benchmark: frame codec speed and request round trips over a paced pty.

Usage: ``python bench/bench_protocol.py [--quick]``

1. Frames per second, encode (message -> wire bytes) + decode (stream decoder -> message), for a
   READ_CELL request and a SPIKE_BATCH reply of one decision window (150 spikes x 8 columns).
2. Request round trips per second over a real pseudo-terminal at 115200 and 921600 baud: the
   host uses pyserial on the slave end; the board side (a DeviceEndpoint with a handler that
   returns a precomputed reply, so only the protocol is measured) reads and writes the master end
   through a PacedTransport that releases bytes at the line rate (10 bits per byte). A pty alone
   has no baud rate; the pacing makes the numbers comparable to a UART. Each round trip is
   compared with the wire limit: 1 / ((request bytes + reply bytes) * 10 / baud).
   Target: >= 80 % of the wire limit for SPIKE_BATCH-sized payloads.
"""

from __future__ import annotations

import argparse
import random
import sys
import time

from snan_hil.protocol import messages as m
from snan_hil.protocol.board import MEMRICORE
from snan_hil.protocol.device import DeviceEndpoint, DeviceServer
from snan_hil.protocol.frames import Frame, FrameDecoder, encode_frame
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.transport import (BITS_PER_BYTE, CallbackTransport, PacedTransport,
                                         SerialTransport, open_pty_pair)

TARGET_RATIO = 0.80


def window(seed: int = 0, p: float = 0.15, n_bins: int = 1000, rows: int = 15,
           cols: int = 8) -> tuple[m.SpikeBatch, m.SpikeBatchReply]:
    """One decision window: 15 rows driven at the read code (<= 0.3 V), spikes with
    probability p per 1 ms bin."""
    rng = random.Random(seed)
    bins = tuple(b for b in range(n_bins) if rng.random() < p)
    req = m.SpikeBatch((m.SpikeGroup(tuple((r, MEMRICORE.read_code) for r in range(rows)), bins),),
                       tuple(range(cols)), n_bins, 1000)
    reply = m.SpikeBatchReply(0, cols, tuple(tuple(rng.randrange(16384) for _ in range(cols))
                                             for _ in bins))
    return req, reply


def codec_rate(msg: m.Message, seconds: float) -> tuple[float, int]:
    """Encode+decode frames/s and wire bytes of one frame."""
    dec = FrameDecoder()
    n, t0 = 0, time.perf_counter()
    wire = b""
    while time.perf_counter() - t0 < seconds:
        for _ in range(20):
            wire = encode_frame(Frame.of(msg, n & 0xFFFF, 1))
            (frame,) = dec.feed(wire)
            assert frame.message() == msg
            n += 1
    return n / (time.perf_counter() - t0), len(wire)


class Canned:
    """Handler answering each request type with a fixed reply (protocol cost only)."""

    def __init__(self, spike_reply: m.SpikeBatchReply):
        self.spike_reply = spike_reply

    def __call__(self, req: m.Request) -> m.Reply:
        if isinstance(req, m.Hello):
            return m.Info(board_id="bench", firmware_version="bench")
        if isinstance(req, m.SpikeBatch):
            return self.spike_reply
        if isinstance(req, m.ReadCell):
            return m.ReadCellReply(1234)
        raise AssertionError(type(req))


def round_trips(req: m.Request, reply: m.Reply, baud: int | None, n: int) -> dict:
    """Measure ``n`` round trips of ``req``; baud None = synchronous in-process transport."""
    handler = Canned(reply if isinstance(reply, m.SpikeBatchReply) else window()[1])
    endpoint = DeviceEndpoint(handler, boot_nonce=7)
    req_bytes = len(encode_frame(Frame.of(req, 1, 7)))
    rep_bytes = len(encode_frame(Frame.of(reply, 1, 7)))
    if baud is None:
        client = LinkClient(CallbackTransport(endpoint.feed), timeout=1.0)
        server = pair = None
    else:
        pair = open_pty_pair()
        server = DeviceServer(endpoint, PacedTransport(pair.master, baud), poll_s=0.01)
        client = LinkClient(SerialTransport(pair.slave_path, baud), timeout=1.0)
    try:
        client.hello()
        client.request(req)  # warm up
        t0 = time.perf_counter()
        for _ in range(n):
            client.request(req)
        elapsed = time.perf_counter() - t0
        retries = client.counters.retries
    finally:
        client.close()
        if server is not None:
            server.stop(close_transport=False)
            pair.close()
    rate = n / elapsed
    limit = baud / (BITS_PER_BYTE * (req_bytes + rep_bytes)) if baud else None
    return {"rate": rate, "limit": limit, "bytes": req_bytes + rep_bytes, "retries": retries}


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = parser.parse_args(argv)
    quick = args.quick
    spike_req, spike_reply = window()
    small = m.ReadCell(3, 4, MEMRICORE.read_code)

    print("Frame codec (encode + stream-decode + message decode), one core")
    print(f"{'frame':34s} {'wire B':>7s} {'frames/s':>10s} {'MB/s':>7s} "
          f"{'wire frames/s @921600':>22s}  target")
    for name, msg in (("READ_CELL request", small),
                      (f"SPIKE_BATCH reply ({len(spike_reply.codes)}x8)", spike_reply),
                      ("SPIKE_BATCH request (1000 bins)", spike_req)):
        rate, size = codec_rate(msg, 0.3 if quick else 1.0)
        wire_fps = 921600 / (BITS_PER_BYTE * size)
        ok = "ok" if rate >= 10 * wire_fps else "BELOW"
        print(f"{name:34s} {size:7d} {rate:10.0f} {rate * size / 1e6:7.2f} {wire_fps:22.0f}  "
              f">= 10x wire: {ok}")

    print()
    print("Round trips over a pty, board side paced at the baud rate (10 bits/byte)")
    print(f"{'request':28s} {'baud':>8s} {'B/rt':>6s} {'rt/s':>8s} {'wire rt/s':>10s} "
          f"{'ratio':>6s} {'retries':>7s}  target")
    status = 0
    cases = [("READ_CELL", small, m.ReadCellReply(1234)), ("SPIKE_BATCH", spike_req,
                                                          spike_reply)]
    for baud in (115200, 921600, None):
        for name, req, reply in cases:
            if baud == 115200:
                n = (3 if quick else 8) if name == "SPIKE_BATCH" else (20 if quick else 100)
            elif baud == 921600:
                n = (10 if quick else 40) if name == "SPIKE_BATCH" else (50 if quick else 300)
            else:
                n = 50 if quick else 300
            res = round_trips(req, reply, baud, n)
            if res["limit"]:
                ratio = res["rate"] / res["limit"]
                target = f">= {TARGET_RATIO:.0%}" if name == "SPIKE_BATCH" else "(latency-bound)"
                if name == "SPIKE_BATCH":
                    target += ": ok" if ratio >= TARGET_RATIO else ": BELOW"
                    status |= ratio < TARGET_RATIO
                print(f"{name:28s} {baud:8d} {res['bytes']:6d} {res['rate']:8.1f} "
                      f"{res['limit']:10.1f} {ratio:6.2f} {res['retries']:7d}  {target}")
            else:
                print(f"{name + ' (in-process)':28s} {'-':>8s} {res['bytes']:6d} "
                      f"{res['rate']:8.1f} {'-':>10s} {'-':>6s} {res['retries']:7d}  "
                      "(no line: protocol overhead only)")
    return 0 if not status else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
