"""The discovery server: a registry of nodes per swarm, fed and read over authenticated UDP.

Nodes' proxies beacon their Zenoh identity (ZID and locators) every period. The server
keeps each swarm's members, forgets a member not heard for ``ttl`` seconds, and tells every
member of a swarm about every other: a new or changed member is **pushed** to the others
at once; a beacon is answered with a tiny ACK when the sender's view is current, or with
a full snapshot when it is not. It holds no flight data and is not on the data path:
once the nodes have dialled each other it may die, and on restart it rebuilds its
registry from the next round of beacons.

Bad input never crashes it: every datagram is size-checked, rate-limited per source
address, authenticated (HMAC-SHA256 with the swarm's key) and replay-checked before its
body is decoded, and every drop is counted under a reason (``stats``). With a swarm's key
directory (``--identities``) a beacon or goodbye must also carry the node tag of the identity
it speaks for (discovery/identities.py): one member's credentials cannot list, replace or
remove another member.

Under a flood from spoofed source addresses the work per datagram stays bounded and
constant (:class:`SourceLimiter`): sources that never authenticated share a bounded table
whose oldest entry is dropped in O(1), and they can never evict, or drain, the rate-limit
state of sources that did. A beacon costs O(1) whatever the swarm's size (a running view
digest per swarm, members kept in the order they were last heard), so legitimate members
keep being heard and never expire because of junk.

Run: ``mrswarm discovery serve --listen <edge-address>:7450 --keys keys.txt``
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import selectors
import socket
import sys
import threading
import time
from collections import Counter, OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from discovery.identities import SwarmIdentities
from discovery.protocol import (
    BODY_BUDGET,
    DEFAULT_PERIOD,
    DEFAULT_PORT,
    DEFAULT_TTL,
    DEFAULT_WINDOW,
    MAX_DATAGRAM,
    MAX_ITEMS,
    Envelope,
    MsgType,
    NodeEntry,
    Peers,
    ProtocolError,
    RegisteredNode,
    ReplayGuard,
    check_key,
    chunk_entries,
    digest_of,
    entry_hash,
    packed_size,
    parse_beacon,
    parse_bye,
    parse_query,
    peers_body,
    seal,
    unseal,
)
from groundfloor.net import Addr
from groundfloor.process import die_with_parent, say, setup_logging, stop_event

log = logging.getLogger(__name__)

SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)  # Linux: a receive-queue drop counter with each datagram
_CMSG_SPACE = socket.CMSG_SPACE(4)


@dataclass
class Member:
    entry: NodeEntry
    addr: Addr
    first_seen: float
    last_seen: float
    last_ts: float  # sender timestamp of the newest accepted beacon (older ones are replays)
    h: int = 0  # entry_hash(entry): this member's share of the swarm's view digest

    def __post_init__(self) -> None:
        self.h = entry_hash(self.entry)


class Swarm:
    """One swarm's members, ordered by when they were last heard (oldest first), and the
    running sum of their entry hashes (the view digest of all of them)."""

    __slots__ = ("members", "total")

    def __init__(self) -> None:
        self.members: dict[tuple[str, int], Member] = {}
        self.total = 0

    def heard(self, m: Member) -> None:
        """Move ``m`` to the end (the most recently heard); O(1)."""
        k = m.entry.key
        self.members.pop(k, None)
        self.members[k] = m

    def add(self, m: Member) -> None:
        self.members[m.entry.key] = m
        self.total += m.h

    def update(self, m: Member, e: NodeEntry) -> None:
        self.total -= m.h
        m.entry = e
        m.h = entry_hash(e)
        self.total += m.h

    def pop(self, k: tuple[str, int]) -> Member | None:
        m = self.members.pop(k, None)
        if m is not None:
            self.total -= m.h
        return m

    def view_of(self, m: Member) -> bytes:
        """The digest of every member but ``m``: what ``m`` should hold."""
        return digest_of(self.total - m.h)

    def silent_since(self, cutoff: float) -> list[tuple[str, int]]:
        """Members last heard before ``cutoff``: a prefix of the order, so the scan stops at the first live one."""
        out = []
        for k, m in self.members.items():
            if m.last_seen >= cutoff:
                break
            out.append(k)
        return out


class TokenBucket:
    """Per-source rate limit: ``rate`` datagrams/s with bursts of ``burst``."""

    __slots__ = ("rate", "burst", "tokens", "t")

    def __init__(self, rate: float, burst: float, now: float):
        self.rate, self.burst, self.tokens, self.t = rate, burst, burst, now

    def take(self, now: float) -> bool:
        self.tokens = min(self.burst, self.tokens + (now - self.t) * self.rate)
        self.t = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


class SourceLimiter:
    """Per-source-address token buckets whose upkeep is O(1) per datagram, whatever the flood.

    Sources that have sent an authenticated datagram (``trusted``) and all the others
    (``strangers``) live in two bounded LRU tables. A stranger's bucket is charged before the
    datagram is authenticated (junk from one address costs little); a trusted source's bucket
    only for authenticated datagrams, so spoofing a member's address can neither drain its
    budget nor push its bucket out: a flood of spoofed sources only churns the strangers'
    table, one O(1) eviction per new address.
    """

    def __init__(self, rate: float, burst: float, max_strangers: int = 4096, max_trusted: int = 16384):
        self.rate, self.burst = rate, burst
        self.max_strangers, self.max_trusted = max_strangers, max_trusted
        self.strangers: OrderedDict[str, TokenBucket] = OrderedDict()
        self.trusted: OrderedDict[str, TokenBucket] = OrderedDict()
        self.evicted = 0  # stranger buckets dropped to make room

    def is_trusted(self, ip: str) -> bool:
        return ip in self.trusted

    def admit_unauthenticated(self, ip: str, now: float) -> bool:
        """Before authentication: may a datagram from this (untrusted) source be looked at?"""
        b = self.strangers.get(ip)
        if b is None:
            if len(self.strangers) >= self.max_strangers:
                self.strangers.popitem(last=False)
                self.evicted += 1
            b = self.strangers[ip] = TokenBucket(self.rate, self.burst, now)
        else:
            self.strangers.move_to_end(ip)
        return b.take(now)

    def admit_authenticated(self, ip: str, now: float) -> bool:
        """After authentication: charge the source's trusted bucket (made on its first authenticated datagram)."""
        b = self.trusted.get(ip)
        if b is None:
            b = self.strangers.pop(ip, None) or TokenBucket(self.rate, self.burst, now)
            if len(self.trusted) >= self.max_trusted:
                self.trusted.popitem(last=False)
            self.trusted[ip] = b
            return True  # already charged as a stranger
        self.trusted.move_to_end(ip)
        return b.take(now)

    def __len__(self) -> int:
        return len(self.strangers) + len(self.trusted)


@dataclass
class ServerConfig:
    keys: dict[str, bytes]  # swarm -> HMAC key
    ttl: float = DEFAULT_TTL
    window: float = DEFAULT_WINDOW
    rate: float = 100.0  # datagrams/s per source IP (a host running many nodes shares one budget)
    burst: float = 200.0
    sweep_period: float = 0.1
    # while the kernel is dropping datagrams (the receive queue overflowed, e.g. under a
    # flood), a silent member may only have lost its beacons there: it is forgotten only
    # after overload_grace x ttl of silence
    overload_grace: float = 10.0
    # swarm -> its roster and beacon key: beacons and goodbyes of that swarm must carry their node's tag
    identities: dict[str, SwarmIdentities] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.keys:
            raise ValueError("the discovery server needs at least one swarm key")
        self.keys = {s: check_key(k, f"key of swarm {s!r}") for s, k in self.keys.items()}
        for s in self.identities:
            if s not in self.keys:
                raise ValueError(f"identities of swarm {s!r}, which has no key")
        if self.ttl <= 0 or self.window <= 0 or self.rate <= 0:
            raise ValueError("ttl, window and rate must be > 0")


@dataclass
class DiscoveryServer:
    """The registry and its protocol logic; :meth:`serve` drives it from a UDP socket."""

    config: ServerConfig
    sock: socket.socket | None = None
    swarms: dict[str, Swarm] = field(default_factory=dict)
    stats: Counter[str] = field(default_factory=Counter)
    started: float = field(default_factory=time.time)

    def __post_init__(self) -> None:
        self.guard = ReplayGuard(self.config.window)
        self.limiter = SourceLimiter(self.config.rate, self.config.burst)
        self.kernel_drops = 0  # datagrams the kernel dropped on our full receive queue, so far
        self.overloaded_at = -float("inf")  # when that count last grew
        self._snap = int.from_bytes(os.urandom(4), "big") | 1

    # ---- socket plumbing ---------------------------------------------------------------------------
    def bind(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT) -> Addr:
        fam = socket.AF_INET6 if ":" in host else socket.AF_INET
        s = socket.socket(fam, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        try:  # the kernel then reports how many datagrams it dropped on a full receive queue
            s.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
        except OSError:  # not Linux: expiry cannot tell overload from silence
            pass
        s.bind((host, port))
        s.setblocking(False)
        self.sock = s
        return s.getsockname()[:2]

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def _send(self, data: bytes, addr: Addr) -> None:
        assert self.sock is not None
        try:
            self.sock.sendto(data, addr)
            self.stats["tx"] += 1
        except OSError as exc:  # unreachable peer, full buffer: count, never crash
            self.stats["tx_error"] += 1
            log.debug("send to %s failed: %s", addr, exc)

    def serve(self, stop: threading.Event, duration: float | None = None) -> None:
        assert self.sock is not None, "bind() first"
        sel = selectors.DefaultSelector()
        sel.register(self.sock, selectors.EVENT_READ)
        end = time.monotonic() + duration if duration is not None else float("inf")
        next_sweep = time.monotonic()
        next_log = next_sweep + 30.0
        logged: dict[str, int] = {}
        try:
            while not stop.is_set() and time.monotonic() < end:
                now_m = time.monotonic()
                if now_m >= next_sweep:
                    self.sweep(time.time())
                    next_sweep = now_m + self.config.sweep_period
                if now_m >= next_log:  # a status line every 30 s, when something changed
                    if dict(self.stats) != logged:
                        logged = dict(self.stats)
                        log.info("registry %s; counters %s", self.summary(), logged)
                    next_log = now_m + 30.0
                timeout = max(0.0, min(next_sweep, end) - time.monotonic())
                if sel.select(min(timeout, 0.5)):
                    self.drain()
        finally:
            sel.close()

    def drain(self, max_datagrams: int = 4096) -> None:
        assert self.sock is not None
        recvmsg = self.sock.recvmsg
        for _ in range(max_datagrams):
            try:
                data, anc, _flags, addr = recvmsg(MAX_DATAGRAM + 1, _CMSG_SPACE)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                self.stats["rx_error"] += 1
                log.debug("recv failed: %s", exc)
                return
            now = time.time()
            if anc:
                self._note_overflow(anc, now)
            self.handle(data, addr[:2], now)

    def _note_overflow(self, anc: list[tuple[int, int, bytes]], now: float) -> None:
        for level, kind, value in anc:
            if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(value) >= 4:
                dropped = int.from_bytes(value[:4], sys.byteorder)
                if dropped > self.kernel_drops:
                    self.stats["drop_rx_queue_full"] += dropped - self.kernel_drops
                    self.kernel_drops = dropped
                    self.overloaded_at = now

    # ---- protocol ------------------------------------------------------------------------------------
    @property
    def members(self) -> dict[str, dict[tuple[str, int], Member]]:
        """Each swarm's members by (role, node)."""
        return {name: sw.members for name, sw in self.swarms.items()}

    def handle(self, data: bytes, addr: Addr, now: float) -> None:
        """Process one datagram. Never raises on bad input: drops it and counts why."""
        st = self.stats
        st["rx"] += 1
        ip = addr[0]
        limiter = self.limiter
        trusted = limiter.is_trusted(ip)
        if not trusted and not limiter.admit_unauthenticated(ip, now):
            st["drop_rate_limited"] += 1
            return
        try:
            env = unseal(data, self.config.keys.get)
            self.guard.check(env, now)
            if not limiter.admit_authenticated(ip, now):  # a stranger is promoted, already charged
                st["drop_rate_limited"] += 1
                return
            if env.type == MsgType.BEACON:
                self._on_beacon(env, addr, now)
            elif env.type == MsgType.BYE:
                self._on_bye(env, addr)
            elif env.type == MsgType.QUERY:
                self._on_query(env, addr, now)
            else:
                raise ProtocolError("unexpected_type", env.type.name)
        except ProtocolError as exc:
            st["drop_" + exc.reason] += 1
            log.debug("dropped datagram from %s:%s: %s", addr[0], addr[1], exc)
        except Exception:  # a bug must not take the registry down; count it and go on
            st["drop_internal_error"] += 1
            log.exception("internal error on a datagram from %s", addr)

    def _check_identity(self, env: Envelope, role: str, node: int) -> None:
        """A swarm with identities: the datagram carries the tag of the node it speaks for."""
        ids = self.config.identities.get(env.swarm)
        if ids is None:
            return
        if not env.tag:
            raise ProtocolError("untagged", f"{role} {node}: no node tag")
        token = ids.token(role, node)
        if token is None or not env.tag_matches(token):
            raise ProtocolError("bad_identity", f"{role} {node}: not tagged by that node's credentials")

    def _on_beacon(self, env: Envelope, addr: Addr, now: float) -> None:
        b = parse_beacon(env.body)
        e = b.entry
        self._check_identity(env, e.role, e.node)
        swarm = self.swarms.get(env.swarm)
        if swarm is None:
            swarm = self.swarms[env.swarm] = Swarm()
        m = swarm.members.get(e.key)
        if m is not None and env.ts <= m.last_ts:
            raise ProtocolError("replayed", "older than the last beacon of this node")
        changed = m is None or m.entry != e
        if m is None:
            m = Member(e, addr, now, now, env.ts)
            swarm.add(m)
            self.stats["registered"] += 1
            log.info("%s: %s %d joined from %s:%d (zid %s, %s)", env.swarm, e.role, e.node, addr[0], addr[1], e.zid_hex,
                     ", ".join(e.locators))
        else:
            if m.entry.zid != e.zid:
                self.stats["restarted"] += 1
                m.first_seen = now
            if changed:
                swarm.update(m, e)
            m.addr, m.last_seen, m.last_ts = addr, now, env.ts
            swarm.heard(m)
        self.stats["beacons"] += 1
        key = self.config.keys[env.swarm]
        if changed:  # tell every other member at once: they dial the newcomer without waiting
            push = seal(MsgType.PEERS, env.swarm, key, peers_body(Peers(0, 0, 1, (e,))))
            for other in swarm.members.values():
                if other is not m:
                    self._send(push, other.addr)
                    self.stats["pushes"] += 1
        if b.view == swarm.view_of(m):
            self._send(seal(MsgType.ACK, env.swarm, key, [b.view]), addr)
            self.stats["acks"] += 1
        else:
            self._send_snapshot(env.swarm, key, [o.entry for o in swarm.members.values() if o is not m], addr)

    def _send_snapshot(self, swarm: str, key: bytes, entries: list[NodeEntry], addr: Addr) -> None:
        self._snap = (self._snap + 1) & 0xFFFFFFFF or 1
        groups = chunk_entries([e.to_wire() for e in entries])
        for i, g in enumerate(groups):
            body = [self._snap, i, len(groups), g]
            self._send(seal(MsgType.PEERS, swarm, key, body), addr)
        self.stats["snapshots"] += 1

    def _remove(self, swarm: str, keys: list[tuple[str, int]], reason: str) -> None:
        sw = self.swarms.get(swarm)
        if sw is None:
            return
        gone = [k for k in keys if sw.pop(k) is not None]
        if not gone:
            return
        self.stats[reason] += len(gone)
        log.info("%s: %s %s", swarm, reason, ", ".join(f"{r} {n}" for r, n in gone))
        key = self.config.keys[swarm]
        for g in chunk_entries([list(k) for k in gone]):  # many at once (a mass expiry) span datagrams
            data = seal(MsgType.GONE, swarm, key, g)
            for m in sw.members.values():
                self._send(data, m.addr)

    def _on_bye(self, env: Envelope, addr: Addr) -> None:
        k = parse_bye(env.body)
        self._check_identity(env, *k)
        sw = self.swarms.get(env.swarm)
        m = sw.members.get(k) if sw is not None else None
        if m is not None and m.addr == addr:  # only the node itself can say goodbye
            self._remove(env.swarm, [k], "left")
        else:
            self.stats["drop_bye_unknown"] += 1

    def _on_query(self, env: Envelope, addr: Addr, now: float) -> None:
        qid = parse_query(env.body)
        sw = self.swarms.get(env.swarm)
        rows = [[m.entry.to_wire(), m.first_seen, m.last_seen, f"{m.addr[0]}:{m.addr[1]}"]
                for m in (sw.members.values() if sw is not None else ())]
        self.stats["queries"] += 1
        stats = self.counters(now)
        groups = chunk_entries(rows)
        # the counters ride in the last datagram, or in one of their own if they do not fit there
        if sum(packed_size(r) for r in groups[-1]) + packed_size(stats) > BODY_BUDGET or len(groups[-1]) >= MAX_ITEMS:
            groups.append([])
        key = self.config.keys[env.swarm]
        for i, g in enumerate(groups):
            last = i == len(groups) - 1
            self._send(seal(MsgType.REGISTRY, env.swarm, key, [qid, i, len(groups), g, stats if last else None]), addr)

    def counters(self, now: float) -> dict[str, Any]:
        """The counters a registry answer carries: at most MAX_ITEMS of them, and within one datagram."""
        stats: dict[str, Any] = {"uptime": round(now - self.started, 3), "sources": len(self.limiter),
                                 "sources_evicted": self.limiter.evicted}
        for k, v in sorted(self.stats.items()):
            if len(stats) >= 64 or packed_size(stats) > BODY_BUDGET // 2:  # the reasons are a fixed set; belt and braces
                break
            stats[k] = v
        return stats

    def sweep(self, now: float) -> None:
        """Forget members not heard within the TTL (and tell the others).

        If the kernel dropped datagrams within the last TTL, silence proves nothing (the
        beacons may be among the drops): only members silent for ``overload_grace`` TTLs go."""
        ttl = self.config.ttl
        cutoff = now - ttl
        if now - self.overloaded_at <= ttl:
            cutoff = now - ttl * self.config.overload_grace
            self.stats["expiry_deferred"] += any(sw.silent_since(now - ttl) for sw in self.swarms.values())
        for name, sw in self.swarms.items():
            dead = sw.silent_since(cutoff)
            if dead:
                self._remove(name, dead, "expired")

    def summary(self) -> dict[str, int]:
        return {s: len(sw.members) for s, sw in self.swarms.items()}

    def registry(self, swarm: str) -> list[RegisteredNode]:
        sw = self.swarms.get(swarm)
        return [RegisteredNode(swarm, m.entry, m.first_seen, m.last_seen, f"{m.addr[0]}:{m.addr[1]}")
                for m in (sw.members.values() if sw is not None else ())]


# ---- keys ----------------------------------------------------------------------------------------------
def load_keys(path: str | Path) -> dict[str, str]:
    """A keys file: one ``SWARM KEY`` per line (``#`` starts a comment), or a JSON object."""
    text = Path(path).read_text()
    if text.lstrip().startswith("{"):
        data = json.loads(text)
        if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
            raise ValueError(f"{path}: a JSON keys file maps swarm names to key strings")
        return dict(data)
    keys: dict[str, str] = {}
    for i, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) != 2:
            raise ValueError(f"{path}:{i}: expected 'SWARM KEY'")
        keys[parts[0]] = parts[1]
    return keys


def parse_listen(text: str) -> Addr:
    host, _, port = text.rpartition(":")
    host = host.strip("[]")
    if not host:
        raise ValueError(f"--listen {text!r}: name the address to listen on (0.0.0.0 for every interface)")
    try:
        return host, int(port)
    except ValueError:
        raise ValueError(f"--listen {text!r}: expected HOST:PORT") from None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mrswarm discovery serve", description=__doc__.splitlines()[0])
    ap.add_argument("--listen", default=f"127.0.0.1:{DEFAULT_PORT}",
                    help=f"UDP HOST:PORT (default 127.0.0.1:{DEFAULT_PORT}; an edge server names its own address)")
    ap.add_argument("--keys", default=None, help="file with one 'SWARM KEY' per line (or a JSON object)")
    ap.add_argument("--key", action="append", default=[], metavar="SWARM=KEY",
                    help="a swarm key on the command line (visible to other users in ps; prefer --keys)")
    ap.add_argument("--identities", action="append", default=[], metavar="DIR",
                    help="a swarm's key directory or the edge's bundle (roster.json, beacon.key): its beacons must carry "
                         "their node's tag, so one member cannot speak for another (repeatable)")
    ap.add_argument("--ttl", type=float, default=DEFAULT_TTL, help=f"forget nodes silent this long, s (default {DEFAULT_TTL})")
    ap.add_argument("--window", type=float, default=DEFAULT_WINDOW, help="accepted clock difference, s")
    ap.add_argument("--rate", type=float, default=100.0, help="datagrams/s accepted per source IP")
    ap.add_argument("--duration", type=float, default=None, help="exit after this many seconds")
    ap.add_argument("--log-level", default="INFO")
    ap.add_argument("--die-with-parent", action="store_true", help="exit when the launching process dies (runtimes)")
    args = ap.parse_args(argv)
    if args.die_with_parent:
        die_with_parent()
    setup_logging(args.log_level, unknown=logging.INFO)
    try:
        keys: dict[str, str] = load_keys(args.keys) if args.keys else {}
        for kv in args.key:
            s, sep, k = kv.partition("=")
            if not sep:
                raise ValueError(f"--key {kv!r}: expected SWARM=KEY")
            keys[s] = k
        identities = {ids.swarm: ids for ids in map(SwarmIdentities.load, args.identities)}
        cfg = ServerConfig(keys={s: k.encode() for s, k in keys.items()}, ttl=args.ttl, window=args.window,
                           rate=args.rate, burst=2 * args.rate, identities=identities)
        server = DiscoveryServer(cfg)
        host, port = server.bind(*parse_listen(args.listen))
    except (OSError, ValueError) as exc:
        print(f"mrswarm discovery serve: error: {exc}", file=sys.stderr)
        return 2
    stop = stop_event()
    bound = f"; beacons bound to identities for {', '.join(sorted(cfg.identities))}" if cfg.identities else ""
    say(f"discovery server on udp/{host}:{port} for swarms {', '.join(sorted(cfg.keys))} "
        f"(period {DEFAULT_PERIOD:g} s, ttl {cfg.ttl:g} s){bound}")
    try:
        server.serve(stop, args.duration)
    finally:
        log.info("stopping; registry %s; counters %s", server.summary(), dict(server.stats))
        server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
