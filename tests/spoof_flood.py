"""UDP datagrams from spoofed loopback source addresses, for the red-team tests.

    python -m tests.spoof_flood --target 127.0.0.1:7450 --count 100000 [--swarm alpha] [--seed 1]

Every datagram comes from a different source address in 127.0.0.0/8 (127.1.0.0 upwards)
and a random port, as an attacker forging source addresses would send them; nothing leaves
the loopback interface. With CAP_NET_RAW the datagrams are built by hand (IPv4 + UDP header,
a raw socket, about 200 k/s from one core); without it each one is sent from a socket bound
to its source address, which Linux allows for any 127.x.y.z (slower, same effect).

Half of the datagrams carry a well-formed discovery header for ``--swarm`` with a random
MAC (the server has to compute the HMAC to reject them), the rest random bytes. Prints
``SENT <n> <raw|bound>`` and exits 0.
"""

from __future__ import annotations

import argparse
import ipaddress
import os
import random
import socket
import struct
import sys
import time


def spoofed_source(i: int) -> str:
    """The i-th source address: 127.1.0.0 + i, never 127.0.0.x (where the real nodes live)."""
    return str(ipaddress.IPv4Address((127 << 24) + (1 << 16) + i % ((1 << 24) - (1 << 16))))


def payloads(n: int, swarm: str, rng: random.Random) -> list[bytes]:
    sw = swarm.encode()
    head = b"MRSD" + bytes((1, 6, len(sw))) + sw  # version 1, QUERY
    out = []
    for i in range(n):
        if i % 2 == 0:
            ts = struct.pack(">Q", int(time.time() * 1e6))
            out.append(head + ts + rng.randbytes(8) + b"\x91\x07" + rng.randbytes(32))
        else:
            out.append(rng.randbytes(rng.randrange(8, 200)))
    return out


def udp_packet(src: str, sport: int, dst: str, dport: int, data: bytes) -> bytes:
    """IPv4 + UDP header by hand (the kernel fills in the IP checksum; UDP checksum 0 = none)."""
    ulen = 8 + len(data)
    ip = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + ulen, 0, 0, 64, socket.IPPROTO_UDP, 0,
                     socket.inet_aton(src), socket.inet_aton(dst))
    return ip + struct.pack("!HHHH", sport, dport, ulen, 0) + data


def flood(target: tuple[str, int], count: int, swarm: str, seed: int = 1, first: int = 0) -> tuple[int, str]:
    rng = random.Random(seed)
    datas = payloads(min(count, 4096), swarm, rng)
    dst, dport = target
    sent = 0
    try:
        raw = socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW)
    except PermissionError:
        raw = None
    if raw is not None:
        with raw:
            for i in range(count):
                pkt = udp_packet(spoofed_source(first + i), 1024 + rng.randrange(60000), dst, dport, datas[i % len(datas)])
                try:
                    raw.sendto(pkt, (dst, 0))
                    sent += 1
                except (BlockingIOError, OSError):  # a full send buffer: drop, like any flood
                    pass
        return sent, "raw"
    for i in range(count):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind((spoofed_source(first + i), 0))
                s.sendto(datas[i % len(datas)], target)
                sent += 1
            except OSError:
                pass
    return sent, "bound"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.spoof_flood")
    ap.add_argument("--target", required=True, help="HOST:PORT on 127.0.0.0/8")
    ap.add_argument("--count", type=int, default=100_000)
    ap.add_argument("--swarm", default="alpha")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--first", type=int, default=0, help="index of the first source address")
    a = ap.parse_args(argv)
    host, _, port = a.target.rpartition(":")
    if not ipaddress.IPv4Address(host).is_loopback:
        ap.error("--target must be a loopback address: this tool never sends off the host")
    sent, mode = flood((host, int(port)), a.count, a.swarm, a.seed, a.first)
    print(f"SENT {sent} {mode}", flush=True)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    sys.exit(main())
