"""``mrswarm discovery probe``: join a swarm and report what this node sees.

A diagnostic node (and what the discovery tests and benchmark run on every host): a
:class:`SwarmNode` with the chosen connectivity that optionally publishes a pose at a fixed
rate and records

* the peers its Zenoh session links to directly, with the time each link appeared (from
  Zenoh's transport events, so the times are exact);
* every remote sample it receives under ``mrs/**`` (all swarms, to prove isolation), and
  for poses, per sender, the arrival gaps and the poses lost (from sequence numbers);
* liveliness tokens of its swarm appearing and disappearing;
* the discovery proxy's status and counters.

It writes all of it as JSON to ``--status`` (atomically, every ``--status-period``) and,
without ``--status``, prints a line per change of its peer set.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

GAP = 0.35  # s between two poses of one sender that is recorded as a gap (poses come every 0.1 s)
STALL = 0.2  # s between two iterations of our own loop that is recorded as a stall (busy machine)


def _read_key(text: str | None, file: str | None) -> str | None:
    if file:
        return Path(file).read_text().strip()
    return text


def build_connectivity(args: argparse.Namespace) -> Any:
    if args.connectivity == "discovery":
        from discovery.proxy import BeaconDiscovery

        key = _read_key(args.key, args.key_file)
        if not key:
            raise SystemExit("mrswarm discovery probe: --key or --key-file is required")
        extra = {}
        for item in args.extra_swarm:
            s, sep, f = item.partition("=")
            if not sep:
                raise SystemExit(f"--extra-swarm {item!r}: expected SWARM=KEYFILE")
            extra[s] = Path(f).read_text().strip()
        return BeaconDiscovery(server=args.server, key=key, listen=tuple(args.listen or ["tcp/127.0.0.1:0"]),
                               advertise=tuple(args.advertise), extra_swarms=extra, period=args.period,
                               connect=tuple(args.connect), zid=args.zid)
    from swarmnet.connectivity import Rendezvous

    if not args.connect:
        raise SystemExit("mrswarm discovery probe: --connectivity rendezvous needs --connect ROUTER_ENDPOINT")
    return Rendezvous(tuple(args.connect), mode="peer", listen=tuple(args.listen or ["tcp/127.0.0.1:0"]))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mrswarm discovery probe", description=__doc__.splitlines()[0])
    ap.add_argument("--swarm", required=True)
    ap.add_argument("--id", type=int, required=True, help="node id (1..65535)")
    ap.add_argument("--role", default="uav", choices=["uav", "gcs", "edge", "observer"])
    ap.add_argument("--realm", default="virtual", choices=["virtual", "physical"])
    ap.add_argument("--connectivity", default="discovery", choices=["discovery", "rendezvous"])
    ap.add_argument("--server", default="127.0.0.1:7450", help="discovery server HOST:PORT")
    ap.add_argument("--key", default=None, help="the swarm's discovery key (prefer --key-file)")
    ap.add_argument("--key-file", default=None)
    ap.add_argument("--extra-swarm", action="append", default=[], metavar="SWARM=KEYFILE",
                    help="also join this swarm's discovery (ground stations)")
    ap.add_argument("--listen", action="append", default=None, help="Zenoh listen endpoint (repeatable)")
    ap.add_argument("--advertise", action="append", default=[], help="announce this host/locator instead")
    ap.add_argument("--connect", action="append", default=[], help="static Zenoh endpoint (rendezvous router)")
    ap.add_argument("--period", type=float, default=1.0, help="beacon period, s")
    ap.add_argument("--zid", default=None, help="pin the Zenoh id (hex)")
    ap.add_argument("--publish", type=float, default=10.0, help="pose rate, Hz (0: none; UAVs only)")
    ap.add_argument("--status", default=None, help="write the status JSON to this file")
    ap.add_argument("--status-period", type=float, default=0.2)
    ap.add_argument("--poll", type=float, default=0.05, help="loop period, s (pose arrival times are taken per loop)")
    ap.add_argument("--duration", type=float, default=None)
    args = ap.parse_args(argv)

    import zenoh

    from groundfloor.files import write_json_atomic
    from groundfloor.process import die_with_parent, stop_event
    from swarmnet.messages import DecodeError, Realm, decode_pose
    from swarmnet.node import NodeIdentity, SwarmNode
    from swarmnet.receive import Inlet, subscribe

    die_with_parent()  # with whoever launched us (a test harness): no orphans
    stop = stop_event()
    ident = NodeIdentity(args.swarm, args.id, Realm.parse(args.realm), args.role)
    conn = build_connectivity(args)
    rate = args.publish if args.role == "uav" else 0.0
    node = SwarmNode(ident, conn, pose_rate_hz=rate or 10.0)
    t_launch = time.time()
    node.open()
    t_open = time.time()
    s = node.session
    assert s is not None
    spy = Inlet(8192, how="ring")  # stamped at the drain, as this loop always did
    spy_sub = subscribe(s, "mrs/**", spy, allowed_origin=zenoh.Locality.REMOTE)
    lock = threading.Lock()
    pending: list[tuple[float, str, str]] = []  # (time, "put"/"delete", zid) from Zenoh's transport events

    def on_transport(ev: Any) -> None:  # runs on a Zenoh thread: record and return
        t = time.time()
        tr = ev.transport
        if tr.is_multicast or str(tr.whatami).lower().endswith("client"):
            return
        with lock:
            pending.append((t, "put" if ev.kind == zenoh.SampleKind.PUT else "delete", str(tr.zid)))

    transports = s.info.declare_transport_events_listener(on_transport, history=True)
    peers: dict[str, float] = {}
    lost: dict[str, float] = {}
    rx: dict[str, dict[str, Any]] = {}
    per_swarm: dict[str, int] = {}
    alive_since: dict[str, float] = {}
    alive_left: dict[str, float] = {}
    status_path = Path(args.status) if args.status else None
    next_status = next_pose = 0.0
    end = t_open + args.duration if args.duration else float("inf")
    zid = str(s.info.zid())
    stalls: list[list[float]] = []  # [from, to] when this loop itself did not run for > STALL (busy machine)
    last_loop = time.time()
    try:
        while not stop.is_set() and time.time() < end:
            now = time.time()
            if now - last_loop > STALL and len(stalls) < 500:
                stalls.append([last_loop, now])
            last_loop = now
            if rate and now >= next_pose:
                node.publish_pose(t_sim=now - t_open, x=float(args.id), y=0.0, z=10.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0)
                next_pose = max(next_pose + 1.0 / rate, now)
            inbox = node.poll(now)
            for k in inbox.joined:
                alive_since.setdefault(k, now)
                alive_left.pop(k, None)
            for k in inbox.left:
                alive_left[k] = now
                alive_since.pop(k, None)
            for _at, sample in spy.drain():  # bounded per loop, like every other receiver
                key = str(sample.key_expr)
                parts = key.split("/")
                if len(parts) < 3:
                    continue
                per_swarm[parts[1]] = per_swarm.get(parts[1], 0) + 1
                if len(parts) == 4 and parts[3] == "pose":
                    r = rx.setdefault(f"{parts[1]}/{parts[2]}", {"n": 0, "first": now, "last": now, "max_gap": 0.0, "gaps": [],
                                                                 "seq": None, "missing": 0, "losses": []})
                    gap = now - r["last"]
                    if r["n"] and gap > r["max_gap"]:
                        r["max_gap"] = gap
                    if r["n"] and gap > GAP and len(r["gaps"]) < 100:
                        r["gaps"].append([r["last"], now])
                    try:  # sequence numbers tell lost poses from a receiver that was merely busy
                        seq = decode_pose(sample.payload.to_bytes()).seq
                    except DecodeError:
                        seq = None
                    if seq is not None:
                        if r["seq"] is not None:
                            missing = (seq - r["seq"] - 1) % 65536
                            if missing and missing < 32768:
                                r["missing"] += missing
                                if len(r["losses"]) < 100:
                                    r["losses"].append([now, missing])
                        r["seq"] = seq
                    r["n"] += 1
                    r["last"] = now
            with lock:
                events, pending = pending, []
            for t, kind, z in events:
                if kind == "put":
                    peers.setdefault(z, t)
                    lost.pop(z, None)
                else:
                    lost[z] = t
                    peers.pop(z, None)
                if status_path is None:
                    print(f"{t - t_open:7.3f} s  {'linked to' if kind == 'put' else 'lost'} {z} ({len(peers)} peers)", flush=True)
            if status_path is not None and now >= next_status:
                next_status = now + args.status_period
                st = {
                    "t": now, "launched_at": t_launch, "opened_at": t_open, "zid": zid, "swarm": args.swarm,
                    "role": args.role, "id": args.id, "pid": os.getpid(),
                    "peers": peers, "lost": lost, "links": len(list(s.info.links())),
                    "peers_now": sorted(str(z) for z in s.info.peers_zid()),
                    "rx": rx, "per_swarm": per_swarm, "stalls": stalls, "alive": alive_since, "alive_left": alive_left,
                    "discovery": conn.status() if hasattr(conn, "status") else {},
                    "rejects": dict(node.stats.rejected),
                }
                write_json_atomic(status_path, st)
            time.sleep(args.poll)
    finally:
        spy_sub.undeclare()
        transports.undeclare()
        node.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
