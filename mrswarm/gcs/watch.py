"""``mrswarm gcs watch``: a live table of every UAV of a swarm.

The loop only drains ring channels (``SwarmObserver.poll``), so a slow or silent UAV can
never block it: its row just ages and turns dim, then red. Only the rows that fit the
terminal are rendered, so hundreds of UAVs cost no more than a screenful. Keys (in a
terminal): ``q`` quit, ``s``/``S`` next/previous sort column, ``r`` reverse, ``f`` cycle a
phase filter, ``n``/``p`` (PgDn/PgUp, arrows) page, ``c`` clear the filters.
"""

from __future__ import annotations

import json
import math
import os
import select
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console, Group, JustifyMethod
from rich.live import Live
from rich.table import Table
from rich.text import Text

from mrswarm.gcs.session import GcsError, parse_ids
from mrswarm.results.wording import format_ids
from swarmnet.observer import SwarmObserver
from uav_stack.phases import AgentPhase

STALE_S = 3.0  # no data for this long: the row is dim
LOST_S = 10.0  # ... and red after this
SORT_KEYS = ("id", "phase", "mode", "alt", "speed", "battery", "rtf", "age", "rx", "use", "seen", "loss")


@dataclass
class Row:
    id: int
    realm: str = "-"
    phase: str = "-"
    override: str = ""
    mode: str = "-"
    armed: bool | None = None
    x: float = math.nan
    y: float = math.nan
    alt: float = math.nan
    speed: float = math.nan
    battery: float = math.nan  # 0..1
    rtf: float = math.nan
    age: float = math.nan  # transport age of its latest pose to this ground station, s
    rx: float = math.nan  # its own transport age of its neighbours' poses, p50 over its last second, ms
    use: float = math.nan  # its own age at use of those poses (arrival -> controller), p50, ms
    seen: float = math.nan  # s since anything arrived from it
    rate: float = math.nan  # poses/s
    loss: float = math.nan  # fraction of poses lost
    detail: str = ""  # the agent's phase detail: what it waits for in init/arming, why it is in error

    def get(self, key: str) -> Any:
        return self.phase + self.override if key == "phase" else getattr(self, key)


def rows_from(obs: SwarmObserver, now: float) -> list[Row]:
    rows = []
    for uav, v in obs.uavs.items():
        r = Row(uav)
        times = []
        if v.pose is not None:
            p = v.pose
            r.realm = p.realm.label
            r.x, r.y, r.alt = p.x, p.y, p.z
            r.speed = math.sqrt(p.vx * p.vx + p.vy * p.vy + p.vz * p.vz)
            r.age = max(0.0, v.pose_recv - p.t_wall)
            times.append(v.pose_recv)
            n = obs.node.neighbours.get(uav)
            if n is not None:
                r.rate, r.loss = n.rate, n.loss
        if v.telemetry is not None:
            t = v.telemetry
            r.realm = t.realm.label
            r.mode, r.armed = t.mode, t.armed
            r.battery = t.battery if t.battery >= 0 else math.nan
            r.rtf = t.rtf if t.rtf > 0 else math.nan
            r.rx = t.transport_ms if t.transport_ms >= 0 else math.nan
            r.use = t.use_ms if t.use_ms >= 0 else math.nan
            times.append(t.t_wall)
        if v.state is not None:
            r.phase, r.override, r.detail = v.state.phase, v.state.override, v.state.detail
            times.append(v.state_recv)
        r.seen = now - max(times) if times else math.nan
        rows.append(r)
    return rows


@dataclass
class Filter:
    """Row filters from ``--filter KEY=VALUE`` (repeatable, all must hold)."""

    ids: set[int] | None = None
    phase: str | None = None
    mode: str | None = None
    realm: str | None = None
    override: bool = False  # only rows with an override
    stale: bool = False  # only rows silent for STALE_S

    @classmethod
    def parse(cls, items: list[str]) -> Filter:
        f = cls()
        for it in items:
            key, _, val = it.partition("=")
            key = key.strip().lower()
            if key == "id":
                f.ids = set(parse_ids(val))
            elif key in ("phase", "mode", "realm"):
                if not val:
                    raise GcsError(f"--filter {it!r}: give a value, e.g. {key}=...")
                setattr(f, key, val.lower())
                if key == "phase" and f.phase not in set(AgentPhase):
                    raise GcsError(f"--filter {it!r}: unknown phase (one of: {', '.join(AgentPhase)})")
            elif key in ("override", "stale") and not val:
                setattr(f, key, True)
            else:
                raise GcsError(f"--filter {it!r}: use id=1-20, phase=NAME, mode=NAME, realm=virtual|physical, override or stale")
        return f

    def match(self, r: Row) -> bool:
        if self.ids is not None and r.id not in self.ids:
            return False
        if self.phase is not None and r.phase.lower() != self.phase:
            return False
        if self.mode is not None and r.mode.lower() != self.mode:
            return False
        if self.realm is not None and r.realm != self.realm:
            return False
        if self.override and not r.override:
            return False
        return not self.stale or r.seen > STALE_S or math.isnan(r.seen)

    def describe(self) -> str:
        parts = []
        if self.ids is not None:
            parts.append(f"id={format_ids(self.ids)}")
        for k in ("phase", "mode", "realm"):
            if getattr(self, k) is not None:
                parts.append(f"{k}={getattr(self, k)}")
        parts += [k for k in ("override", "stale") if getattr(self, k)]
        return " ".join(parts) or "none"


def sort_rows(rows: list[Row], key: str, reverse: bool = False) -> list[Row]:
    if key not in SORT_KEYS:
        raise GcsError(f"--sort {key!r}: one of {', '.join(SORT_KEYS)}")

    def k(r: Row) -> tuple[int, Any, int]:
        v = r.get(key)
        missing = v is None or (isinstance(v, float) and math.isnan(v))
        return (1 if missing else 0, "" if missing else v, r.id)

    out = sorted(rows, key=k)
    if reverse:  # missing values stay last
        have = [r for r in out if k(r)[0] == 0][::-1]
        out = have + [r for r in out if k(r)[0] == 1]
    return out


# column -> (justify, minimum width); in the order shown
COLUMNS: dict[str, tuple[JustifyMethod, int]] = {
    "id": ("right", 3), "R": ("left", 1), "phase": ("left", 7), "override": ("left", 8), "mode": ("left", 8),
    "arm": ("left", 3), "x": ("right", 6), "y": ("right", 6), "alt": ("right", 5), "m/s": ("right", 4),
    "bat%": ("right", 4), "rtf": ("right", 4), "age ms": ("right", 6), "rx ms": ("right", 5), "use ms": ("right", 6),
    "Hz": ("right", 4), "loss%": ("right", 5), "seen s": ("right", 6), "detail": ("left", 12),
}
# dropped first when the terminal is narrow (the realm is R: V = virtual, P = physical); a UAV that
# waits (init, arming) or gave up (error) says why below the table at any width
_DROP_ORDER = ("detail", "loss%", "Hz", "use ms", "rx ms", "R", "arm", "rtf", "m/s")
WAITING = frozenset({AgentPhase.INIT, AgentPhase.ARMING, AgentPhase.ERROR})
MAX_WAIT_LINES = 5


def fit_columns(width: int) -> list[str]:
    cols = list(COLUMNS)
    need = lambda cs: sum(max(COLUMNS[c][1], len(c)) + 1 for c in cs) + 8  # noqa: E731 - cells a bit wider than minimums
    for c in _DROP_ORDER:
        if need(cols) <= width:
            break
        cols.remove(c)
    return cols


def _f(v: float, fmt: str) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, fmt)


class WatchView:
    """Sorting, filtering, paging and rendering (separate from the terminal loop)."""

    def __init__(self, swarm: str, sort: str = "id", reverse: bool = False, filt: Filter | None = None,
                 run_dir: Path | None = None):
        sort_rows([], sort)  # validates
        self.swarm = swarm
        self.sort = sort
        self.reverse = reverse
        self.filter = filt or Filter()
        self.page = 0
        self.started = time.time()
        self.run_dir = run_dir  # --run: the run folder, whose run.json says when the run has ended
        self._ended: float | None = None  # wall time the run stopped
        self._next_look = 0.0

    def run_ended(self, now: float) -> float | None:
        """When the watched run stopped (its run.json's ``stopped``), looked up once a second; None while it flies."""
        if self.run_dir is None or self._ended is not None or now < self._next_look:
            return self._ended
        self._next_look = now + 1.0
        try:
            stopped = json.loads((self.run_dir / "run.json").read_text()).get("stopped")
        except (OSError, ValueError, AttributeError):
            return None  # not written yet, or being replaced
        if isinstance(stopped, int | float):
            self._ended = float(stopped)
        return self._ended

    def render(self, obs: SwarmObserver, now: float, height: int, width: int = 200) -> Group:
        rows = rows_from(obs, now)
        total = len(rows)
        shown = sort_rows([r for r in rows if self.filter.match(r)], self.sort, self.reverse)
        waiting = [r for r in sort_rows(rows, "id") if r.phase in WAITING and r.detail]
        wait_lines = min(len(waiting), MAX_WAIT_LINES)
        per_page = max(1, height - 9 - wait_lines - (len(waiting) > wait_lines))
        pages = max(1, math.ceil(len(shown) / per_page))
        self.page = min(self.page, pages - 1)
        page_rows = shown[self.page * per_page:(self.page + 1) * per_page]
        phases: dict[str, int] = {}
        for r in rows:
            phases[r.phase] = phases.get(r.phase, 0) + 1
        stale = sum(1 for r in rows if r.seen > STALE_S)
        overrides = sum(1 for r in rows if r.override)
        failsafes = sum(1 for r in rows if r.override.startswith("failsafe:"))  # companion failsafes (docs/reliability.md)
        alive = len(obs.alive_uavs())
        head = Text.assemble(
            (f"swarm {self.swarm}", "bold"), f"  {total} UAVs seen, {alive} alive, {stale} stale, {overrides} overridden",
            (f", {failsafes} in failsafe" if failsafes else "", "bold magenta"), "  ",
            ("phases: ", "dim"), ", ".join(f"{k} {v}" for k, v in sorted(phases.items())) or "-",
        )
        cols = fit_columns(width)
        t = Table(box=None, pad_edge=False, header_style="bold", expand=False, padding=(0, 1))
        for name in cols:
            just, min_w = COLUMNS[name]
            t.add_column(name, justify=just, no_wrap=True, min_width=min_w, overflow="ellipsis")
        for r in page_rows:
            style = ""
            if r.seen > LOST_S:
                style = "red"
            elif r.seen > STALE_S:
                style = "dim"
            elif r.override.startswith("failsafe:"):
                style = "magenta"
            elif r.override:
                style = "yellow"
            cells = {
                "id": str(r.id), "R": r.realm[:1].upper() if r.realm != "-" else "-", "phase": r.phase,
                "override": r.override or "", "mode": r.mode, "arm": "-" if r.armed is None else ("yes" if r.armed else "no"),
                "x": _f(r.x, ".1f"), "y": _f(r.y, ".1f"), "alt": _f(r.alt, ".1f"), "m/s": _f(r.speed, ".1f"),
                "bat%": _f(r.battery * 100 if r.battery == r.battery else math.nan, ".0f"), "rtf": _f(r.rtf, ".2f"),
                "age ms": _f(r.age * 1000 if r.age == r.age else math.nan, ".1f"), "rx ms": _f(r.rx, ".1f"),
                "use ms": _f(r.use, ".0f"), "Hz": _f(r.rate, ".1f"),
                "loss%": _f(r.loss * 100 if r.loss == r.loss else math.nan, ".1f"), "seen s": _f(r.seen, ".1f"),
                "detail": r.detail,
            }
            t.add_row(*(cells[c] for c in cols), style=style)
        ended = self.run_ended(now)
        if ended is not None and self.run_dir is not None:
            summary = self.run_dir / "summary.json"
            at = time.strftime("%H:%M:%S", time.localtime(ended))
            head.append(Text(f"\nthe run has ended ({now - ended:.0f} s ago, at {at})"
                             + (f"; summary: {summary}" if summary.exists() else "; its summary is being written"),
                             style="bold red"))
        waits = [Text.assemble((f"UAV {r.id} {r.phase}: ", "bold red" if r.phase == AgentPhase.ERROR else "bold"), r.detail,
                               no_wrap=True, overflow="ellipsis") for r in waiting[:wait_lines]]
        if len(waiting) > wait_lines:
            waits.append(Text(f"... and {len(waiting) - wait_lines} more waiting (--filter phase=init)", style="dim"))
        foot = Text(
            f"sort {self.sort}{' (reversed)' if self.reverse else ''} | filter {self.filter.describe()} | "
            f"rows {len(shown)} of {total}, page {self.page + 1}/{pages} | "
            "q quit  s/S sort  r reverse  f phase  c clear  n/p page", style="dim")
        return Group(head, t, *waits, foot)

    # ---- keys -------------------------------------------------------------------------------
    def key(self, k: str, obs: SwarmObserver) -> bool:
        """Apply one key; False means quit."""
        if k in ("q", "Q", "\x03"):
            return False
        if k == "s":
            self.sort = SORT_KEYS[(SORT_KEYS.index(self.sort) + 1) % len(SORT_KEYS)]
        elif k == "S":
            self.sort = SORT_KEYS[(SORT_KEYS.index(self.sort) - 1) % len(SORT_KEYS)]
        elif k == "r":
            self.reverse = not self.reverse
        elif k in ("n", "PGDN", "DOWN", " ", "j"):
            self.page += 1
        elif k in ("p", "PGUP", "UP", "k"):
            self.page = max(0, self.page - 1)
        elif k == "c":
            self.filter = Filter()
        elif k == "f":
            phases = sorted({v.state.phase for v in obs.uavs.values() if v.state is not None})
            cur = self.filter.phase
            if not phases:
                self.filter.phase = None
            elif cur is None or cur not in phases:
                self.filter.phase = phases[0]
            else:
                i = phases.index(cur) + 1
                self.filter.phase = phases[i] if i < len(phases) else None
            self.page = 0
        return True


_ESC = {"\x1b[5~": "PGUP", "\x1b[6~": "PGDN", "\x1b[A": "UP", "\x1b[B": "DOWN"}


def split_keys(data: str) -> list[str]:
    out = []
    i = 0
    while i < len(data):
        for seq, name in _ESC.items():
            if data.startswith(seq, i):
                out.append(name)
                i += len(seq)
                break
        else:
            out.append(data[i])
            i += 1
    return out


@contextmanager
def cbreak(fd: int | None) -> Iterator[None]:
    if fd is None:
        yield
        return
    import termios
    import tty

    old = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)
        yield
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, old)


def run_watch(obs: SwarmObserver, view: WatchView, console: Console, *, refresh_hz: float = 4.0,
              duration: float | None = None, once: bool = False, clock: Callable[[], float] = time.time) -> int:
    if once:  # one snapshot for scripts: wait briefly for data, print, exit
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            obs.poll()
            if obs.uavs and all(v.state is not None and v.telemetry is not None for v in obs.uavs.values()) and \
                    len(obs.uavs) >= len(obs.alive_uavs()):
                break
            time.sleep(0.1)
        if not console.is_terminal:  # a pipe or a file: do not squeeze columns to 80
            console = Console(file=console.file, width=max(console.width, 160))
        console.print(view.render(obs, clock(), 10_000, console.width))
        return 0
    fd = sys.stdin.fileno() if sys.stdin is not None and sys.stdin.isatty() else None
    period = 1.0 / max(2.0, refresh_hz)
    end = math.inf if duration is None else time.monotonic() + duration
    with cbreak(fd), Live(console=console, auto_refresh=False, screen=False, transient=False,
                          vertical_overflow="crop") as live:
        next_draw = 0.0
        while time.monotonic() < end:
            obs.poll()
            if fd is not None:
                r, _, _ = select.select([fd], [], [], 0)
                if r:
                    data = os.read(fd, 64).decode(errors="ignore")
                    if not all(view.key(k, obs) for k in split_keys(data)):
                        break
                    next_draw = 0.0
            now_m = time.monotonic()
            if now_m >= next_draw:
                next_draw = now_m + period
                live.update(view.render(obs, clock(), console.size.height, console.size.width), refresh=True)
            time.sleep(0.05)
    return 0
