"""A Zenoh router used as gossip rendezvous (and, for client-mode nodes, as data router).

Peers connect to it, learn each other's locators from its gossip and then mesh directly;
the router is not on their data path and may die without interrupting them: Zenoh's gossip
only hands each new link the locators it knows, over links that already exist (upstream
source: ``zenoh/src/net/protocol/gossip.rs``). Client-mode nodes (UAVs behind carrier NAT)
route all data through it instead.

With ``--feed SWARM`` it also runs the edge pose feed for that swarm (swarmnet/feed.py):
one batch of every UAV's latest pose per period instead of a message per neighbour.

Run: ``python -m discovery.rendezvous --listen tcp/127.0.0.1:7447 [--feed alpha]`` (or ``mrswarm router``).
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from typing import Any

import zenoh

from swarmnet.connectivity import TransportTuning
from swarmnet.feed import DEFAULT_PERIOD, PoseFeed


def router_config(listen: list[str], tuning: TransportTuning | None = None) -> dict[str, Any]:
    cfg: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": listen},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True, "multihop": False}},
    }
    return (tuning or TransportTuning()).apply(cfg)


def serve(listen: list[str], stop: threading.Event, duration: float | None = None,
          feed_swarms: list[str] | None = None, feed_period: float = DEFAULT_PERIOD) -> None:
    session = zenoh.open(zenoh.Config.from_json5(json.dumps(router_config(listen))))
    try:
        print(f"rendezvous router {session.info.zid()} listening on {', '.join(listen)}"
              + (f", pose feed for {', '.join(feed_swarms)} every {feed_period * 1000:.0f} ms" if feed_swarms else ""),
              flush=True)
        if not feed_swarms:
            stop.wait(duration)
            return
        feed = PoseFeed(session, feed_swarms, feed_period)
        end = time.monotonic() + duration if duration is not None else float("inf")
        while not stop.is_set() and time.monotonic() < end:
            nxt = feed.step()
            stop.wait(max(0.0, min(nxt - time.time(), end - time.monotonic())))
    finally:
        session.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mrswarm router", description=__doc__.splitlines()[0])
    ap.add_argument("--listen", action="append", default=None, help="Zenoh endpoint, e.g. tcp/127.0.0.1:7447 (repeatable)")
    ap.add_argument("--feed", action="append", default=[], metavar="SWARM",
                    help="run the edge pose feed for this swarm ('*' for all; repeatable)")
    ap.add_argument("--feed-period", type=float, default=DEFAULT_PERIOD, help="seconds between pose batches")
    ap.add_argument("--duration", type=float, default=None, help="exit after this many seconds")
    args = ap.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    serve(args.listen or ["tcp/127.0.0.1:7447"], stop, args.duration, args.feed, args.feed_period)
    return 0


if __name__ == "__main__":
    sys.exit(main())
