"""A Zenoh router used as gossip rendezvous (and, for client-mode nodes, as data router).

Peers connect to it, learn each other's locators from its gossip and then mesh directly;
the router is not on their data path and may die without interrupting them: Zenoh's gossip
only hands each new link the locators it knows, over links that already exist (upstream
source: ``zenoh/src/net/protocol/gossip.rs``). Client-mode nodes (UAVs behind carrier NAT)
route all data through it instead.

With ``--feed SWARM`` it also runs the edge pose feed for that swarm (swarmnet/feed.py):
the poses that arrive within a short window (``--feed-window-ms``, 3 ms by default; 0 forwards
at once) leave as one batch, instead of a message per neighbour. With spatial interest
(``--interest-radius-m``), ``--pool pool-<n>=<ids>`` names the UAVs a pool of virtual UAVs hosts
(repeatable; the runner gives its layout): each pool gets one near batch for all of them.

With ``--keys DIR`` (the swarm's key directory, or the router's bundle of it) every link is
mutual TLS and the router enforces the swarm's access control on what enters and what leaves
it (docs/security.md), as ``edge.<swarm>``. It counts the handshakes its listener refused and
the links of certificates outside the roster, and ``--stats FILE`` writes those counters.

Run: ``python -m discovery.rendezvous --listen tcp/127.0.0.1:7447 [--feed alpha] [--keys keys/alpha]``
(or ``mrswarm router``). ``--connect tls/<other router>:7447`` links it to another edge router
(one edge per server, docs/deploy.md).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import zenoh

from groundfloor.files import write_json_atomic
from groundfloor.process import say, stop_event
from groundfloor.schema import ConfigError, convert
from swarmnet.connectivity import TransportTuning, secured
from swarmnet.feed import DEFAULT_WINDOW, PoseFeed
from swarmnet.interest import Interest, PoolMembers, pool_groups
from swarmnet.security.credentials import Credentials
from swarmnet.stats import NodeStats

TICK = 0.2  # s between two looks at the link events and the stats file when no feed runs
STATS_PERIOD = 1.0  # s between two writes of --stats


def router_config(listen: list[str], tuning: TransportTuning | None = None,
                  credentials: Credentials | None = None, connect: list[str] | None = None) -> dict[str, Any]:
    """``connect``: other edge routers this one links to (router to router, e.g. one edge per server)."""
    cfg: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": listen},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True, "multihop": False}},
    }
    if connect:
        cfg["connect"] = {"endpoints": connect}
    return secured((tuning or TransportTuning()).apply(cfg), credentials)


def router_credentials(keys: str, identity: str | None = None) -> Credentials:
    """The router's credentials in key directory ``keys``: ``edge.<swarm>`` unless named."""
    if identity:
        return Credentials(keys=keys, identity=identity)
    from swarmnet.security.roster import Roster

    return Credentials(keys=keys, identity=f"edge.{Roster.load(keys).swarm}")


class StatsFile:
    """``--stats FILE``, replaced atomically every second. A write the disk refuses (full, read-only) is counted
    (``unwritten``, in the next write that succeeds) and logged once a minute; the router never stops for it."""

    def __init__(self, path: Path):
        self.path = path
        self.unwritten = 0
        self._warned = -math.inf

    def write(self, stats: NodeStats, feed: PoseFeed | None) -> bool:
        out: dict[str, Any] = {"refused": dict(stats.refused)}
        if feed is not None:
            out["feed"] = {"received": dict(feed.stats.received), "rejected": dict(feed.stats.rejected),
                           "sent": dict(feed.stats.sent)}
        if self.unwritten:
            out["unwritten"] = self.unwritten
        try:
            write_json_atomic(self.path, out)
            return True
        except OSError as exc:
            self.unwritten += 1
            if time.monotonic() - self._warned >= 60.0:
                self._warned = time.monotonic()
                say(f"warning: cannot write {self.path} ({exc.strerror or exc}); the router goes on, counting it")
            return False


def serve(listen: list[str], stop: threading.Event, duration: float | None = None,
          feed_swarms: list[str] | None = None, feed_window: float = DEFAULT_WINDOW,
          credentials: Credentials | None = None, stats: NodeStats | None = None, stats_file: Path | None = None,
          interest: Interest | None = None, connect: list[str] | None = None,
          pools: Sequence[PoolMembers] = ()) -> None:
    """Run the router until ``stop`` is set (or ``duration`` s); ``stats`` receives its refusals."""
    stats = stats if stats is not None else NodeStats()
    session = zenoh.open(zenoh.Config.from_json5(json.dumps(router_config(listen, credentials=credentials, connect=connect))))
    links = None
    feed = None
    try:
        shown = [e.replace("tcp/", "tls/", 1) if credentials else e for e in listen]
        say(f"rendezvous router {session.info.zid()} listening on {', '.join(shown)}"
              + (f" as {credentials.identity} (mutual TLS, access control)" if credentials else " (plain TCP, no access control)")
              + (f", pose feed for {', '.join(feed_swarms)} (window {feed_window * 1000:g} ms)" if feed_swarms else "")
              + (f", interest radius {interest.radius_m:g} m (+{interest.margin_m:g}), far {interest.far_rate_hz:g} Hz"
                 if feed_swarms and interest else "")
              + (f", {len(pools)} pools of virtual UAVs ({sum(len(p.uavs) for p in pools)} UAVs)" if pools else ""))
        if credentials is not None:
            from swarmnet.security.acl import member_names
            from swarmnet.security.links import LinkWatch

            links = LinkWatch(session, member_names(credentials.roster()), stats)
        # the feed runs in threads of its own (swarmnet/feed.py); this loop only watches
        feed = PoseFeed(session, feed_swarms, feed_window, interest=interest, pools=pools).start() if feed_swarms else None
        end = time.monotonic() + duration if duration is not None else float("inf")
        next_stats = 0.0
        out = StatsFile(stats_file) if stats_file is not None else None
        while not stop.is_set() and time.monotonic() < end:
            if links is not None:
                links.poll()
            if out is not None and time.monotonic() >= next_stats:
                out.write(stats, feed)
                next_stats = time.monotonic() + STATS_PERIOD
            stop.wait(max(0.0, min(TICK, end - time.monotonic())))
        if out is not None:
            if links is not None:
                links.poll()
            out.write(stats, feed)
    finally:
        if feed is not None:
            feed.close()
        if links is not None:
            links.close()
        session.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mrswarm router", description=__doc__.splitlines()[0])
    ap.add_argument("--listen", action="append", default=None, help="Zenoh endpoint, e.g. tcp/127.0.0.1:7447 (repeatable)")
    ap.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                    help="another edge router to link to, e.g. tls/router:7447 (repeatable; one edge per server)")
    ap.add_argument("--feed", action="append", default=[], metavar="SWARM",
                    help="run the edge pose feed for this swarm ('*' for all; repeatable)")
    ap.add_argument("--feed-window-ms", type=float, default=DEFAULT_WINDOW * 1000.0,
                    help="a pose waits at most this long for others to share its batch (0: forward at once)")
    ap.add_argument("--interest-radius-m", type=float, default=None, metavar="M",
                    help="spatial interest (docs/scale.md): each UAV gets full-rate poses only from UAVs this close")
    ap.add_argument("--interest-margin-m", type=float, default=5.0, metavar="M",
                    help="with --interest-radius-m: a neighbour stays at full rate until this much farther")
    ap.add_argument("--interest-far-hz", type=float, default=1.0, metavar="HZ",
                    help="with --interest-radius-m: every UAV's pose to the whole swarm at this rate (0: never)")
    ap.add_argument("--pool", action="append", default=[], metavar="pool-N=IDS",
                    help="with --interest-radius-m: the UAVs pool N hosts (e.g. pool-1=1-50,52), sent one near batch "
                         "for all of them on feed/near/pool-N (repeatable)")
    ap.add_argument("--keys", default=None, metavar="DIR",
                    help="the swarm's key directory (mrswarm keys init), or the router's bundle: mutual TLS and access control")
    ap.add_argument("--identity", default=None, help="certificate to speak as (default: edge.<swarm of --keys>)")
    ap.add_argument("--insecure", action="store_true", help="plain TCP without access control (labs only; says so at start)")
    ap.add_argument("--stats", default=None, metavar="FILE",
                    help="write the router's counters (refusals, feed) here every second")
    ap.add_argument("--duration", type=float, default=None, help="exit after this many seconds")
    args = ap.parse_args(argv)
    if not args.keys and not args.insecure:
        ap.error("give the swarm's keys (--keys DIR, see `mrswarm keys`), or --insecure for plain TCP")
    if not 0.0 <= args.feed_window_ms <= 1000.0:
        ap.error("--feed-window-ms must be in 0..1000")
    interest = None
    if args.interest_radius_m is not None:
        try:
            interest = convert({"radius_m": args.interest_radius_m, "margin_m": args.interest_margin_m,
                                "far_rate_hz": args.interest_far_hz}, Interest)
        except ConfigError as exc:
            ap.error(f"--interest: {exc}")
        if not args.feed:
            ap.error("--interest-radius-m filters the pose feed: give --feed SWARM too")
    pools: list[PoolMembers] = []
    if args.pool:
        if interest is None:
            ap.error("--pool groups the near feed of spatial interest: give --interest-radius-m too")
        try:
            pools = [PoolMembers.parse(text) for text in args.pool]
            pool_groups(pools)
        except ConfigError as exc:
            ap.error(f"--pool: {exc}")
    stop = stop_event()
    stats = NodeStats()
    credentials = None
    if args.keys:
        try:
            credentials = router_credentials(args.keys, args.identity)
            credentials.files()
        except ConfigError as exc:
            ap.error(f"--keys: {exc.msg}")
        from swarmnet.security.zenoh_log import ZenohLogTap

        ZenohLogTap(stats)  # counts the handshakes the listener refuses
    else:
        print("WARNING: plain TCP without access control: anyone who reaches this router can command the swarm "
              "(docs/security.md)", file=sys.stderr, flush=True)
    serve(args.listen or ["tcp/127.0.0.1:7447"], stop, args.duration, args.feed, args.feed_window_ms / 1000.0, credentials,
          stats, Path(args.stats) if args.stats else None, interest, args.connect, pools)
    return 0


if __name__ == "__main__":
    sys.exit(main())
