"""What a lone virtual UAV's I/O costs with none of its logic: the floor under its CPU.

A lone virtual UAV wakes ten times a second, exchanges MAVLink datagrams with its virtual FCU
over UDP, publishes its pose, telemetry and state over Zenoh, keeps a subscriber thread waiting
for neighbours' poses, beacons to the discovery server and writes its records. This benchmark
runs the same I/O in a process that does nothing else, in four steps, and the real lone UAV
beside them, alternated round by round:

* ``wake``: the 10 Hz loop alone (``select`` on an eventfd with a timeout, as the UAV's loop
  waits on its node's waker);
* ``io``: plus, each tick, a telemetry datagram (89 bytes, about 2.7 MAVLink frames) from an
  "FCU" socket to an "agent" socket and a setpoint (65 bytes) back, both drained until empty;
  a trajectory row each tick, written out each second; a counters file replaced each second;
  a thread that sends a 200-byte beacon each second and waits in ``select``;
* ``io+zenoh``: plus a Zenoh peer session linked to a router on 127.0.0.1 over plain TCP:
  10 poses (48 bytes, express), 2 telemetry and 1 state ``put`` a second, a pose subscriber
  whose thread waits in the ring channel, and the command subscribers;
* ``io+zenoh-tls``: the same over mutual TLS with access control, as the UAV's own link (a
  throw-away CA, a certificate for the UAV and one for the router);
* ``uav``: a lone virtual UAV in the default configuration (``scale.py --sizes 1 --configs
  default``), its process.

CPU is each process's user+system time over the window (psutil), in % of one core, as
``scale.py`` measures a UAV; the router and the discovery server are not counted. The skeleton
encodes and parses nothing, so ``io+zenoh-tls`` is a lower bound of what any UAV process with
this I/O costs on the machine, and ``uav`` minus it is what the UAV's own Python costs.

**A UAV of a fleet** (``--fleet N``): the same question for a UAV among N on the machine, in
the configuration the default chooses above 25 UAVs (client mode through one edge router, the
edge pose feed, mutual TLS). N skeletons run at once, each with the ``io`` of a lone UAV, a
client session to the edge router (which runs the pose feed, 3 ms window, as ``mrswarm run``
starts it), a valid pose each tick, telemetry and state, a liveliness token and the
subscriptions of a UAV (the feed's batches in a ring channel with a thread that stamps and
queues them, commands, liveliness), beside the real fleet:

* ``fleet``: the queued batches are dropped at each tick, unread;
* ``fleet+decode``: each tick also decodes every batch and every pose in it with the UAV's own
  rules (``accept_pose_batch``, ``accept_batched_pose``) and keeps the newest per sender: the
  least Python any UAV must run for what it receives;
* ``fleet-aligned``, ``fleet-aligned+decode``: the same with every skeleton's ticks on the wall
  clock's 100 ms grid, as ``network.align_ticks`` has the UAVs' (all at the same instants);
* ``uav``: a UAV of the real fleet, each UAV's ticks on its own grid (``scale.py --configs
  client-edge``; the median UAV, as ``scale.py`` reports it);
* ``uav-aligned``: the same with aligned ticks (``client-edge-aligned``, what the default is
  above 25 UAVs).

    python benchmarks/lone_floor.py --rounds 3 --window 30 --out benchmarks/results
    # -> benchmarks/results/lone_floor.{json,csv,png}; about 13 minutes
    python benchmarks/lone_floor.py --fleet 50 --rounds 3 --window 30 --tag fleet_floor_n50
    # -> benchmarks/results/fleet_floor_n50.{json,csv,png}; about 15 minutes
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import psutil

from groundfloor.files import write_json_atomic
from groundfloor.process import stop_event

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from deploy.process_runtime import wait_file  # noqa: E402
from discovery.netutil import free_port, wait_tcp  # noqa: E402
from discovery.options import FeedOptions  # noqa: E402
from mrswarm.run.keys import throwaway_keys  # noqa: E402
from swarmnet.feed import DEFAULT_WINDOW  # noqa: E402
from swarmnet.keyspace import SwarmKeys  # noqa: E402
from swarmnet.messages import Pose, Realm, Rejected, accept_batched_pose, accept_pose_batch, encode_pose  # noqa: E402
from swarmnet.security.credentials import Credentials  # noqa: E402
from swarmnet.security.identity import NodeName  # noqa: E402

VARIANTS = ("wake", "io", "io+zenoh", "io+zenoh-tls", "uav")
FLEET_VARIANTS = ("fleet", "fleet+decode", "fleet-aligned", "fleet-aligned+decode", "uav", "uav-aligned")
SWARM = "floor"
TICK_S = 0.1  # the UAV's loop: 10 Hz
TELEMETRY = bytes(89)  # a tick's MAVLink telemetry: about 2.7 frames (GLOBAL_POSITION_INT 10 Hz and the rest)
SETPOINT = bytes(65)  # SET_POSITION_TARGET_LOCAL_NED, MAVLink 2
POSE = bytes(48)


def skeleton(variant: str, endpoint: str, seconds: float, workdir: Path, keys: str = "", uav: int = 1) -> None:
    """The child process: ``variant``'s I/O for ``seconds`` or until SIGTERM (every loop bounded in time)."""
    waker = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
    io = variant != "wake"
    fleet = variant.startswith("fleet")
    decode = variant.endswith("+decode")
    aligned = "aligned" in variant  # ticks on the wall clock's grid, as network.align_ticks has the UAVs'
    if aligned:  # imported only here: the other skeletons load no more than their I/O needs
        from uav_stack.runtime import next_grid_instant
    stop = stop_event((signal.SIGTERM,))
    if io:
        fcu = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        agent = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        up = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for s in (fcu, agent, sink, up):
            s.bind(("127.0.0.1", 0))
        fcu.setblocking(False)
        agent.setblocking(False)
        fcu_at, agent_at, sink_at = fcu.getsockname(), agent.getsockname(), sink.getsockname()

        def beacon() -> None:
            while not stop.is_set():
                up.sendto(bytes(200), sink_at)
                select.select([up], [], [], 1.0)

        if not fleet:  # the default fleet's UAVs find the edge router by its address, without discovery
            threading.Thread(target=beacon, daemon=True).start()
        counters = workdir / (f"counters-uav{uav}.json" if fleet else f"counters-{os.getpid()}.json")
    session: Any = None
    batches: deque[tuple[float, Any]] = deque(maxlen=256)
    alive: Any = None
    if variant.startswith(("io+zenoh", "fleet")):
        import zenoh

        from swarmnet.connectivity import TransportTuning, base_config, to_zenoh

        creds = None if variant == "io+zenoh" else Credentials(keys=keys, identity=NodeName.uav(uav, SWARM).cn)
        mode, listen = ("client", ()) if fleet else ("peer", ("tcp/127.0.0.1:0",))
        session = zenoh.open(to_zenoh(base_config(mode, (endpoint,), listen, TransportTuning(), creds)))
        deadline = time.monotonic() + 60.0  # a link that never came up would measure nothing
        while not list(session.info.routers_zid()):
            if time.monotonic() > deadline:
                raise SystemExit(f"{variant}: no link to the router at {endpoint}")
            time.sleep(0.1)
        k = SwarmKeys(SWARM)
        pose = session.declare_publisher(k.pose(uav), congestion_control=zenoh.CongestionControl.DROP,
                                         priority=zenoh.Priority.DATA_HIGH, express=True)
        telemetry = session.declare_publisher(k.telemetry(uav))
        state = session.declare_publisher(k.state(uav))
        if fleet:
            poses = session.declare_subscriber(k.pose_feed, zenoh.handlers.RingChannel(256))
            alive = session.liveliness().declare_subscriber(k.all_alive, zenoh.handlers.RingChannel(256), history=True)
            session.liveliness().declare_token(k.alive("uav", uav))
        else:
            poses = session.declare_subscriber(k.all_poses, zenoh.handlers.RingChannel(64),
                                               allowed_origin=zenoh.Locality.REMOTE)
        session.declare_subscriber(k.cmd(uav), lambda sample: None)
        session.declare_subscriber(k.swarm_cmd, lambda sample: None)

        def inlet() -> None:  # as the UAV's inlet: stamp and queue, nothing else on this thread
            try:
                while True:
                    sample = poses.handler.recv()
                    batches.append((time.time(), sample))
            except zenoh.ZError:
                return

        inlet_thread = threading.Thread(target=inlet, daemon=True)
        inlet_thread.start()
        if fleet:
            (workdir / f"ready-{uav}").touch()

    def drain(sock: socket.socket) -> None:
        for _ in range(256):
            try:
                sock.recvfrom(4096)
            except BlockingIOError:
                return

    newest: dict[int, Pose] = {}
    taken = [0, 0]  # batches, poses decoded
    with open(workdir / f"trajectory-{os.getpid()}.csv", "w") as trajectory:  # written by io variants only
        t0 = time.monotonic()
        next_tick = next_grid_instant(t0, TICK_S) if aligned else t0
        next_second, tick = t0 + 1.0, 0
        while (now := time.monotonic()) < t0 + seconds and not stop.is_set():
            if next_tick > now:
                select.select([waker], [], [], next_tick - now)
                continue
            next_tick = next_grid_instant(now, TICK_S) if aligned else max(next_tick + TICK_S, now)
            tick += 1
            if not io:
                continue
            fcu.sendto(TELEMETRY, agent_at)
            drain(agent)
            agent.sendto(SETPOINT, fcu_at)
            drain(fcu)
            if session is not None:
                if fleet:
                    wall = time.time()
                    pose.put(encode_pose(Pose(uav, Realm.VIRTUAL, tick & 0xFFFF, now - t0, wall, 10.0 + uav, 20.0, 30.0,
                                              0.5, 0.5, 0.0, 1.571)))
                    for _ in range(len(batches)):
                        _, sample = batches.popleft()
                        taken[0] += 1
                        if decode:
                            taken[1] += decode_batch(sample, newest, uav)
                    while alive.handler.try_recv() is not None:
                        pass
                else:
                    pose.put(POSE)
                if tick % 5 == 0:
                    telemetry.put(bytes(60))
                if tick % 10 == 0:
                    state.put(bytes(40))
            trajectory.write(f"{now:.3f},1.000,2.000,3.000,0.500,0.500,0.000,1.571\n")
            if now >= next_second:
                next_second += 1.0
                trajectory.flush()
                write_json_atomic(counters, {"tick": tick, "t": now - t0, "batches": taken[0], "poses": taken[1],
                                             "rx": list(range(40))})
    stop.set()
    if session is not None:
        session.close()
        # a thread still blocked in Zenoh at exit aborts the process ("FATAL: exception not rethrown")
        inlet_thread.join(5.0)


def decode_batch(sample: Any, newest: dict[int, Pose], own: int) -> int:
    """A feed batch taken in as a UAV's node takes it: the envelope, then each pose by the batch
    rule, the newest kept per sender but ``own``. Returns the neighbours' poses accepted."""
    try:
        batch = accept_pose_batch(str(sample.key_expr), sample.payload.to_bytes())
    except Rejected:
        return 0
    n = 0
    for sender, data in zip(batch.senders, batch.poses, strict=True):
        try:
            p = accept_batched_pose(sender, data)
        except Rejected:
            continue
        if p.uav != own:  # our own pose comes back in the swarm's batch
            newest[p.uav] = p
            n += 1
    return n


def cpu_pct(a: Any, b: Any, window: float) -> float:
    """% of one core used between two ``cpu_times()`` readings ``window`` s apart (user + system)."""
    return 100.0 * ((b.user + b.system) - (a.user + a.system)) / window


def cpu_of(proc: psutil.Process, warmup: float, window: float) -> float:
    """% of one core that ``proc`` used over ``window`` s, after ``warmup`` s."""
    time.sleep(warmup)
    a = proc.cpu_times()
    time.sleep(window)
    return cpu_pct(a, proc.cpu_times(), window)


def run_skeleton(variant: str, endpoint: str, window: float, workdir: Path, keys: Path) -> float:
    warmup = 3.0
    child = subprocess.Popen([sys.executable, __file__, "--child", variant, "--endpoint", endpoint,
                              "--seconds", str(warmup + window + 2.0), "--workdir", str(workdir), "--keys", str(keys)],
                             env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        return cpu_of(psutil.Process(child.pid), warmup, window)
    finally:
        try:
            child.wait(timeout=warmup + window + 30.0)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


def run_uav(window: float, workdir: Path, n: int = 1, config: str = "default") -> dict[str, float]:
    """A real UAV: one ``scale.py`` run of ``n`` UAVs in ``config``, its median UAV."""
    out = workdir / "scale"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "scale.py"), "--sizes", str(n), "--configs", config,
           "--window", str(window), "--out", str(out), "--tag", "uav"]
    subprocess.run(cmd, env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True, timeout=600 + 6 * n,
                   stdout=subprocess.DEVNULL)
    row = json.loads((out / "uav.json").read_text())["rows"][0]
    return {"cpu_pct": float(row["cpu_pct_median"]), "cpu_pct_max": float(row["cpu_pct_max"]),
            "router_cpu_pct": float(row.get("router_cpu_pct") or 0.0), "rtf_min": float(row["rtf_min"]),
            "batches_rx_per_uav_s": float("nan"), "poses_rx_per_uav_s": float(row.get("poses_rx_per_uav_s") or "nan")}


THREAD_GROUPS = ("main", "python", "zenoh_rx", "zenoh_tx", "zenoh_other")


def thread_times(proc: psutil.Process) -> dict[str, float]:
    """CPU seconds of ``proc``'s threads by group: its main thread, its other Python threads, and
    Zenoh's (named by their runtime: ``rx-*`` receive, ``tx-*`` send, ``net-*``/``acc-*``/``app-*``)."""
    out = dict.fromkeys(THREAD_GROUPS, 0.0)
    for t in proc.threads():
        try:
            name = Path(f"/proc/{proc.pid}/task/{t.id}/comm").read_text().strip()
        except OSError:  # the thread ended meanwhile
            continue
        group = "main" if t.id == proc.pid else "zenoh_rx" if name.startswith("rx-") else \
            "zenoh_tx" if name.startswith("tx-") else "zenoh_other" if name[:4] in ("net-", "acc-", "app-") else "python"
        out[group] += t.user_time + t.system_time
    return out


def run_fleet(variant: str, n: int, endpoint: str, window: float, workdir: Path, keys: Path,
              router: psutil.Process) -> dict[str, float]:
    """``n`` skeletons of ``variant`` at once: their median and highest CPU, and the edge router's, over ``window`` s."""
    warmup = 5.0
    for f in [*workdir.glob("ready-*"), *workdir.glob("counters-uav*")]:
        f.unlink()
    children = [subprocess.Popen([sys.executable, __file__, "--child", variant, "--endpoint", endpoint,
                                  "--seconds", str(300.0 + window), "--workdir", str(workdir), "--keys", str(keys),
                                  "--uav", str(i)], env={**os.environ, "PYTHONPATH": str(ROOT)})
                for i in range(1, n + 1)]
    try:
        deadline = time.monotonic() + 240.0
        while len(list(workdir.glob("ready-*"))) < n:
            if time.monotonic() > deadline or any(c.poll() is not None for c in children):
                raise SystemExit(f"{variant}: {len(list(workdir.glob('ready-*')))} of {n} skeletons linked to the router")
            time.sleep(0.5)
        time.sleep(warmup)
        procs = [psutil.Process(c.pid) for c in children] + [router]
        before = [p.cpu_times() for p in procs]
        threads_before = [thread_times(p) for p in procs[:-1]]
        time.sleep(window)
        after = [p.cpu_times() for p in procs]
        threads_after = [thread_times(p) for p in procs[:-1]]
        cpu = [cpu_pct(a, b, window) for a, b in zip(before, after, strict=True)]
        taken = [json.loads((workdir / f"counters-uav{i}.json").read_text()) for i in range(1, n + 1)]
        by_thread = {f"cpu_pct_{group}": statistics.median(100.0 * (b.get(group, 0.0) - a.get(group, 0.0)) / window
                                                           for a, b in zip(threads_before, threads_after, strict=True))
                     for group in THREAD_GROUPS}
        return {"cpu_pct": statistics.median(cpu[:-1]), "cpu_pct_max": max(cpu[:-1]), "router_cpu_pct": cpu[-1],
                "rtf_min": float("nan"), "batches_rx_per_uav_s": statistics.median(c["batches"] / c["t"] for c in taken),
                "poses_rx_per_uav_s": statistics.median(c["poses"] / c["t"] for c in taken), **by_thread}
    finally:
        for c in children:
            c.terminate()
        for c in children:
            try:
                c.wait(timeout=30.0)
            except subprocess.TimeoutExpired:
                c.kill()
                c.wait()


def plot(rows: list[dict[str, Any]], path: Path, variants: tuple[str, ...], target: float, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for i, v in enumerate(variants):
        ys = [r["cpu_pct"] for r in rows if r.get("label", r["variant"]) == v]
        ax.scatter([i] * len(ys), ys, color="tab:blue", alpha=0.6)
        if ys:
            ax.hlines(statistics.median(ys), i - 0.3, i + 0.3, color="tab:red")
    ax.axhline(target, color="grey", linestyle="--", label=f"the target, {target:g} %")
    ax.set_xticks(range(len(variants)), variants, rotation=15)
    ax.set_ylabel("% of one core (red: median)")
    ax.set_ylim(bottom=0)
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def start_router(listen: str, security: list[str], *extra: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", "discovery.rendezvous", "--listen", listen, *security, *extra],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def measure_lone(args: argparse.Namespace, work: Path, routers: list[subprocess.Popen[bytes]]) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    keys = throwaway_keys(work / "keys", SWARM, [NodeName("edge", 0, SWARM), NodeName.uav(1, SWARM)])
    plain, tls = free_port(), free_port()
    endpoints = {"io+zenoh": f"tcp/127.0.0.1:{plain}", "io+zenoh-tls": f"tls/127.0.0.1:{tls}"}
    routers.append(start_router(endpoints["io+zenoh"], ["--insecure"]))
    routers.append(start_router(endpoints["io+zenoh-tls"], ["--keys", str(keys), "--stats", str(work / "router.json")]))
    wait_tcp("127.0.0.1", plain, timeout=20.0)
    wait_file(work / "router.json", timeout=20.0, proc=routers[1])  # a bare TCP probe would count as refused
    for rnd in range(args.rounds):
        for v in VARIANTS if rnd % 2 == 0 else VARIANTS[::-1]:
            cpu = run_uav(args.window, work)["cpu_pct"] if v == "uav" else \
                run_skeleton(v, endpoints.get(v, ""), args.window, work, keys)
            rows.append({"round": rnd, "variant": v, "cpu_pct": round(cpu, 3)})
            print(f"round {rnd} {v}: {cpu:.3f} % of a core", flush=True)
    return rows


def measure_fleet(args: argparse.Namespace, work: Path, routers: list[subprocess.Popen[bytes]]) -> list[dict[str, Any]]:
    n = args.fleet
    rows: list[dict[str, Any]] = []
    keys = throwaway_keys(work / "keys", SWARM, [NodeName("edge", 0, SWARM), *(NodeName.uav(i, SWARM) for i in range(1, n + 1))])
    runs: list[tuple[str, str, float]] = []  # (label, variant, the edge feed's window in ms)
    endpoints: dict[float, str] = {}
    for w in args.feed_window_ms:  # a router per window, each with its own stats file
        endpoints[w] = endpoint = f"tls/127.0.0.1:{free_port()}"
        stats = work / f"router-{w:g}.json"
        routers.append(start_router(endpoint, ["--keys", str(keys), "--stats", str(stats)],
                                    *FeedOptions(swarm=SWARM, window_s=w / 1000.0).argv()))
        wait_file(stats, timeout=20.0, proc=routers[-1])
        for v in args.variants:
            if not v.startswith("uav"):
                runs.append((v if len(args.feed_window_ms) == 1 else f"{v} {w:g} ms", v, w))
    for v in ("uav", "uav-aligned"):
        if v in args.variants:
            runs.append((v, v, 1000 * DEFAULT_WINDOW))  # the fleet as mrswarm run starts it
    by_window = {w: psutil.Process(r.pid) for w, r in zip(args.feed_window_ms, routers, strict=True)}
    for rnd in range(args.rounds):
        for label, v, w in runs if rnd % 2 == 0 else runs[::-1]:
            r = run_uav(args.window, work, n, {"uav": "client-edge", "uav-aligned": "client-edge-aligned"}[v]) \
                if v.startswith("uav") else \
                run_fleet(v, n, endpoints[w], args.window, work, keys, by_window[w])
            rows.append({"round": rnd, "label": label, "variant": v, "n": n, "feed_window_ms": w,
                         **{k: round(x, 3) for k, x in r.items()}})
            print(f"round {rnd} {label}: median {r['cpu_pct']:.3f} % of a core per UAV (max {r['cpu_pct_max']:.3f}), "
                  f"edge router {r['router_cpu_pct']:.2f} %, {r['batches_rx_per_uav_s']:.0f} batches and "
                  f"{r['poses_rx_per_uav_s']:.0f} poses taken in a second per UAV", flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3, help="each round runs every variant once, in turn")
    ap.add_argument("--window", type=float, default=30.0, help="measurement window per run, s")
    ap.add_argument("--fleet", type=int, default=0, metavar="N",
                    help="a UAV among N (client mode, edge feed, TLS) instead of a lone UAV")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--tag", default="", help="output file names (default: lone_floor, or fleet_floor_n<N>)")
    ap.add_argument("--child", choices=[*VARIANTS[:-1], *FLEET_VARIANTS[:-2]], help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", default="", help=argparse.SUPPRESS)
    ap.add_argument("--seconds", type=float, default=0.0, help=argparse.SUPPRESS)
    ap.add_argument("--workdir", default="", help=argparse.SUPPRESS)
    ap.add_argument("--keys", default="", help=argparse.SUPPRESS)
    ap.add_argument("--feed-window-ms", type=float, nargs="+", default=[1000 * DEFAULT_WINDOW],
                    help="with --fleet: the edge feed's window(s), ms; the skeletons run at each, side by side "
                         "(the real fleet at the default)")
    ap.add_argument("--variants", nargs="+", choices=FLEET_VARIANTS, default=list(FLEET_VARIANTS),
                    help="with --fleet: which to run")
    ap.add_argument("--uav", type=int, default=1, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        skeleton(args.child, args.endpoint, args.seconds, Path(args.workdir), args.keys, args.uav)
        return 0
    if args.fleet < 0 or args.fleet == 1:
        ap.error("--fleet: a fleet of at least 2 UAVs (a lone UAV: leave it out)")
    tag = args.tag or (f"fleet_floor_n{args.fleet}" if args.fleet else "lone_floor")

    routers: list[subprocess.Popen[bytes]] = []
    with tempfile.TemporaryDirectory(prefix="lone-floor-") as tmp:
        try:
            rows = (measure_fleet if args.fleet else measure_lone)(args, Path(tmp), routers)
        finally:
            for r in routers:
                r.terminate()
                try:
                    r.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    r.kill()
    labels = tuple(dict.fromkeys(r.get("label", r["variant"]) for r in rows))
    medians = {v: statistics.median(r["cpu_pct"] for r in rows if r.get("label", r["variant"]) == v) for v in labels}
    for v, m in medians.items():
        print(f"median {v}: {m:.3f} %")
    out = Path(args.out)
    write_results(out, tag, {"args": vars(args), "medians": medians, "rows": rows}, rows)
    if args.fleet:
        and_uav = ", and the UAV" if any(v.startswith("uav") for v in labels) else ""
        plot(rows, out / f"{tag}.png", labels, 1.5, f"A UAV among {args.fleet}: its I/O without its logic{and_uav}")
    else:
        plot(rows, out / f"{tag}.png", labels, 1.2, "A lone UAV's I/O without its logic, and the UAV")
    print(f"wrote {out / tag}.json/.csv/.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
