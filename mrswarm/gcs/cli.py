"""``mrswarm gcs``: argument parsing and the subcommands (docs/gcs.md has the reference)."""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time
from typing import Any

from mrswarm.gcs.session import GcsError, parse_ids, resolve_target
from mrswarm.results.wording import format_ids
from uav_stack.cli_args import ArgumentParser

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130


def _common(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("where the swarm is")
    g.add_argument("--run", metavar="RUN_DIR", help="a folder of a running `mrswarm run` (reads its network.json)")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="Zenoh endpoint of the edge/rendezvous router, e.g. tls/10.0.0.1:7447 (repeatable)")
    g.add_argument("--swarm", help="swarm name (default: the run's)")
    g.add_argument("--keys", metavar="DIR", help="the ground station's credentials: the swarm's key directory or a gcs "
                                                 "bundle (default with --run: the run's); docs/security.md")
    g.add_argument("--identity", help="certificate to speak as (default gcs-1): gcs-<id> or gcs-<id>.<swarm>")


def _targets(p: argparse.ArgumentParser) -> None:
    t = p.add_mutually_exclusive_group(required=True)
    t.add_argument("--uav", metavar="IDS", help="one UAV or a list: 3, 1,2,5-7")
    t.add_argument("--all", action="store_true", help="every UAV alive in the swarm")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for every acknowledgement (default 5)")
    p.add_argument("--json", action="store_true", help="one JSON line per UAV instead of a table")


def build_parser(prog: str = "mrswarm gcs") -> argparse.ArgumentParser:
    ap = ArgumentParser(prog=prog, description="Ground station: live swarm telemetry and overrides (docs/gcs.md).")
    sub = ap.add_subparsers(dest="sub", required=True, metavar="SUBCOMMAND")

    p = sub.add_parser("nodes", help="who is alive: id, role, realm, version, address, last seen")
    _common(p)
    p.add_argument("--wait", type=float, default=2.0, help="seconds to listen before listing (default 2)")
    p.add_argument("--json", action="store_true")
    p.add_argument("--discovery", metavar="HOST:PORT",
                   help="the swarm's discovery server, for versions and locators (--run finds it by itself)")
    p.add_argument("--discovery-key-file", metavar="FILE", help="the swarm's key (`SWARM KEY` lines, as the server's)")

    p = sub.add_parser("watch", help="live table of every UAV (q quits; s sort, f filter, n/p page)")
    _common(p)
    p.add_argument("--sort", default="id", help="id, phase, mode, alt, speed, battery, rtf, age, rx, use, seen or loss")
    p.add_argument("--reverse", action="store_true")
    p.add_argument("--filter", action="append", default=[], metavar="KEY[=VALUE]",
                   help="id=1-20, phase=mission, mode=RTL, realm=physical, override, stale (repeatable: all must hold)")
    p.add_argument("--refresh", type=float, default=4.0, help="redraws per second (at least 2; default 4)")
    p.add_argument("--duration", type=float, default=None, help="exit after this many seconds")
    p.add_argument("--once", action="store_true", help="print one snapshot of every row and exit")

    p = sub.add_parser("telemetry", help="one UAV's telemetry, for scripts")
    _common(p)
    p.add_argument("--uav", type=int, required=True)
    p.add_argument("--follow", action="store_true", help="keep printing as updates arrive (Ctrl-C stops)")
    p.add_argument("--json", action="store_true", help="JSON lines")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the first telemetry")
    p.add_argument("--duration", type=float, default=None, help="with --follow: stop after this many seconds")

    helps = {
        "takeoff": "take off and hover (also relaunches a landed UAV)",
        "start": "start the mission, taking off first if on the ground (relaunches a landed UAV into it)",
        "hold": "suspend the swarm behaviour and hold position (until resume)",
        "resume": "give control back to the swarm behaviour (also after a human took over)",
        "land": "land where they are",
        "rtl": "return to launch and land",
        "goto": "fly to X Y Z (m east, north, up from the swarm origin), or --geo LAT,LON,ALT, and hold there",
        "arm": "arm the motors (on the ground)",
        "disarm": "disarm (on the ground)",
        "kill": "EMERGENCY: stop the motors now, also in flight (asks for confirmation)",
    }
    for verb, h in helps.items():
        p = sub.add_parser(verb, help=h)
        _common(p)
        _targets(p)
        if verb == "goto":
            p.add_argument("xyz", nargs="*", type=float, metavar="X Y Z", help="m east, north, up from the swarm origin")
            p.add_argument("--geo", metavar="LAT,LON,ALT",
                           help="a geodetic target instead: degrees, degrees, m above sea level (e.g. --geo -33.9,151.2,50)")
        if verb == "kill":
            p.add_argument("--yes", action="store_true", help="skip the confirmation (scripts)")

    p = sub.add_parser("record", help="record everything the swarm publishes to FILE: MCAP (--mcap, or FILE.mcap) or JSON lines")
    _common(p)
    p.add_argument("file")
    p.add_argument("--mcap", action="store_true", help="write MCAP (docs/recording.md); the default for a FILE ending in .mcap")
    p.add_argument("--die-with-parent", action="store_true", help="finish the file and stop when the parent process exits")
    p.add_argument("--lockstep", action="store_true",
                   help="MCAP: a lock-step run (time: lockstep): every record in its simulated time (docs/recording.md)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: Ctrl-C)")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--status", action="store_true",
                   help="MCAP: a line 'recorder-status {json}' on stdout per file begun or sealed, and at the end")

    p = sub.add_parser("foxglove", help="serve the swarm live to Foxglove (WebSocket protocol; docs/recording.md)")
    _common(p)
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8765, help="TCP port (default 8765, Foxglove's)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: Ctrl-C)")

    p = sub.add_parser("web", help="serve the live map: every UAV, trails, phases, commands with their acks (docs/recording.md)")
    _common(p)
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8088, help="TCP port (default 8088)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: Ctrl-C)")

    p = sub.add_parser("plot", help="draw a recording: trajectories, altitude, battery, phases")
    p.add_argument("file")
    p.add_argument("--out", default=None, help="PNG path (default: FILE with .png)")
    return ap


def main(argv: list[str] | None = None) -> int:
    from rich.console import Console

    ap = build_parser()
    args = ap.parse_args(argv)
    console = Console()
    err = Console(stderr=True)
    try:
        return _dispatch(args, console)
    except GcsError as exc:
        err.print(f"[red]error:[/] {exc}", highlight=False, soft_wrap=True)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED


def _dispatch(args: argparse.Namespace, console: Any) -> int:
    if args.sub == "plot":
        from mrswarm.gcs.record import plot_recording

        try:
            out, info = plot_recording(args.file, args.out)
        except (OSError, ValueError) as exc:
            raise GcsError(str(exc)) from None
        console.print(f"{out}: {info['uavs']} UAVs, {info['messages']} messages", highlight=False)
        return EXIT_OK
    if args.sub == "watch":  # validate options before connecting
        from mrswarm.gcs.watch import Filter, WatchView

        if args.refresh < 2.0:
            raise GcsError("--refresh must be at least 2 per second")
        filt = Filter.parse(args.filter)
    ids = parse_ids(args.uav) if getattr(args, "uav", None) is not None and isinstance(args.uav, str) else None
    if args.sub == "goto":
        from mrswarm.gcs.commands import goto_args

        goto_args(args.xyz, args.geo)
    target = resolve_target(args.run, args.connect, args.swarm, args.keys, args.identity)
    if args.sub == "nodes" and (args.discovery or args.discovery_key_file):
        target = _with_registry(target, args.discovery, args.discovery_key_file)

    from mrswarm.gcs.session import open_observer

    obs = open_observer(target)
    try:
        if args.sub == "nodes":
            return _nodes(obs, args, console, target)
        if args.sub == "watch":
            from pathlib import Path

            from mrswarm.gcs.watch import run_watch

            view = WatchView(target.swarm, args.sort, args.reverse, filt, run_dir=Path(args.run) if args.run else None)
            return run_watch(obs, view, console, refresh_hz=args.refresh, duration=args.duration, once=args.once)
        if args.sub == "telemetry":
            return _telemetry(obs, args, console)
        if args.sub == "foxglove":
            return _foxglove(obs, args, console)
        if args.sub == "web":
            from pathlib import Path

            from mrswarm.gcs.web.server import serve_web

            return serve_web(obs, host=args.host, port=args.port, duration=args.duration,
                             run_dir=Path(args.run) if args.run else None)
        if args.sub == "record" and (args.mcap or args.file.endswith(".mcap")):
            return _record_mcap(obs, args, console)
        if args.sub == "record":
            from mrswarm.gcs.record import run_record

            counts, interrupted = run_record(obs, args.file, duration=args.duration, quiet=args.quiet)
            console.print(f"recorded {sum(counts.values())} messages to {args.file}", highlight=False)
            return EXIT_INTERRUPTED if interrupted else EXIT_OK
        return _command(obs, args, ids, console)
    finally:
        obs.close()


def _record_mcap(obs: Any, args: argparse.Namespace, console: Any) -> int:
    """``record --mcap``: every message of the swarm into an MCAP file; with --run, the run's files too."""
    from pathlib import Path

    from mrswarm.recorder.recording import Stop, record_swarm
    from mrswarm.recorder.run_recorder import STATUS_PREFIX

    if Path(args.file).exists():
        raise GcsError(f"{args.file} exists: a recording is never overwritten")
    stop = Stop()
    stop.install()
    last = [time.monotonic()]

    def say(line: str) -> None:  # a full disk under the log, or a runner gone, must not end the recording
        try:
            print(line, flush=True)
        except OSError:
            pass

    def report(counts: dict[str, int]) -> None:
        if not args.quiet and time.monotonic() - last[0] >= 5.0:
            last[0] = time.monotonic()
            say(f"recording {args.file}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))

    def status(st: dict[str, object]) -> None:
        if args.status:
            say(f"{STATUS_PREFIX}{json.dumps(st)}")

    parent = os.getppid() if args.die_with_parent else None  # the runner: a runner killed hard still leaves a whole file

    def stopped() -> bool:
        return stop.requested or (parent is not None and os.getppid() != parent)

    counts = record_swarm(obs, args.file, duration=args.duration, run_dir=Path(args.run) if args.run else None,
                          lockstep=args.lockstep, stop=stopped, report=report, status=status)
    unwritten = counts.pop("unwritten", 0)
    say(f"recorded {sum(counts.values())} messages to {args.file}"
        + (f"; {unwritten} could not be written (the disk refused them)" if unwritten else ""))
    return 130 if stop.signum == signal.SIGINT else EXIT_OK


def _foxglove(obs: Any, args: argparse.Namespace, console: Any) -> int:
    from mrswarm.gcs.foxglove import serve_foxglove
    from mrswarm.recorder.recording import Stop

    if not 0 <= args.port <= 65535:
        raise GcsError(f"--port {args.port}: expected 0..65535")
    stop = Stop()
    stop.install()

    def ready(port: int) -> None:
        print(f"Foxglove: open a connection to ws://{args.host}:{port} (swarm {obs.keys.swarm}; Ctrl-C stops)", flush=True)

    serve_foxglove(obs, host=args.host, port=args.port, duration=args.duration, stop=lambda: stop.requested, ready=ready)
    return 130 if stop.signum == signal.SIGINT else EXIT_OK


def _with_registry(target: Any, server: str | None, key_file: str | None) -> Any:
    from dataclasses import replace

    from discovery.server import load_keys

    if not server or not key_file:
        raise GcsError("--discovery HOST:PORT and --discovery-key-file FILE go together")
    try:
        key = load_keys(key_file).get(target.swarm)
    except (OSError, ValueError) as exc:
        raise GcsError(f"--discovery-key-file {key_file}: {exc}") from None
    if not key:
        raise GcsError(f"--discovery-key-file {key_file}: no key for swarm {target.swarm!r}")
    return replace(target, discovery=(server, key))


def _nodes(obs: Any, args: argparse.Namespace, console: Any, target: Any = None) -> int:
    from mrswarm.gcs.directory import LivelinessDirectory
    from mrswarm.gcs.session import wait_alive

    wait_alive(obs, None, args.wait)
    deadline = time.monotonic() + min(args.wait, 1.5)  # a little longer, for realm and last-seen data
    while time.monotonic() < deadline:
        obs.poll()
        time.sleep(0.05)
    nodes = LivelinessDirectory(obs).nodes()
    if target is not None and target.discovery is not None:
        from discovery.client import QueryTimeout
        from mrswarm.gcs.directory import RegistryDirectory, merge

        server, key = target.discovery
        try:
            nodes = merge(nodes, RegistryDirectory(server, obs.keys.swarm, key).nodes())
        except QueryTimeout:
            print(f"warning: the discovery server {server} did not answer; versions and locators are unknown",
                  file=sys.stderr)
    now = time.time()
    if args.json:
        for n in nodes:
            d = dict(n.__dict__)
            d["last_seen"] = None if math.isnan(n.last_seen) else n.last_seen
            sys.stdout.write(json.dumps(d) + "\n")
        return EXIT_OK
    print_table(console, nodes_table(obs.keys.swarm, nodes, now))
    return EXIT_OK


def nodes_table(swarm: str, nodes: list[Any], now: float) -> Any:
    """The node list as a table; addresses and versions are plain text (an IPv6 ``[...]`` is not markup)."""
    from rich.table import Table
    from rich.text import Text

    t = Table(title=f"swarm {swarm}: {sum(n.role == 'uav' and n.alive for n in nodes)} UAVs alive", title_justify="left")
    for c in ("id", "role", "realm", "version", "address", "last seen", "alive"):
        t.add_column(c)
    for n in nodes:
        seen = "-" if math.isnan(n.last_seen) else f"{max(0.0, now - n.last_seen):.1f} s ago"
        t.add_row(str(n.id), n.role, n.realm, Text(n.version), Text(n.address), seen, "yes" if n.alive else "[red]no[/]")
    return t


def print_table(console: Any, table: Any) -> None:
    """A table in full: in a pipe or a file (no terminal to fit) no column is cut to the 80 columns rich assumes."""
    if console.is_terminal:
        console.print(table)
        return
    from rich.measure import Measurement

    width = console.width
    console.width = max(width, Measurement.get(console, console.options.update(width=100_000), table).maximum)
    try:
        console.print(table)
    finally:
        console.width = width


def telemetry_record(obs: Any, uav: int, now: float) -> dict[str, Any] | None:
    v = obs.uavs.get(uav)
    if v is None or (v.telemetry is None and v.pose is None):
        return None
    d: dict[str, Any] = {"uav": uav, "t": round(now, 3)}
    if v.telemetry is not None:
        t = v.telemetry
        d.update(realm=t.realm.label, mode=t.mode, armed=t.armed, lat=t.lat, lon=t.lon, alt_amsl=t.alt,
                 battery=t.battery, voltage=t.voltage, rtf=t.rtf, telemetry_age_s=round(max(0.0, now - t.t_wall), 3))
        if t.transport_ms >= 0:  # the UAV's own pose ages (p50 over its last second), if it reports them
            d.update(neighbour_transport_age_ms=t.transport_ms, neighbour_use_age_ms=t.use_ms if t.use_ms >= 0 else None)
    if v.pose is not None:
        p = v.pose
        d.update(x=p.x, y=p.y, z=p.z, vx=p.vx, vy=p.vy, vz=p.vz, yaw=p.yaw,
                 speed=round(math.sqrt(p.vx ** 2 + p.vy ** 2 + p.vz ** 2), 2),
                 pose_age_ms=round(max(0.0, v.pose_recv - p.t_wall) * 1000, 1))
    if v.state is not None:
        d.update(phase=v.state.phase, override=v.state.override, behaviour=v.state.behaviour, detail=v.state.detail)
    return d


def _telemetry(obs: Any, args: argparse.Namespace, console: Any) -> int:
    from mrswarm.gcs.session import wait_alive

    uav = args.uav
    if not 1 <= uav <= 65535:
        raise GcsError(f"--uav {uav}: ids are 1..65535")
    alive = wait_alive(obs, {uav}, min(args.timeout, 3.0))
    if uav not in alive:
        raise GcsError(f"unknown UAV id {uav}: not alive in swarm '{obs.keys.swarm}' (alive: {format_ids(alive)})")
    deadline = time.monotonic() + args.timeout
    while time.monotonic() < deadline:
        obs.poll()
        v = obs.uavs.get(uav)
        if v is not None and v.telemetry is not None and v.state is not None:
            break
        time.sleep(0.05)
    rec = telemetry_record(obs, uav, time.time())
    if rec is None:
        console.print(f"[red]no telemetry from UAV {uav} within {args.timeout:g} s[/]")
        return EXIT_FAILED
    _print_telemetry(rec, args.json, console)
    if not args.follow:
        return EXIT_OK
    end = math.inf if args.duration is None else time.monotonic() + args.duration
    last_seq = None
    while time.monotonic() < end:
        obs.poll()
        v = obs.uavs[uav]
        seq = (v.telemetry.seq if v.telemetry else None, v.state.seq if v.state else None)
        if seq != last_seq:
            last_seq = seq
            rec = telemetry_record(obs, uav, time.time())
            if rec is not None:
                _print_telemetry(rec, args.json, console)
        time.sleep(0.05)
    return EXIT_OK


def _print_telemetry(rec: dict[str, Any], as_json: bool, console: Any) -> None:
    if as_json:
        sys.stdout.write(json.dumps(rec) + "\n")
        sys.stdout.flush()
        return
    parts = [f"uav {rec['uav']}"]
    for k, fmt in (("phase", "{}"), ("override", "{}"), ("mode", "{}"), ("armed", "{}"), ("x", "{:.1f}"), ("y", "{:.1f}"),
                   ("z", "{:.1f}"), ("speed", "{:.1f}"), ("battery", "{:.0%}"), ("rtf", "{:.2f}"), ("pose_age_ms", "{:.0f}")):
        if rec.get(k) not in (None, ""):
            parts.append(f"{k}={fmt.format(rec[k])}")
    console.print(" ".join(parts), highlight=False, soft_wrap=True)  # one line per update, also in a pipe


def _command(obs: Any, args: argparse.Namespace, ids: list[int] | None, console: Any) -> int:
    from mrswarm.gcs.commands import confirm_kill, goto_args, print_results, resolve_targets, send_and_collect

    verb = args.sub
    targets, _ = resolve_targets(obs, ids, wait=2.0 if ids is None else 3.0)
    cmd_args = goto_args(args.xyz, args.geo) if verb == "goto" else None
    if verb == "kill" and not confirm_kill(targets, args.yes, console=console):
        console.print("not confirmed: nothing sent")
        return EXIT_FAILED
    if args.timeout <= 0:
        raise GcsError("--timeout must be > 0")
    results = send_and_collect(obs, verb, targets, cmd_args, to_all=args.all, timeout=args.timeout)
    print_results(results, verb, console, args.json)
    return EXIT_OK if all(r.status == "ok" for r in results) else EXIT_FAILED
