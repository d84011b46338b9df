"""Override commands: send a verb to UAVs, collect every acknowledgement, report per UAV."""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TextIO

from rich.console import Console
from rich.table import Table

from mrswarm.gcs.session import GcsError, wait_alive
from mrswarm.results.wording import format_ids
from swarmnet.observer import SwarmObserver

VERBS = ("takeoff", "start", "hold", "resume", "land", "rtl", "goto", "arm", "disarm", "kill")


@dataclass
class Result:
    uav: int
    status: str  # ok | failed | timeout
    message: str
    latency_ms: float | None


def resolve_targets(obs: SwarmObserver, ids: list[int] | None, wait: float) -> tuple[list[int], set[int]]:
    """(targets, alive). ``ids=None`` means every alive UAV. Unknown ids are an error."""
    alive = wait_alive(obs, set(ids) if ids is not None else None, wait)
    if ids is None:
        if not alive:
            raise GcsError(f"no UAV is alive in swarm '{obs.keys.swarm}'")
        return sorted(alive), alive
    unknown = sorted(set(ids) - alive)
    if unknown:
        raise GcsError(f"unknown UAV id{'s' if len(unknown) > 1 else ''} {format_ids(unknown)}: not alive in swarm "
                       f"'{obs.keys.swarm}' (alive: {format_ids(alive)})")
    return ids, alive


def send_and_collect(obs: SwarmObserver, verb: str, targets: list[int], args: dict[str, Any] | None, *,
                     to_all: bool, timeout: float, clock: Callable[[], float] = time.monotonic) -> list[Result]:
    """Send once (the swarm key for ``to_all``), re-send once to the silent ones halfway, wait for acks."""
    t0 = clock()
    pending = [obs.command(verb, None if to_all else targets, args)]
    if to_all:
        pending[0].targets = set(targets)  # the acks we insist on: everyone alive when we resolved
    acks: dict[int, tuple[Any, float]] = {}
    resent = False
    deadline = t0 + timeout
    while True:
        obs.poll()
        for p in pending:
            for u, a in p.acks.items():
                if u in targets and u not in acks:
                    acks[u] = (a, (clock() - t0) * 1000.0)
        missing = [u for u in targets if u not in acks]
        now = clock()
        if not missing or now >= deadline:
            break
        if not resent and now - t0 >= timeout / 2:
            resent = True  # every verb is idempotent; the first put may race a fresh session's routes
            pending.append(obs.command(verb, missing, args))
        time.sleep(0.02)
    out = []
    for u in targets:
        if u in acks:
            a, ms = acks[u]
            out.append(Result(u, "ok" if a.ok else "failed", a.message, round(ms, 1)))
        else:
            out.append(Result(u, "timeout", f"no acknowledgement within {timeout:g} s", None))
    return out


def print_results(results: list[Result], verb: str, console: Console, as_json: bool, out: TextIO = sys.stdout) -> None:
    if as_json:
        for r in results:
            out.write(json.dumps({"uav": r.uav, "verb": verb, "status": r.status, "message": r.message,
                                  "latency_ms": r.latency_ms}) + "\n")
        out.flush()
        return
    t = Table(title=f"{verb}: {sum(r.status == 'ok' for r in results)}/{len(results)} ok", title_justify="left")
    for c in ("uav", "result", "ms", "message"):
        t.add_column(c, justify="right" if c in ("uav", "ms") else "left")
    style = {"ok": "green", "failed": "red", "timeout": "red"}
    for r in results:
        t.add_row(str(r.uav), f"[{style[r.status]}]{r.status}[/]", "-" if r.latency_ms is None else f"{r.latency_ms:.0f}",
                  r.message)
    console.print(t)


def goto_args(xyz: list[float], geo: str | None = None) -> dict[str, float]:
    """The goto command's arguments: X Y Z in the swarm frame, or ``--geo LAT,LON,ALT``."""
    if geo is not None:
        if xyz:
            raise GcsError("goto: give X Y Z or --geo LAT,LON,ALT, not both")
        return geo_args(geo)
    if len(xyz) != 3:
        raise GcsError("goto needs X Y Z (metres east, north and up from the swarm origin) or --geo LAT,LON,ALT")
    for name, v in zip("xyz", xyz, strict=True):
        if not math.isfinite(v):
            raise GcsError(f"goto: {name}={v} is not a finite number")
    return {"x": xyz[0], "y": xyz[1], "z": xyz[2]}


def geo_args(text: str) -> dict[str, float]:
    """``LAT,LON,ALT`` (degrees, degrees, metres AMSL) -> the goto command's geodetic arguments."""
    try:
        lat, lon, alt = (float(x) for x in text.split(","))
    except ValueError:
        raise GcsError(f"goto --geo {text!r}: expected LAT,LON,ALT (degrees, degrees, metres above sea level)") from None
    if not all(math.isfinite(v) for v in (lat, lon, alt)):
        raise GcsError(f"goto --geo {text!r}: not finite numbers")
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise GcsError(f"goto --geo {text!r}: latitude must be within -90..90 and longitude within -180..180")
    return {"lat": lat, "lon": lon, "alt": alt}


def confirm_kill(targets: list[int], yes: bool, stdin: TextIO = sys.stdin, console: Console | None = None) -> bool:
    """Emergency motor stop needs a typed confirmation (or --yes in scripts)."""
    if yes:
        return True
    if stdin is None or not stdin.isatty():
        raise GcsError("kill stops the motors in flight (the UAVs fall): confirm in a terminal, or pass --yes")
    c = console or Console()
    c.print(f"[bold red]KILL[/] stops the motors of {len(targets)} UAV(s) ({format_ids(targets)}); airborne ones will fall.")
    c.print("Type [bold]kill[/] to confirm: ", end="")
    answer = stdin.readline().strip()
    return answer == "kill"
