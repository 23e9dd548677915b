"""A module in under 150 lines, from docs/protocol.md alone: pyzmq and the standard library.

Sends ``--frames`` synthetic 8-bit PNG frames and a batch of sensor samples
to a ship, resends what is not acknowledged, stops on a refusal that
resending cannot help, says ``bye``. Run it against ``camcal ingest``, with
the keys folder holding ``ship.key`` and ``modules/X.key_secret`` (``camcal
keys create X`` on the ship makes them):

    python docs/examples/minimal_module.py tcp://127.0.0.1:5555 --module X --frames 5 --keys KEYS

Exit status 0 when every message was acknowledged. (A real module keeps
each message on its SD card until the ack; this sketch keeps them in memory.)
"""

import argparse
import hashlib
import json
import secrets
import struct
import sys
import time
import zlib
from datetime import UTC, datetime

import zmq
import zmq.auth


def png_gray8(width, height, value):
    """An 8-bit grayscale PNG, rows unfiltered, as the protocol recommends."""
    raw = b"".join(b"\x00" + bytes([value]) * width for _ in range(height))

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    idat = zlib.compress(raw, 1)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def sha(data):
    return hashlib.sha256(data).hexdigest()


def now():
    return datetime.now(UTC).isoformat().replace("+00:00", "Z")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("ship")
    ap.add_argument("--module", default="X")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--timeout", type=float, default=30.0)
    ap.add_argument("--keys", help="keys folder: ship.key, modules/<module>.key_secret (none: plaintext)")
    args = ap.parse_args()
    boot = datetime.now(UTC).strftime("%Y%m%dT%H%M%S") + "-min"
    sock = zmq.Context.instance().socket(zmq.DEALER)
    if args.keys:  # CURVE: the ship knows this module by its key
        sock.curve_serverkey, _ = zmq.auth.load_certificate(f"{args.keys}/ship.key")
        public, secret = zmq.auth.load_certificate(f"{args.keys}/modules/{args.module}.key_secret")
        sock.curve_publickey, sock.curve_secretkey = public, secret
    route = f"{args.module}/{secrets.token_hex(16)}"  # module id, '/', digits nobody can guess
    sock.setsockopt(zmq.ROUTING_ID, route.encode())
    sock.setsockopt(zmq.LINGER, 1000)
    sock.connect(args.ship)

    def send(header, payload=None):
        header = {"v": 1, "module": args.module, "sent_at": now(), "boot": boot, **header}
        frames = [json.dumps(header).encode()] + ([payload] if payload is not None else [])
        sock.send_multipart(frames)

    pending = {}  # seq -> (header, payload): everything not yet acknowledged
    for seq in range(1, args.frames + 1):
        img = png_gray8(64, 48, 10 * seq)
        meta = dict(captured_at=now(), camera=args.module, wavelength_nm=460, exposure_s=0.05, gain_db=6.0)
        meta |= dict(depth_m=3420.0, width_px=64, height_px=48, encoding="png", schedule_version=0)
        pending[seq] = (dict(type="frame", seq=seq, size=len(img), sha256=sha(img), **meta), img)
    rows = json.dumps([[time.time(), 4.0, 30.0, 0.0, 0.0, 9.81, 0.0, 0.0, 0.0, 3420.0]]).encode()
    columns = "t_unix_s temperature_c humidity_pct acc_x_m_s2 acc_y_m_s2 acc_z_m_s2 gyro_x_dps gyro_y_dps"
    columns = [*columns.split(), "gyro_z_dps", "depth_m"]
    n = args.frames + 1
    pending[n] = (
        dict(type="sensors", seq=n, columns=columns, count=1, size=len(rows), sha256=sha(rows)),
        rows,
    )
    refused = {}
    welcomed, window, in_flight = False, 1, {}
    last_hello = last_beat = last_ship = 0.0
    deadline = time.monotonic() + args.timeout
    while pending and time.monotonic() < deadline:
        t = time.monotonic()
        if welcomed and t - last_ship > 5.0:  # the link timeout: greet the ship again
            welcomed = False
        if not welcomed and t - last_hello >= 1.0:
            send({"type": "hello", "outbox_pending": len(pending), "last_seq": args.frames + 1})
            last_hello = t
        if t - last_beat >= 1.0:
            send(
                {
                    "type": "heartbeat",
                    "outbox_pending": len(pending),
                    "in_flight": len(in_flight),
                    "last_seq": args.frames + 1,
                }
            )
            last_beat = t
        for seq in [q for q, sent in in_flight.items() if t - sent > 15.0]:  # no answer: send again
            del in_flight[seq]
        for seq in sorted(pending):
            if welcomed and seq not in in_flight and len(in_flight) < window:
                send(*pending[seq])
                in_flight[seq] = t
        if not sock.poll(100):
            continue
        msg, last_ship = json.loads(sock.recv_multipart()[0]), time.monotonic()
        if msg["type"] == "welcome":
            welcomed, window, in_flight = True, msg["window"], {}
        elif msg["type"] in ("ack", "ship_heartbeat"):
            window = msg["window"]
            for b, first, last in msg.get("ranges", []):
                for seq in [q for q in pending if b == boot and first <= q <= last]:
                    pending.pop(seq)
                    in_flight.pop(seq, None)
        elif msg["type"] == "nack":
            seq = msg.get("seq")
            print(f"nack: {msg['reason']} ({msg.get('detail')})", file=sys.stderr)
            if seq in pending and not msg["retry"]:
                refused[seq] = msg["reason"]
                pending.pop(seq)
            in_flight.pop(seq, None)
    send({"type": "bye"})
    sock.close()
    print(json.dumps({"unacknowledged": sorted(pending), "refused": refused}))
    return 0 if not pending and not refused else 1


if __name__ == "__main__":
    sys.exit(main())
