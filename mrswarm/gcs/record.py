"""``mrswarm gcs record FILE`` and ``mrswarm gcs plot FILE``.

A recording is JSON Lines, one message per line, exactly what the ground station received:

    {"t": <receive wall time>, "kind": "pose" | "telemetry" | "state" | "ack" | "joined" | "left", ...fields}

The file is opened for appending and flushed (and fsynced) at least once a second, so a crash
loses at most the last second; a torn last line is skipped when reading.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, is_dataclass
from enum import Enum
from pathlib import Path
from typing import Any, TextIO

from swarmnet.observer import SwarmObserver

FLUSH_EVERY = 1.0


def _jsonable(kind: str, msg: Any, t: float) -> dict[str, Any]:
    if is_dataclass(msg) and not isinstance(msg, type):  # an instance, not a dataclass type
        d = asdict(msg)
        for k, v in d.items():
            if isinstance(v, Enum):
                d[k] = v.name.lower()
            elif isinstance(v, float) and not math.isfinite(v):
                d[k] = None
    else:
        d = {"key": str(msg)}
    return {"t": round(t, 6), "kind": kind, **d}


class Recorder:
    """Appends every observed message to a JSONL file; flushes at least every second."""

    def __init__(self, path: str | Path, clock: Callable[[], float] = time.time, flush_every: float = FLUSH_EVERY):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.clock = clock
        self.flush_every = flush_every
        self._f: TextIO = open(self.path, "a", encoding="utf-8", buffering=1 << 16)  # noqa: SIM115 (open until close())
        self._last_flush = clock()
        self.counts: dict[str, int] = {}

    def __call__(self, kind: str, msg: Any) -> None:
        now = self.clock()
        self._f.write(json.dumps(_jsonable(kind, msg, now), separators=(",", ":")) + "\n")
        self.counts[kind] = self.counts.get(kind, 0) + 1

    def maybe_flush(self) -> None:
        now = self.clock()
        if now - self._last_flush >= self.flush_every:
            self.flush()

    def flush(self) -> None:
        self._f.flush()
        try:
            os.fsync(self._f.fileno())
        except OSError:
            pass
        self._last_flush = self.clock()

    def close(self) -> None:
        if not self._f.closed:
            self.flush()
            self._f.close()


def run_record(obs: SwarmObserver, path: str | Path, *, duration: float | None = None, quiet: bool = False,
               stop: Callable[[], bool] = lambda: False) -> tuple[dict[str, int], bool]:
    """Record until ``duration``, ``stop()`` or Ctrl-C; returns (messages per kind, stopped by Ctrl-C).

    The file is flushed and closed either way, so a Ctrl-C loses nothing."""
    rec = Recorder(path)
    interrupted = False
    obs.tap = rec
    end = math.inf if duration is None else time.monotonic() + duration
    next_report = time.monotonic() + 5.0
    try:
        while time.monotonic() < end and not stop():
            obs.poll()
            rec.maybe_flush()
            if not quiet and time.monotonic() >= next_report:
                next_report += 5.0
                print(f"recording {path}: " + ", ".join(f"{k} {v}" for k, v in sorted(rec.counts.items())), flush=True)
            time.sleep(0.05)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        obs.tap = None
        rec.close()
    return rec.counts, interrupted


def read_recording(path: str | Path) -> Iterator[dict[str, Any]]:
    """Every well-formed line (a torn last line after a crash, or junk, is skipped)."""
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            try:
                d = json.loads(line)
            except ValueError:
                continue
            if isinstance(d, dict) and "kind" in d and isinstance(d.get("t"), (int, float)):
                yield d


LEGEND_MAX_UAVS = 20  # one colour each (tab20); more UAVs are told apart by the id at each track's end


def plot_recording(path: str | Path, out: str | Path | None = None) -> tuple[Path, dict[str, Any]]:
    """Trajectories (x/y), altitude, battery and the phase timeline of every UAV -> PNG."""
    import matplotlib.pyplot as plt

    fig, info = draw_recording(path)
    out = Path(out) if out else Path(path).with_suffix(".png")
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out, info


def draw_recording(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """The figure of a recording (matplotlib Figure, not saved) and what it holds.

    The trajectory panel has a legend (colour -> UAV) for up to LEGEND_MAX_UAVS UAVs, and every
    track ends in its UAV's id, so a colour that repeats in a larger swarm is still named."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    poses: dict[int, list[tuple[float, float, float, float]]] = {}
    battery: dict[int, list[tuple[float, float]]] = {}
    phases: dict[int, list[tuple[float, str, str]]] = {}
    t0 = math.inf
    n = 0
    for d in read_recording(path):
        n += 1
        t = float(d["t"])
        t0 = min(t0, t)
        kind, uav = d["kind"], d.get("uav")
        if not isinstance(uav, int):
            continue
        try:
            if kind == "pose":
                poses.setdefault(uav, []).append((t, float(d["x"]), float(d["y"]), float(d["z"])))
            elif kind == "telemetry" and d.get("battery") is not None and d["battery"] >= 0:
                battery.setdefault(uav, []).append((t, 100.0 * float(d["battery"])))
            elif kind == "state":
                timeline = phases.setdefault(uav, [])
                label = (str(d.get("phase")), str(d.get("override") or ""))
                if not timeline or timeline[-1][1:] != label:
                    timeline.append((t, *label))
        except (KeyError, TypeError, ValueError):
            continue
    if n == 0:
        raise ValueError(f"{path}: no recorded messages")
    fig, axes = plt.subplots(2, 2, figsize=(13, 9))
    ax_xy, ax_z, ax_b, ax_ph = axes[0][0], axes[0][1], axes[1][0], axes[1][1]
    cmap = plt.get_cmap("tab20")
    uavs = sorted(set(poses) | set(battery) | set(phases))
    color = {u: cmap(i % 20) for i, u in enumerate(uavs)}
    for u, pts in sorted(poses.items()):
        xs, ys = [p[1] for p in pts], [p[2] for p in pts]
        ax_xy.plot(xs, ys, lw=0.8, color=color[u], label=f"UAV {u}")
        ax_xy.plot(xs[-1:], ys[-1:], "o", ms=3, color=color[u])
        ax_xy.annotate(str(u), (xs[-1], ys[-1]), xytext=(3, 3), textcoords="offset points", fontsize=7, color=color[u])
        ax_z.plot([p[0] - t0 for p in pts], [p[3] for p in pts], lw=0.8, color=color[u])
    for u, samples in battery.items():
        ax_b.plot([s[0] - t0 for s in samples], [s[1] for s in samples], lw=0.8, color=color[u])
    palette: dict[str, Any] = {}
    for row, u in enumerate(uavs):
        segs = phases.get(u, [])
        for i, (t, ph, ov) in enumerate(segs):
            t_end = segs[i + 1][0] if i + 1 < len(segs) else max(t, _last_time(poses.get(u), t))
            name = ph if not ov else f"{ph} ({ov})"
            if name not in palette:
                palette[name] = cmap(len(palette) % 20)
            ax_ph.barh(row, max(t_end - t, 0.05), left=t - t0, color=palette[name], height=0.8,
                       label=name if name not in ax_ph.get_legend_handles_labels()[1] else None)
    ax_xy.set(title="trajectories (swarm frame)", xlabel="east x (m)", ylabel="north y (m)")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_z.set(title="altitude above the origin", xlabel="t (s)", ylabel="z (m)")
    ax_b.set(title="battery", xlabel="t (s)", ylabel="remaining (%)")
    ax_ph.set(title="agent phase (override)", xlabel="t (s)", ylabel="UAV")
    ax_ph.set_yticks(range(len(uavs)), [str(u) for u in uavs], fontsize=6 if len(uavs) > 30 else 8)
    if palette:
        ax_ph.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    if poses and len(poses) <= LEGEND_MAX_UAVS:
        ax_xy.legend(fontsize=7, loc="best", ncol=2 if len(poses) > 10 else 1, title="colour", title_fontsize=7)
    for ax in (ax_xy, ax_z, ax_b):
        ax.grid(alpha=0.3)
    fig.suptitle(f"{Path(path).name}: {len(uavs)} UAVs, {n} messages")
    fig.tight_layout()
    return fig, {"messages": n, "uavs": len(uavs), "poses": sum(len(p) for p in poses.values())}


def _last_time(pts: list[tuple[float, float, float, float]] | None, default: float) -> float:
    return pts[-1][0] if pts else default
