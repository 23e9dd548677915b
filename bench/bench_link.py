"""What CURVE costs the module link: 5 MP frames DEALER -> ROUTER over tcp://127.0.0.1, plaintext vs CURVE.

Two processes (a module and the ship) send and acknowledge PNG-sized
payloads (1.5 MB, what a 5 MP frame of the T-REX cameras weighs) with 8 in
flight, as the ingest's window allows, first in plaintext (the floor), then
encrypted and authenticated with CURVE and a ZAP handler, in the same run.
Prints frames/s and MB/s of both and their ratio.

    python bench/bench_link.py [--frames 300]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import threading
import time
from typing import Any

import zmq

PAYLOAD = 1_500_000
WINDOW = 8


def _zap(ctx: zmq.Context[Any], stop: threading.Event) -> None:
    sock = ctx.socket(zmq.ROUTER)
    sock.bind("inproc://zeromq.zap.01")
    while not stop.is_set():
        if sock.poll(50):
            req = sock.recv_multipart()
            sock.send_multipart([req[0], b"", b"1.0", req[3], b"200", b"OK", b"bench", b""])
    sock.close(0)


def _module(endpoint: str, n: int, keys: tuple[bytes, bytes, bytes] | None) -> None:
    ctx = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    if keys is not None:
        sock.curve_serverkey, sock.curve_publickey, sock.curve_secretkey = keys
    sock.connect(endpoint)
    data = os.urandom(PAYLOAD)
    in_flight = 0
    for _ in range(n):
        while in_flight >= WINDOW:
            sock.recv()
            in_flight -= 1
        sock.send_multipart([b'{"type":"frame"}', data])
        in_flight += 1
    for _ in range(in_flight):
        sock.recv()
    sock.close(0)
    ctx.term()


def run(n: int, curve: bool) -> float:
    """Seconds for ``n`` payloads sent and acknowledged."""
    ctx = zmq.Context()
    stop = threading.Event()
    keys = None
    zap = None
    if curve:
        zap = threading.Thread(target=_zap, args=(ctx, stop), daemon=True)
        zap.start()
        time.sleep(0.1)
    router = ctx.socket(zmq.ROUTER)
    if curve:
        server_public, server_secret = zmq.curve_keypair()
        client_public, client_secret = zmq.curve_keypair()
        router.curve_server = True
        router.curve_publickey, router.curve_secretkey = server_public, server_secret
        router.zap_domain = b"camcal"
        keys = (server_public, client_public, client_secret)
    router.bind("tcp://127.0.0.1:*")
    endpoint = router.getsockopt(zmq.LAST_ENDPOINT).decode()
    proc = multiprocessing.get_context("spawn").Process(target=_module, args=(endpoint, n, keys))
    proc.start()
    t0 = None
    for _ in range(n):
        ident, _header, _payload = router.recv_multipart(copy=False)
        t0 = t0 or time.perf_counter()
        router.send_multipart([ident.bytes, b'{"type":"ack"}'])
    elapsed = time.perf_counter() - (t0 or time.perf_counter())
    proc.join(30)
    router.close(0)
    stop.set()
    if zap is not None:
        zap.join(2)
    ctx.term()
    return elapsed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    plain, curve = [], []
    for _ in range(args.repeats):  # alternated, so that both see the same machine
        plain.append(run(args.frames, False))
        curve.append(run(args.frames, True))
    fp, fc = args.frames / min(plain), args.frames / min(curve)
    mb = PAYLOAD / 1e6
    print(f"| link | frames/s | MB/s |  (1.5 MB payloads, {WINDOW} in flight, best of {args.repeats})")
    print(f"| plaintext (floor) | {fp:.0f} | {fp * mb:.0f} |")
    print(f"| CURVE + ZAP | {fc:.0f} | {fc * mb:.0f} |")
    print(f"CURVE / plaintext: {fc / fp:.2f}x the frames/s; {1e3 / fc - 1e3 / fp:.2f} ms more per frame")


if __name__ == "__main__":
    main()
