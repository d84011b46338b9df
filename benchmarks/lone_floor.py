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

    python benchmarks/lone_floor.py --rounds 3 --window 30 --out benchmarks/results
    # -> benchmarks/results/lone_floor.{json,csv,png}; about 13 minutes
"""

from __future__ import annotations

import argparse
import json
import os
import select
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from deploy.process_runtime import wait_file  # noqa: E402
from discovery.netutil import free_port, wait_tcp  # noqa: E402
from mrswarm.run_keys import throwaway_keys  # noqa: E402
from swarmnet.keyspace import SwarmKeys  # noqa: E402
from swarmnet.security.credentials import Credentials  # noqa: E402
from swarmnet.security.identity import NodeName  # noqa: E402

VARIANTS = ("wake", "io", "io+zenoh", "io+zenoh-tls", "uav")
SWARM = "floor"
TICK_S = 0.1  # the UAV's loop: 10 Hz
TELEMETRY = bytes(89)  # a tick's MAVLink telemetry: about 2.7 frames (GLOBAL_POSITION_INT 10 Hz and the rest)
SETPOINT = bytes(65)  # SET_POSITION_TARGET_LOCAL_NED, MAVLink 2
POSE = bytes(48)


def skeleton(variant: str, endpoint: str, seconds: float, workdir: Path, keys: str = "") -> None:
    """The child process: ``variant``'s I/O for ``seconds`` (every loop bounded in time)."""
    waker = os.eventfd(0, os.EFD_NONBLOCK | os.EFD_CLOEXEC)
    io = variant != "wake"
    stop = threading.Event()
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

        threading.Thread(target=beacon, daemon=True).start()
        counters = workdir / f"counters-{os.getpid()}.json"
    session: Any = None
    if variant.startswith("io+zenoh"):
        import zenoh

        from swarmnet.connectivity import TransportTuning, base_config, to_zenoh

        creds = Credentials(keys=keys, identity=NodeName.uav(1, SWARM).cn) if variant == "io+zenoh-tls" else None
        session = zenoh.open(to_zenoh(base_config("peer", (endpoint,), ("tcp/127.0.0.1:0",), TransportTuning(), creds)))
        deadline = time.monotonic() + 10.0  # a link that never came up would measure nothing
        while not list(session.info.routers_zid()):
            if time.monotonic() > deadline:
                raise SystemExit(f"{variant}: no link to the router at {endpoint}")
            time.sleep(0.1)
        k = SwarmKeys(SWARM)
        pose = session.declare_publisher(k.pose(1), congestion_control=zenoh.CongestionControl.DROP,
                                         priority=zenoh.Priority.DATA_HIGH, express=True)
        telemetry = session.declare_publisher(k.telemetry(1))
        state = session.declare_publisher(k.state(1))
        poses = session.declare_subscriber(k.all_poses, zenoh.handlers.RingChannel(64),
                                           allowed_origin=zenoh.Locality.REMOTE)
        session.declare_subscriber(k.cmd(1), lambda sample: None)
        session.declare_subscriber(k.swarm_cmd, lambda sample: None)

        def inlet() -> None:
            try:
                while True:
                    poses.handler.recv()
            except zenoh.ZError:
                return

        threading.Thread(target=inlet, daemon=True).start()

    def drain(sock: socket.socket) -> None:
        for _ in range(256):
            try:
                sock.recvfrom(4096)
            except BlockingIOError:
                return

    with open(workdir / f"trajectory-{os.getpid()}.csv", "w") as trajectory:  # written by io variants only
        t0 = time.monotonic()
        next_tick, next_second, tick = t0, t0 + 1.0, 0
        while (now := time.monotonic()) < t0 + seconds:
            if next_tick > now:
                select.select([waker], [], [], next_tick - now)
                continue
            next_tick = max(next_tick + TICK_S, now)
            tick += 1
            if not io:
                continue
            fcu.sendto(TELEMETRY, agent_at)
            drain(agent)
            agent.sendto(SETPOINT, fcu_at)
            drain(fcu)
            if session is not None:
                pose.put(POSE)
                if tick % 5 == 0:
                    telemetry.put(bytes(60))
                if tick % 10 == 0:
                    state.put(bytes(40))
            trajectory.write(f"{now:.3f},1.000,2.000,3.000,0.500,0.500,0.000,1.571\n")
            if now >= next_second:
                next_second += 1.0
                trajectory.flush()
                tmp = counters.with_name(f".{counters.name}.tmp")
                tmp.write_text(json.dumps({"tick": tick, "rx": list(range(40))}))
                os.replace(tmp, counters)
    stop.set()
    if session is not None:
        session.close()


def cpu_of(proc: psutil.Process, warmup: float, window: float) -> float:
    """% of one core that ``proc`` used over ``window`` s, after ``warmup`` s."""
    time.sleep(warmup)
    a = proc.cpu_times()
    time.sleep(window)
    b = proc.cpu_times()
    return 100.0 * ((b.user + b.system) - (a.user + a.system)) / window


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


def run_uav(window: float, workdir: Path) -> float:
    """The real lone UAV: one ``scale.py`` run at N = 1, the default configuration."""
    out = workdir / "scale"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "scale.py"), "--sizes", "1", "--configs", "default",
           "--window", str(window), "--out", str(out), "--tag", "lone"]
    subprocess.run(cmd, env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True, timeout=600,
                   stdout=subprocess.DEVNULL)
    rows = json.loads((out / "lone.json").read_text())["rows"]
    return float(rows[0]["cpu_pct_median"])


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for i, v in enumerate(VARIANTS):
        ys = [r["cpu_pct"] for r in rows if r["variant"] == v]
        ax.scatter([i] * len(ys), ys, color="tab:blue", alpha=0.6)
        if ys:
            ax.hlines(statistics.median(ys), i - 0.3, i + 0.3, color="tab:red")
    ax.axhline(1.2, color="grey", linestyle="--", label="a lone UAV's target, 1.2 %")
    ax.set_xticks(range(len(VARIANTS)), VARIANTS)
    ax.set_ylabel("% of one core (red: median)")
    ax.set_ylim(bottom=0)
    ax.set_title("A lone UAV's I/O without its logic, and the UAV")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3, help="each round runs every variant once, in turn")
    ap.add_argument("--window", type=float, default=30.0, help="measurement window per run, s")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--tag", default="lone_floor")
    ap.add_argument("--child", choices=VARIANTS[:-1], help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", default="", help=argparse.SUPPRESS)
    ap.add_argument("--seconds", type=float, default=0.0, help=argparse.SUPPRESS)
    ap.add_argument("--workdir", default="", help=argparse.SUPPRESS)
    ap.add_argument("--keys", default="", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        skeleton(args.child, args.endpoint, args.seconds, Path(args.workdir), args.keys)
        return 0

    rows: list[dict[str, Any]] = []
    routers: list[subprocess.Popen[bytes]] = []
    with tempfile.TemporaryDirectory(prefix="lone-floor-") as tmp:
        work = Path(tmp)
        keys = throwaway_keys(work / "keys", SWARM, [NodeName("edge", 0, SWARM), NodeName.uav(1, SWARM)])
        plain, tls = free_port(), free_port()
        endpoints = {"io+zenoh": f"tcp/127.0.0.1:{plain}", "io+zenoh-tls": f"tls/127.0.0.1:{tls}"}
        try:
            for endpoint, security in ((endpoints["io+zenoh"], ["--insecure"]),
                                       (endpoints["io+zenoh-tls"], ["--keys", str(keys), "--stats", str(work / "router.json")])):
                routers.append(subprocess.Popen([sys.executable, "-m", "discovery.rendezvous", "--listen", endpoint, *security],
                                                cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            wait_tcp("127.0.0.1", plain, timeout=20.0)
            wait_file(work / "router.json", timeout=20.0, proc=routers[1])  # a bare TCP probe would count as refused
            for rnd in range(args.rounds):
                order = VARIANTS if rnd % 2 == 0 else VARIANTS[::-1]
                for v in order:
                    cpu = run_uav(args.window, work) if v == "uav" else \
                        run_skeleton(v, endpoints.get(v, ""), args.window, work, keys)
                    rows.append({"round": rnd, "variant": v, "cpu_pct": round(cpu, 3)})
                    print(f"round {rnd} {v}: {cpu:.3f} % of a core", flush=True)
        finally:
            for r in routers:
                r.terminate()
                try:
                    r.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    r.kill()
    medians = {v: statistics.median(r["cpu_pct"] for r in rows if r["variant"] == v) for v in VARIANTS}
    for v, m in medians.items():
        print(f"median {v}: {m:.3f} %")
    out = Path(args.out)
    write_results(out, args.tag, {"args": vars(args), "medians": medians, "rows": rows}, rows)
    plot(rows, out / f"{args.tag}.png")
    print(f"wrote {out / args.tag}.json/.csv/.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
