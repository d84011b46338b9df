"""A Zenoh router used as gossip rendezvous (and, for client-mode nodes, as data router).

Peers connect to it, learn each other's locators from its gossip and then mesh directly;
the router is not on their data path and may die without interrupting them (research note
zenoh.md §1.2, run B6). Client-mode nodes (UAVs behind carrier NAT) route all data
through it instead.

Run: ``python -m discovery.rendezvous --listen tcp/127.0.0.1:7447`` (or ``mrswarm router``).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from typing import Any

import zenoh

from swarmnet.connectivity import TransportTuning


def router_config(listen: list[str], tuning: TransportTuning | None = None) -> dict[str, Any]:
    cfg: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": listen},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True, "multihop": False}},
    }
    return (tuning or TransportTuning()).apply(cfg)


def serve(listen: list[str], stop: threading.Event, duration: float | None = None) -> None:
    session = zenoh.open(zenoh.Config.from_json5(json.dumps(router_config(listen))))
    try:
        print(f"rendezvous router {session.info.zid()} listening on {', '.join(listen)}", flush=True)
        stop.wait(duration)
    finally:
        session.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mrswarm router", description=__doc__.splitlines()[0])
    ap.add_argument("--listen", action="append", default=None, help="Zenoh endpoint, e.g. tcp/127.0.0.1:7447 (repeatable)")
    ap.add_argument("--duration", type=float, default=None, help="exit after this many seconds")
    args = ap.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    serve(args.listen or ["tcp/127.0.0.1:7447"], stop, args.duration)
    return 0


if __name__ == "__main__":
    sys.exit(main())
