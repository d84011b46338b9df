"""A Zenoh router used as gossip rendezvous (and, for client-mode nodes, as data router).

Peers connect to it, learn each other's locators from its gossip and then mesh directly;
the router is not on their data path and may die without interrupting them: Zenoh's gossip
only hands each new link the locators it knows, over links that already exist (upstream
source: ``zenoh/src/net/protocol/gossip.rs``). Client-mode nodes (UAVs behind carrier NAT)
route all data through it instead.

With ``--feed SWARM`` it also runs the edge pose feed for that swarm (swarmnet/feed.py):
the poses that arrive within a short window (``--feed-window-ms``, 3 ms by default; 0 forwards
at once) leave as one batch, instead of a message per neighbour.

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
from swarmnet.feed import DEFAULT_WINDOW, PoseFeed


def router_config(listen: list[str], tuning: TransportTuning | None = None) -> dict[str, Any]:
    cfg: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": listen},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True, "multihop": False}},
    }
    return (tuning or TransportTuning()).apply(cfg)


def serve(listen: list[str], stop: threading.Event, duration: float | None = None,
          feed_swarms: list[str] | None = None, feed_window: float = DEFAULT_WINDOW) -> None:
    session = zenoh.open(zenoh.Config.from_json5(json.dumps(router_config(listen))))
    try:
        print(f"rendezvous router {session.info.zid()} listening on {', '.join(listen)}"
              + (f", pose feed for {', '.join(feed_swarms)} (window {feed_window * 1000:g} ms)" if feed_swarms else ""),
              flush=True)
        if not feed_swarms:
            stop.wait(duration)
            return
        feed = PoseFeed(session, feed_swarms, feed_window)
        end = time.monotonic() + duration if duration is not None else float("inf")
        try:
            feed.run(lambda: not stop.wait(0.2) and time.monotonic() < end, check_every=0.0)
        finally:
            feed.close()
    finally:
        session.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mrswarm router", description=__doc__.splitlines()[0])
    ap.add_argument("--listen", action="append", default=None, help="Zenoh endpoint, e.g. tcp/127.0.0.1:7447 (repeatable)")
    ap.add_argument("--feed", action="append", default=[], metavar="SWARM",
                    help="run the edge pose feed for this swarm ('*' for all; repeatable)")
    ap.add_argument("--feed-window-ms", type=float, default=DEFAULT_WINDOW * 1000.0,
                    help="a pose waits at most this long for others to share its batch (0: forward at once)")
    ap.add_argument("--duration", type=float, default=None, help="exit after this many seconds")
    args = ap.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    if not 0.0 <= args.feed_window_ms <= 1000.0:
        ap.error("--feed-window-ms must be in 0..1000")
    serve(args.listen or ["tcp/127.0.0.1:7447"], stop, args.duration, args.feed, args.feed_window_ms / 1000.0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
