"""Standalone virtual FCU.

    python -m uav_stack.fcu --sysid 1 --listen 127.0.0.1:14580 [--remote 127.0.0.1:14540]
        --home LAT,LON,ALT [--flavour px4|ardupilot] [--boot short|firmware] [--rtf 1.0] [--duration S]
        [--count N] [--param NAME=VALUE ...] [--rate MESSAGE=HZ ...] [--physics-hz 50]
        [--owner HOST:PORT [--owner-only]]

``--boot firmware`` boots on the firmware's own timeline (ArduCopter is ready to arm after about 42 s);
the default ``short`` runs the same boot, ready after 1 s. ``--rate`` sets a stream over the flavour's own
(as a companion's SET_MESSAGE_INTERVAL would).

With ``--count N`` it hosts N vehicles in one process: sysids sysid..sysid+N-1, listen
port and remote ports +i (PX4 SITL's multi-vehicle convention), homes 5 m apart eastwards.
It prints one line per vehicle, ``LISTEN <sysid> <host>:<port>``, once the sockets are
bound (useful with port 0), and exits 0 on --duration, SIGINT or SIGTERM.

Each vehicle's owner (its companion) keeps its place among the vehicle's UDP peers whatever
other ports send: ``--owner`` names it (port +i with --count), else the first peer heard is
the owner; ``--owner-only`` ignores everyone else (docs/security.md).
"""

from __future__ import annotations

import argparse
import sys
import threading

from groundfloor.process import setup_logging, stop_event
from uav_stack.fcu.boot import BOOT_PROFILES
from uav_stack.fcu.config import FcuConfig, VehicleConfig
from uav_stack.fcu.fcu import VirtualFcu
from uav_stack.geo import GeoPoint, LocalFrame


def _hostport(s: str) -> tuple[str, int]:
    host, sep, port = s.rpartition(":")
    if not sep or not host:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {s!r}")
    try:
        p = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"bad port in {s!r}") from None
    if not 0 <= p <= 65535:
        raise argparse.ArgumentTypeError(f"port out of range in {s!r}")
    return host, p


def _home(s: str) -> GeoPoint:
    try:
        lat, lon, alt = (float(x) for x in s.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LAT,LON,ALT, got {s!r}") from None
    return GeoPoint(lat, lon, alt)


def _param(s: str) -> tuple[str, float]:
    name, sep, value = s.partition("=")
    try:
        if not sep:
            raise ValueError
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {s!r}") from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m uav_stack.fcu", description="Virtual MAVLink flight controller")
    p.add_argument("--sysid", type=int, default=1)
    p.add_argument("--listen", type=_hostport, default=("127.0.0.1", 14580), help="HOST:PORT (port 0 = any)")
    p.add_argument("--remote", type=_hostport, action="append", default=[], help="static peer HOST:PORT")
    p.add_argument("--home", type=_home, default=GeoPoint(47.397742, 8.545594, 488.0), help="LAT,LON,ALT")
    p.add_argument("--flavour", choices=["px4", "ardupilot"], default="px4")
    p.add_argument("--boot", choices=list(BOOT_PROFILES), default="short",
                   help="boot timeline: short (ready in 1 s) or firmware (the firmware's own durations)")
    p.add_argument("--rtf", type=float, default=1.0, help="target real-time factor")
    p.add_argument("--physics-hz", type=float, default=50.0)
    p.add_argument("--duration", type=float, default=None, help="seconds of wall time, default forever")
    p.add_argument("--count", type=int, default=1, help="vehicles in this process")
    p.add_argument("--yaw", type=float, default=0.0, help="initial heading, rad")
    p.add_argument("--param", type=_param, action="append", default=[], help="NAME=VALUE override")
    p.add_argument("--rate", type=_param, action="append", default=[], help="MESSAGE=HZ stream rate (0 = off)")
    p.add_argument("--owner", type=_hostport, default=None, help="the companion's HOST:PORT (default: the first peer heard)")
    p.add_argument("--owner-only", action="store_true", help="ignore datagrams from anyone but the owner")
    p.add_argument("--log-level", default="WARNING")
    return p


def config_from_args(a: argparse.Namespace) -> FcuConfig:
    if a.count < 1 or a.sysid + a.count - 1 > 255:
        raise ValueError("--count must be >= 1 and sysids must stay <= 255")
    if a.owner_only and a.owner is None:
        raise ValueError("--owner-only needs --owner HOST:PORT (else the first peer heard would be the only one answered)")
    frame = LocalFrame(a.home)
    vehicles = []
    for i in range(a.count):
        host, port = a.listen
        lat, lon, alt = frame.to_geodetic(5.0 * i, 0.0, 0.0) if i else (a.home.lat, a.home.lon, a.home.alt)
        vehicles.append(
            VehicleConfig(
                sysid=a.sysid + i,
                home=GeoPoint(lat, lon, alt),
                flavour=a.flavour,
                listen=(host, port + i if port else 0),
                remotes=tuple((h, rp + i) for h, rp in a.remote),
                yaw=a.yaw,
                params=dict(a.param),
                owner=(a.owner[0], a.owner[1] + i) if a.owner else None,
                owner_only=a.owner_only,
                boot=a.boot,
            )
        )
    return FcuConfig(vehicles=vehicles, physics_hz=a.physics_hz, target_rtf=a.rtf, stream_rates=dict(a.rate))


def main(argv: list[str] | None = None) -> int:
    a = build_parser().parse_args(argv)
    setup_logging(str(a.log_level))
    try:
        cfg = config_from_args(a)
        fcu = VirtualFcu(cfg)
        addrs = fcu.open()
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    stop = stop_event() if threading.current_thread() is threading.main_thread() else threading.Event()
    for v, (host, port) in zip(cfg.vehicles, addrs, strict=True):
        print(f"LISTEN {v.sysid} {host}:{port}", flush=True)
    try:
        fcu.run(duration=a.duration, stop=stop)
    finally:
        fcu.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
