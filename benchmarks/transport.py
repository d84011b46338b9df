"""Transport benchmark: the same pose workload over MQTT, plain Zenoh and swarmnet, side by side.

N agent processes on 127.0.0.1, each publishing a pose at 10 Hz (random phase) and receiving
every other agent's (full mesh). The transports, flown one after the other at every N (and
``--rounds`` times over), so that all see the machine's load of the same moment:

* ``mqtt``: Mosquitto (started here from the Debian package with a config written here:
  listener on 127.0.0.1 only, no persistence, TCP_NODELAY) + paho-mqtt, QoS 0, MQTT 5
  ``no_local``; agent -> broker -> agents;
* ``zenoh-peer``: plain zenoh-python, explicit full peer mesh, a callback subscriber; agent -> agents;
* ``zenoh-client``: plain zenoh-python in client mode through one Zenoh router
  (``python -m discovery.rendezvous``); agent -> router -> agents;
* ``swarmnet``: ``swarmnet.SwarmNode`` on the same peer mesh, its loop polling at the UAV tick
  (10 Hz); agent -> agents;
* ``swarmnet-client``: ``SwarmNode`` in client mode through the same router, each pose routed
  on its own (``mode: client``, ``pose_feed: direct``: UAVs behind carrier NAT); agent -> router
  -> agents;
* ``swarmnet-edge``: ``SwarmNode`` as a client of the edge router's pose feed (``pose_feed:
  edge``, 3 ms window); agent -> edge router (batches) -> agents.

Raw transports send 48-byte payloads (sender, sequence number, send time, padding); swarmnet
sends its own pose encoding (at most 48 bytes). The pose age is the receiving process's arrival
stamp (taken as the sample leaves Zenoh) minus the sender's stamp, both on this machine's wall
clock: for swarmnet that is its transport age (docs/performance.md). Measured in each agent
over the window: ages (log histogram, 50 bins per decade), poses received against poses
published by the others (delivery ratio; and that of the worst receiver, which tells one agent
linked late from drops spread over all), the agent's own CPU time (all its threads) and RSS;
the broker's or router's CPU by this script. ``--receivers K`` makes only K agents subscribe
(every agent still publishes) for a large N whose full mesh would saturate the machine; a
swarmnet node always subscribes to poses, so its non-receivers still get them and only skip
handling them (its figures with ``--receivers`` are pessimistic).

    python benchmarks/transport.py --sizes 10 25 50 --out benchmarks/results
    python benchmarks/transport.py --sizes 100 --receivers 20 --out benchmarks/results

writes ``transport.json``, ``transport.csv`` and ``transport.png`` (one row per N and transport,
medians over the agents of each run, summed over rounds for the ages).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import shutil
import signal
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from discovery.netutil import free_port  # noqa: E402

TRANSPORTS = ("mqtt", "zenoh-peer", "zenoh-client", "swarmnet", "swarmnet-client", "swarmnet-edge")
POSE_HZ = 10.0
TICK_HZ = 10.0  # swarmnet agents poll at the UAV loop's tick (uav_stack.runtime.tick_hz_for: 10 Hz by default)
PAYLOAD = struct.Struct("<HId")  # sender, seq, send time (s); padded to 48 bytes
PAYLOAD_BYTES = 48


# ---- the agent (one process) ------------------------------------------------------------------------
class Recorder:
    """Ages and counts inside the measurement window (thread-safe enough: one writer per transport)."""

    def __init__(self, w0: float, w1: float):
        from groundfloor.histogram import LogHistogram

        self.w0, self.w1 = w0, w1
        self.hist = LogHistogram()
        self.received = 0
        self.published = 0
        self.span = w1 - w0  # s of arrivals that `received` covers (swarmnet counts from tick to tick)
        self.lock = threading.Lock()

    def arrived(self, at: float, sent: float) -> None:
        if self.w0 <= at < self.w1:
            with self.lock:
                self.received += 1
                self.hist.add(at - sent)


def _payload(me: int, seq: int) -> bytes:
    return PAYLOAD.pack(me, seq, time.time()).ljust(PAYLOAD_BYTES, b"\0")


def _zenoh_config(mode: str, me: int, spec: dict[str, Any]) -> Any:
    from swarmnet.connectivity import TransportTuning, base_config, to_zenoh

    if mode == "client":
        return to_zenoh(base_config("client", (spec["router"],), (), TransportTuning()))
    ports = spec["ports"]
    return to_zenoh(base_config("peer", tuple(f"tcp/127.0.0.1:{ports[j]}" for j in range(me)),
                                (f"tcp/127.0.0.1:{ports[me]}",), TransportTuning()))


def run_agent(spec: dict[str, Any]) -> dict[str, Any]:
    """One agent: publish at 10 Hz from ``start`` for ``warmup + window`` s, receive, report."""
    me, kind, receive = spec["index"], spec["transport"], spec["receive"]
    w0 = spec["start"] + spec["warmup"]
    w1 = w0 + spec["window"]
    rec = Recorder(w0, w1)
    publish, close, tick = _open(kind, me, spec, rec, receive)
    rng = random.Random(me)
    next_pub = spec["start"] + rng.random() / POSE_HZ
    next_tick = time.time()
    seq = 0
    cpu0 = None
    while True:
        now = time.time()
        if now >= w1:
            break
        if cpu0 is None and now >= w0:
            t = os.times()
            cpu0 = (t.user + t.system, now)
        if now >= next_pub:
            if now >= spec["start"]:
                publish(seq)
                seq += 1
                if w0 <= now < w1:
                    rec.published += 1
            next_pub = max(next_pub + 1.0 / POSE_HZ, now)
        if tick is not None and now >= next_tick:
            tick()
            next_tick = max(next_tick + 1.0 / TICK_HZ, now)
        wake = min(next_pub, w1, next_tick if tick is not None else math.inf)
        time.sleep(max(0.0, wake - time.time()))
    if tick is not None:
        # a tick due just before the window's end may wake after it: without this one the count
        # stayed unset, and such an agent was reported as having received nothing (N = 25 delivered
        # 0.96 in 2 of about 14 swarmnet runs: one agent of 25 at 0)
        tick()
    t = os.times()
    assert cpu0 is not None
    cpu = 100.0 * (t.user + t.system - cpu0[0]) / (time.time() - cpu0[1])
    with open("/proc/self/statm") as f:
        rss = int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    out = {"index": me, "transport": kind, "cpu_pct": cpu, "rss_mb": rss, "published": rec.published,
           "received": rec.received, "span": rec.span, "receives": receive, "ages": rec.hist.to_dict()}
    time.sleep(0.5)  # let the others finish their window before links go down
    close()
    return out


def _open(kind: str, me: int, spec: dict[str, Any], rec: Recorder, receive: bool) -> tuple[Any, Any, Any]:
    """(publish(seq), close(), tick() or None) for one transport."""
    if kind == "mqtt":
        import paho.mqtt.client as mqtt
        from paho.mqtt.packettypes import PacketTypes  # noqa: F401 - MQTT 5 properties
        from paho.mqtt.subscribeoptions import SubscribeOptions

        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"agent{me}", protocol=mqtt.MQTTv5)

        def on_message(client: Any, userdata: Any, msg: Any) -> None:
            at = time.time()
            _, _, sent = PAYLOAD.unpack_from(msg.payload)
            rec.arrived(at, sent)

        connected = threading.Event()

        def on_connect(client: Any, userdata: Any, flags: Any, rc: Any, props: Any = None) -> None:
            sock = client.socket()
            if sock is not None:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if receive:
                client.subscribe("pose/+", options=SubscribeOptions(qos=0, noLocal=True))
            connected.set()

        c.on_message = on_message
        c.on_connect = on_connect
        c.connect("127.0.0.1", spec["broker_port"], keepalive=30)
        c.loop_start()
        connected.wait(20.0)
        topic = f"pose/{me}"

        def close() -> None:
            c.disconnect()
            c.loop_stop()

        return (lambda seq: c.publish(topic, _payload(me, seq), qos=0)), close, None

    if kind in ("zenoh-peer", "zenoh-client"):
        import zenoh

        s = zenoh.open(_zenoh_config("client" if kind == "zenoh-client" else "peer", me, spec))
        pub = s.declare_publisher(f"bench/{me}/pose", congestion_control=zenoh.CongestionControl.DROP,
                                  priority=zenoh.Priority.DATA_HIGH, express=True)
        if receive:
            def on_sample(sample: Any) -> None:  # a plain callback, as zenoh-python's examples write it
                at = time.time()
                _, _, sent = PAYLOAD.unpack_from(sample.payload.to_bytes())
                rec.arrived(at, sent)

            s.declare_subscriber("bench/*/pose", on_sample, allowed_origin=zenoh.Locality.REMOTE)
        return (lambda seq: pub.put(_payload(me, seq))), s.close, None

    if kind in ("swarmnet", "swarmnet-client", "swarmnet-edge"):
        from swarmnet.connectivity import Rendezvous, StaticPeers, lean_zenoh_runtime
        from swarmnet.node import NodeIdentity, SwarmNode

        lean_zenoh_runtime()  # Zenoh's runtime as a UAV process has it (ZENOH_RUNTIME='()': Zenoh's defaults)
        if kind == "swarmnet":
            ports = spec["ports"]
            conn: Any = StaticPeers(tuple(f"tcp/127.0.0.1:{ports[j]}" for j in range(me)), listen=(f"tcp/127.0.0.1:{ports[me]}",))
        else:
            conn = Rendezvous((spec["router"],), mode="client")
        node = SwarmNode(NodeIdentity("bench", me + 1), conn, pose_feed="edge" if kind == "swarmnet-edge" else "direct",
                         netem_control=False).open()
        ages = node.stats.ages
        snap: dict[str, Any] = {}

        def tick() -> None:
            now = time.time()
            if receive:
                node.poll(now)
            if "t" not in snap and now >= rec.w0:  # the window starts: what came before does not count
                snap.update(t=now, hist=ages.transport.copy(), n=node.stats.received["pose"])
            if "end" not in snap and now >= rec.w1 - 1.0 / TICK_HZ:
                snap["end"] = True
                rec.hist = ages.transport.since(snap["hist"])
                rec.received = node.stats.received["pose"] - snap["n"]
                rec.span = now - snap["t"]  # up to two ticks short of the window: scaled back in the delivery

        def publish(seq: int) -> None:
            node.publish_pose(t_sim=seq / POSE_HZ, x=float(me), y=0.0, z=10.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0)

        return publish, node.close, tick
    raise ValueError(kind)


# ---- the runner ------------------------------------------------------------------------------------
def start_mosquitto(workdir: Path) -> tuple[subprocess.Popen[bytes], int]:
    binary = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    if not Path(binary).exists():
        raise SystemExit("mosquitto not found: apt-get install mosquitto")
    port = free_port()
    conf = workdir / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\nset_tcp_nodelay true\n"
                    "log_type error\nlog_dest stderr\nmax_queued_messages 10000\n")
    with open(workdir / "mosquitto.log", "wb") as log:  # the child keeps its own descriptor
        proc = subprocess.Popen([binary, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=log)
    _wait_port(port, proc)
    return proc, port


def start_router(feed: bool) -> tuple[subprocess.Popen[bytes], str]:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    argv = [sys.executable, "-m", "discovery.rendezvous", "--listen", endpoint, "--insecure"]  # loopback, as the others
    if feed:
        argv += ["--feed", "bench"]
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=dict(os.environ, PYTHONPATH=str(ROOT)))
    _wait_port(port, proc)
    return proc, endpoint


def _wait_port(port: int, proc: subprocess.Popen[bytes], timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"process exited with {proc.returncode} before listening on {port}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.1)
    raise SystemExit(f"nothing listens on 127.0.0.1:{port}")


def run_cell(n: int, kind: str, args: argparse.Namespace, workdir: Path) -> dict[str, Any]:
    """One transport at one N: the broker/router if any, N agents, their reports merged."""
    import psutil

    from groundfloor.histogram import LogHistogram

    service = None
    spec: dict[str, Any] = {"transport": kind, "warmup": args.warmup, "window": args.window}
    if kind == "mqtt":
        service, spec["broker_port"] = start_mosquitto(workdir)
    elif kind in ("zenoh-client", "swarmnet-client", "swarmnet-edge"):
        service, spec["router"] = start_router(feed=kind == "swarmnet-edge")
    else:
        spec["ports"] = [free_port() for _ in range(n)]
    receivers = set(range(n)) if not args.receivers or args.receivers >= n else set(range(0, n, max(1, n // args.receivers)))
    spec["start"] = time.time() + args.startup + 0.12 * n  # every agent up and linked before it publishes
    procs = []
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for i in range(n):
        s = dict(spec, index=i, receive=i in receivers)
        out = workdir / f"{kind}-{n}-{i}.json"
        procs.append((out, subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--agent", json.dumps(s), "--report",
                                             str(out)], cwd=ROOT, env=env, start_new_session=True)))
    svc_cpu = math.nan
    try:
        if service is not None:
            sp = psutil.Process(service.pid)
            time.sleep(max(0.0, spec["start"] + args.warmup - time.time()))
            c0 = sp.cpu_times()
            t0 = time.time()
            time.sleep(args.window)
            c1 = sp.cpu_times()
            svc_cpu = 100.0 * (c1.user + c1.system - c0.user - c0.system) / (time.time() - t0)
        deadline = spec["start"] + args.warmup + args.window + 60.0
        for _, p in procs:
            try:
                p.wait(max(1.0, deadline - time.time()))
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
    finally:
        for _, p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
        if service is not None:
            service.terminate()
            try:
                service.wait(10)
            except subprocess.TimeoutExpired:
                service.kill()
    reports = [json.loads(out.read_text()) for out, _ in procs if out.exists()]
    hist = LogHistogram()
    for r in reports:
        hist.merge(LogHistogram.from_dict(r["ages"]))
    n_recv = sum(1 for r in reports if r["receives"])
    # every published pose should reach every receiver but its sender; a receiver whose count covers
    # a shorter span than the window (swarmnet's, from tick to tick) is scaled to the window
    expected = sum(r["published"] * (n_recv - (1 if r["receives"] else 0)) for r in reports)
    scaled = [(r, r["received"] * args.window / r["span"]) for r in reports if r["receives"] and r["span"] > 0]
    received = sum(count for _, count in scaled)
    # the worst receiver: one agent that linked late (or not at all) shows here, drops spread over all do not
    total = sum(r["published"] for r in reports)
    worst, worst_agent = min(((count / (total - r["published"]), r["index"]) for r, count in scaled if total > r["published"]),
                             default=(None, None))
    ms = lambda v: round(1000.0 * v, 3) if v == v else None  # noqa: E731
    row = {
        "n": n, "transport": kind, "agents_reported": len(reports), "receivers": n_recv,
        "age_p50_ms": ms(hist.percentile(50)), "age_p99_ms": ms(hist.percentile(99)), "age_max_ms": ms(hist.max),
        "delivery": round(received / expected, 4) if expected else None,
        "delivery_worst_agent": round(worst, 4) if worst is not None else None, "worst_agent": worst_agent,
        "cpu_pct_median": round(statistics.median(r["cpu_pct"] for r in reports), 3) if reports else None,
        "cpu_pct_max": round(max(r["cpu_pct"] for r in reports), 3) if reports else None,
        "rss_mb_median": round(statistics.median(r["rss_mb"] for r in reports), 1) if reports else None,
        "service_cpu_pct": round(svc_cpu, 2) if svc_cpu == svc_cpu else None,
        "ages": hist.to_dict(),
    }
    print({k: v for k, v in row.items() if k != "ages"}, flush=True)
    return row


def worst_of(rows: list[dict[str, Any]]) -> float | None:
    """The worst receiver's delivery over the rounds (rows without it are skipped)."""
    return min((r["delivery_worst_agent"] for r in rows if r.get("delivery_worst_agent") is not None), default=None)


def merge_rounds(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (N, transport): ages merged over rounds, medians of the per-round figures."""
    from groundfloor.histogram import LogHistogram

    out = []
    for key in dict.fromkeys((r["n"], r["transport"]) for r in rows):
        rs = [r for r in rows if (r["n"], r["transport"]) == key]
        h = LogHistogram()
        for r in rs:
            h.merge(LogHistogram.from_dict(r["ages"]))
        def med(k: str, rs: list[dict[str, Any]] = rs) -> float | None:
            vals = [r[k] for r in rs if r[k] is not None]
            return statistics.median(vals) if vals else None

        out.append({"n": key[0], "transport": key[1], "rounds": len(rs), "receivers": rs[0]["receivers"],
                     "age_p50_ms": round(1000 * h.percentile(50), 3) if h.n else None,
                     "age_p99_ms": round(1000 * h.percentile(99), 3) if h.n else None,
                     "delivery": med("delivery"), "delivery_worst_agent": worst_of(rs),
                     "cpu_pct_median": med("cpu_pct_median"), "rss_mb_median": med("rss_mb_median"),
                     "service_cpu_pct": med("service_cpu_pct")})
    return out


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 4, figsize=(19, 4.4))
    for i, kind in enumerate(dict.fromkeys(r["transport"] for r in rows)):
        rs = sorted((r for r in rows if r["transport"] == kind), key=lambda r: r["n"])
        ns = [r["n"] for r in rs]
        c = f"C{i}"
        ax[0].plot(ns, [r["age_p50_ms"] for r in rs], "o-", color=c, label=f"{kind} p50")
        ax[0].plot(ns, [r["age_p99_ms"] for r in rs], "x--", color=c, alpha=0.6, label=f"{kind} p99")
        ax[1].plot(ns, [r["delivery"] for r in rs], "o-", color=c, label=kind)
        ax[2].plot(ns, [r["cpu_pct_median"] for r in rs], "o-", color=c, label=kind)
        ax[3].plot(ns, [r["service_cpu_pct"] for r in rs], "o-", color=c, label=kind)
    ax[0].set_yscale("log")
    ax[0].set_title("pose age, publish -> arrival (ms)")
    ax[1].set_title("delivery ratio")
    ax[2].set_title("CPU per agent, median (% of one core)")
    ax[3].set_title("broker / router CPU (% of one core)")
    for a in ax:
        a.set_xlabel("agents (N)")
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    fig.suptitle("48-byte poses at 10 Hz, full mesh, 127.0.0.1: MQTT, plain Zenoh and swarmnet in one run")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 25, 50])
    ap.add_argument("--transports", nargs="+", choices=TRANSPORTS, default=list(TRANSPORTS))
    ap.add_argument("--rounds", type=int, default=1, help="times every (N, transport) is flown, interleaved")
    ap.add_argument("--receivers", type=int, default=0, help="only this many agents subscribe (0: all)")
    ap.add_argument("--warmup", type=float, default=8.0, help="s of publishing before the window")
    ap.add_argument("--window", type=float, default=20.0, help="measurement window, s")
    ap.add_argument("--startup", type=float, default=4.0, help="s for the agents to start and link (+ 0.12 s per agent)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--tag", default="transport", help="output file names")
    ap.add_argument("--agent", help=argparse.SUPPRESS)
    ap.add_argument("--report", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.agent:  # one agent process
        Path(args.report).write_text(json.dumps(run_agent(json.loads(args.agent))))
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="mrswarm-transport-") as tmp:
        for r in range(args.rounds):
            for n in args.sizes:
                order = list(args.transports)
                if r % 2:  # alternate the order between rounds: no transport always runs first
                    order.reverse()
                rows += [run_cell(n, kind, args, Path(tmp)) for kind in order]
    merged = merge_rounds(rows)
    write_results(out, args.tag, {"args": vars(args), "cores": os.cpu_count(), "rows": merged, "runs": rows}, merged)
    plot(merged, out / f"{args.tag}.png")
    print(f"wrote {out / args.tag}.json/.csv/.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
