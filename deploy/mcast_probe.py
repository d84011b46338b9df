"""Probe whether multicast works on a container network (used by the tests and `mrswarm deploy`).

Run inside containers on the network under test, with a bounded duration:

* ``python3 -m deploy.mcast_probe listen --seconds 8`` joins Zenoh's scouting group
  224.0.0.224 on port 7446, also accepts broadcast and unicast datagrams on that port, and
  prints one JSON line: how many datagrams of each kind it received;
* ``python3 -m deploy.mcast_probe send --to IP --seconds 6`` sends, every 100 ms, one
  datagram to the group, one to the subnet's broadcast address and one unicast to ``IP`` (the control);
* ``python3 -m deploy.mcast_probe zenoh --seconds 8`` opens a Zenoh peer session with
  **multicast scouting enabled** and no endpoint to connect to, publishes its name and prints
  which other probes it heard: the only way they can meet is multicast scouting.
"""

from __future__ import annotations

import argparse
import json
import socket
import struct
import sys
import time

GROUP, PORT = "224.0.0.224", 7446
SIOCGIFNETMASK = 0x891B


def own_address(ifname: str = "eth0") -> tuple[str, str]:
    """This container's IPv4 address and its subnet's broadcast address (no default route
    on an internal network, so every datagram names its interface)."""
    import fcntl

    ip = socket.gethostbyname(socket.gethostname())
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        req = struct.pack("256s", ifname.encode())
        mask = socket.inet_ntoa(fcntl.ioctl(s.fileno(), SIOCGIFNETMASK, req)[20:24])
    a, m = struct.unpack("!I", socket.inet_aton(ip))[0], struct.unpack("!I", socket.inet_aton(mask))[0]
    return ip, socket.inet_ntoa(struct.pack("!I", (a & m) | (~m & 0xFFFFFFFF)))


def listen(seconds: float) -> dict[str, int]:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(("", PORT))
    ip, _ = own_address()
    s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, struct.pack("4s4s", socket.inet_aton(GROUP), socket.inet_aton(ip)))
    counts = {"multicast": 0, "broadcast": 0, "unicast": 0}
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        s.settimeout(left)
        try:
            data, _ = s.recvfrom(256)
        except TimeoutError:
            break
        kind = data.decode(errors="replace").split(":", 1)[0]
        if kind in counts:
            counts[kind] += 1
    return counts


def send(to: str, seconds: float) -> dict[str, int]:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    ip, bcast = own_address()
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(ip))
    sent = {"multicast": 0, "broadcast": 0, "unicast": 0}
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for kind, addr in (("multicast", GROUP), ("broadcast", bcast), ("unicast", to)):
            try:
                s.sendto(f"{kind}:probe".encode(), (addr, PORT))
                sent[kind] += 1
            except OSError:
                pass  # e.g. EPERM when a rule drops it on the way out: not sent
        time.sleep(0.1)
    return sent


def zenoh_probe(name: str, seconds: float) -> dict[str, object]:
    import zenoh

    cfg = {
        "mode": "peer",
        "scouting": {"multicast": {"enabled": True, "interface": "auto"}, "gossip": {"enabled": True}},
        "connect": {"endpoints": []},
        "listen": {"endpoints": ["tcp/0.0.0.0:7447"]},
    }
    heard: set[str] = set()
    with zenoh.open(zenoh.Config.from_json5(json.dumps(cfg))) as session:
        sub = session.declare_subscriber("mcast_probe/*", zenoh.handlers.RingChannel(64))
        pub = session.declare_publisher(f"mcast_probe/{name}")
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            pub.put(name)
            while (s := sub.try_recv()) is not None:
                who = s.payload.to_string()
                if who != name:
                    heard.add(who)
            time.sleep(0.2)
        peers = [str(z) for z in session.info.peers_zid()]
    return {"name": name, "heard": sorted(heard), "peers": len(peers)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python3 -m deploy.mcast_probe")
    ap.add_argument("what", choices=["listen", "send", "zenoh"])
    ap.add_argument("--to", default="127.0.0.1", help="unicast control target (send)")
    ap.add_argument("--name", default=socket.gethostname())
    ap.add_argument("--seconds", type=float, default=6.0)
    args = ap.parse_args(argv)
    secs = min(max(args.seconds, 0.5), 60.0)
    if args.what == "listen":
        out: dict[str, object] = dict(listen(secs))
    elif args.what == "send":
        out = dict(send(args.to, secs))
    else:
        out = zenoh_probe(args.name, secs)
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
