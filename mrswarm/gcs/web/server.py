"""``mrswarm gcs web``: the live map's server. One loopback port serves the page and its WebSocket.

The page (``static/``, shipped in the package, no external asset) draws what this server pushes
five times a second: every UAV's position, heading, phase, realm, link age and failsafe state, and
the commands sent from the page with each UAV's acknowledgement. On connecting, a page gets the
run's mission area, zones and hub, and every UAV's trail from the start of the run
(:mod:`mrswarm.gcs.web.scene`; with ``--run``, else the trails since the server started). Commands go through the same
:class:`~swarmnet.observer.SwarmObserver` as ``mrswarm gcs hold`` (the ground station's identity,
role ``gcs``), with the CLI's rules: only UAVs alive in the swarm, one re-send to the silent ones
halfway, ``timeout`` after :data:`COMMAND_TIMEOUT` s. The page offers hold, resume, land, rtl and
goto; arm, disarm and kill stay with the CLI, which asks for a confirmation.

Who may connect: the server listens on 127.0.0.1 unless told otherwise. Because any web page open
in the same browser could try to reach a loopback port, a WebSocket handshake is accepted only
from the map's own page (its ``Origin`` must be this server), and on loopback only requests
addressed to a loopback name (``Host``), which defeats DNS rebinding.
"""

from __future__ import annotations

import asyncio
import json
import math
import time
from dataclasses import dataclass, field
from http import HTTPStatus
from pathlib import Path
from typing import Any

from websockets.asyncio.server import ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from mrswarm.gcs.session import GcsError
from mrswarm.gcs.web.scene import Trails, recorded_trails, scene_of
from swarmnet.observer import PendingCommand, SwarmObserver

STATIC = Path(__file__).resolve().parent / "static"
FILES = {"/": ("index.html", "text/html; charset=utf-8"), "/index.html": ("index.html", "text/html; charset=utf-8"),
         "/map.js": ("map.js", "text/javascript; charset=utf-8"), "/style.css": ("style.css", "text/css; charset=utf-8")}
WS_PATH = "/ws"
PUSH_PERIOD = 0.2  # s between two pushes of the swarm's state to every page
POLL_PERIOD = 0.05  # s between two polls of the observer
COMMAND_TIMEOUT = 5.0  # s: as `mrswarm gcs <verb> --timeout`
VERBS = ("hold", "resume", "land", "rtl", "goto")
STALE_AFTER = 3.0  # s of silence: a UAV is drawn grey (as in `gcs watch`)
LOOPBACK = ("127.0.0.1", "localhost", "[::1]", "::1")
KEEP_COMMANDS = 30  # the page lists this many recent commands


@dataclass
class WebCommand:
    """A command sent from the page, with every target's outcome."""

    id: int
    verb: str
    targets: list[int]
    args: dict[str, Any]
    sent: float  # monotonic
    sent_wall: float
    pending: list[PendingCommand] = field(default_factory=list)
    resent: bool = False
    results: dict[int, dict[str, Any]] = field(default_factory=dict)  # uav -> status, message, latency_ms

    @property
    def done(self) -> bool:
        return len(self.results) == len(self.targets)

    def to_json(self) -> dict[str, Any]:
        per = [{"uav": u, **self.results.get(u, {"status": "pending", "message": "", "latency_ms": None})} for u in self.targets]
        return {"id": self.id, "verb": self.verb, "args": self.args, "t": self.sent_wall, "targets": per}


def uav_json(obs: SwarmObserver, uav: int, now: float, alive: set[int]) -> dict[str, Any] | None:
    v = obs.uavs.get(uav)
    if v is None or v.pose is None:
        return None
    p, st, tel = v.pose, v.state, v.telemetry
    seen = now - max(v.pose_recv, v.state_recv)
    override = st.override if st is not None else ""
    phase = st.phase if st is not None else ""
    return {
        "id": uav, "realm": p.realm.label, "x": round(p.x, 2), "y": round(p.y, 2), "z": round(p.z, 2), "yaw": round(p.yaw, 4),
        "speed": round(math.hypot(p.vx, p.vy, p.vz), 2), "phase": phase, "override": override,
        "detail": st.detail if st is not None else "", "mode": tel.mode if tel is not None else "",
        "armed": tel.armed if tel is not None else None,
        "battery": round(tel.battery, 3) if tel is not None and tel.battery >= 0 else None,
        "age_ms": round(max(0.0, v.pose_recv - p.t_wall) * 1000.0, 1), "seen_s": round(max(0.0, seen), 2),
        "stale": seen > STALE_AFTER, "alive": uav in alive,
        "failsafe": override.startswith("fcu:") or phase in ("yielded", "error", "killed"),
    }


class WebMap:
    """The server's state: one observer, the pages connected, the commands they sent."""

    def __init__(self, obs: SwarmObserver, host: str, port: int, run_dir: Path | None = None):
        self.obs = obs
        self.scene = scene_of(run_dir) if run_dir is not None else {}  # mission area, zones, hub
        self.trails = recorded_trails(run_dir) if run_dir is not None else Trails()  # from the run's start
        self.host = host
        self.port = port  # the bound port once serving (0 asks the system for one)
        self.clients: set[ServerConnection] = set()
        self.commands: list[WebCommand] = []
        self._next_id = 1
        self.stopping = False  # set from any thread: run() returns within a poll period

    # ---- HTTP: the page, and who may open the WebSocket ---------------------------------------
    def _allowed_host(self, host_header: str | None) -> bool:
        if self.host not in LOOPBACK:
            return True  # listening beyond loopback was asked for: any name the network uses
        if not host_header:
            return False
        name = host_header.rsplit(":", 1)[0] if not host_header.endswith("]") else host_header
        return name in LOOPBACK

    def process_request(self, connection: ServerConnection, request: Request) -> Response | None:
        host = request.headers.get("Host")
        if not self._allowed_host(host):
            return _text(HTTPStatus.FORBIDDEN, "forbidden host\n")
        path = request.path.split("?", 1)[0]
        if path == WS_PATH:
            if request.headers.get("Origin") != f"http://{host}":
                return _text(HTTPStatus.FORBIDDEN, "the map's WebSocket is for its own page only\n")
            return None  # go on with the WebSocket handshake
        entry = FILES.get(path)
        if entry is None:
            return _text(HTTPStatus.NOT_FOUND, "not found\n")
        body = (STATIC / entry[0]).read_bytes()
        headers = Headers({"Content-Type": entry[1], "Content-Length": str(len(body)), "Cache-Control": "no-store",
                           "X-Content-Type-Options": "nosniff", "Content-Security-Policy":
                           "default-src 'self'; connect-src 'self'; img-src 'self' data:; frame-ancestors 'none'"})
        return Response(200, "OK", headers, body)

    # ---- WebSocket: state out, commands in -----------------------------------------------------
    async def handler(self, ws: ServerConnection) -> None:
        self.clients.add(ws)
        try:
            await ws.send(json.dumps({"type": "hello", "swarm": self.obs.keys.swarm, "verbs": list(VERBS),
                                      "command_timeout_s": COMMAND_TIMEOUT, "scene": self.scene,
                                      "trails": self.trails.to_json()}))
            await ws.send(json.dumps(self.snapshot(time.time())))
            async for raw in ws:
                reply = self.on_message(raw)
                await ws.send(json.dumps(reply))
        except ConnectionClosed:
            pass
        finally:
            self.clients.discard(ws)

    def on_message(self, raw: str | bytes) -> dict[str, Any]:
        """A page's request -> the reply (never raises: bad input gets an error naming the field)."""
        try:
            msg = json.loads(raw)
            if not isinstance(msg, dict) or msg.get("op") != "command":
                raise GcsError("op: expected 'command'")
            return {"type": "sent", **self.send(msg.get("verb"), msg.get("uavs"), msg.get("args") or {}).to_json()}
        except (ValueError, GcsError) as exc:
            return {"type": "error", "message": str(exc)}

    def send(self, verb: Any, uavs: Any, args: Any) -> WebCommand:
        if verb not in VERBS:
            raise GcsError(f"verb: {verb!r} is not one of {', '.join(VERBS)}")
        if not isinstance(uavs, list) or not uavs or not all(type(u) is int for u in uavs):
            raise GcsError("uavs: expected a non-empty list of UAV ids")
        alive = self.obs.alive_uavs()
        unknown = sorted(set(uavs) - alive)
        if unknown:
            raise GcsError(f"uavs: {unknown} not alive in swarm '{self.obs.keys.swarm}'")
        cmd_args: dict[str, Any] = {}
        if verb == "goto":
            if not isinstance(args, dict):
                raise GcsError("args: expected x, y, z")
            for k in ("x", "y", "z"):
                v = args.get(k)
                if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                    raise GcsError(f"args.{k}: expected a finite number (m from the swarm origin), got {v!r}")
                cmd_args[k] = float(v)
        targets = sorted(set(uavs))
        c = WebCommand(self._next_id, verb, targets, cmd_args, time.monotonic(), time.time())
        self._next_id += 1
        c.pending.append(self.obs.command(verb, targets, cmd_args or None))
        self.commands.append(c)
        del self.commands[:-KEEP_COMMANDS]
        return c

    def track(self) -> None:
        """Collect acks; re-send once halfway to the silent targets; time out the rest (as the CLI does)."""
        now = time.monotonic()
        for c in self.commands:
            if c.done:
                continue
            for p in c.pending:
                for u, a in p.acks.items():
                    if u in c.targets and u not in c.results:
                        c.results[u] = {"status": "ok" if a.ok else "failed", "message": a.message,
                                        "latency_ms": round((now - c.sent) * 1000.0, 1)}
            silent = [u for u in c.targets if u not in c.results]
            if silent and not c.resent and now - c.sent >= COMMAND_TIMEOUT / 2:
                c.resent = True
                c.pending.append(self.obs.command(c.verb, silent, c.args or None))
            if silent and now - c.sent >= COMMAND_TIMEOUT:
                for u in silent:
                    c.results[u] = {"status": "timeout", "message": f"no acknowledgement within {COMMAND_TIMEOUT:g} s",
                                    "latency_ms": None}

    def snapshot(self, now: float) -> dict[str, Any]:
        alive = self.obs.alive_uavs()
        uavs = [d for u in sorted(set(self.obs.uavs) | alive) if (d := uav_json(self.obs, u, now, alive)) is not None]
        return {"type": "state", "t": now, "swarm": self.obs.keys.swarm, "uavs": uavs,
                "commands": [c.to_json() for c in reversed(self.commands)]}

    # ---- the loop -------------------------------------------------------------------------------
    async def run(self, duration: float | None = None, ready: Any = None) -> None:
        async with serve(self.handler, self.host, self.port, process_request=self.process_request, compression=None,
                         max_size=64 * 1024) as server:
            self.port = next(iter(server.sockets)).getsockname()[1]
            if ready is not None:
                ready(self.port)
            loop = asyncio.get_running_loop()
            end = loop.time() + duration if duration is not None else math.inf
            next_push = 0.0
            while loop.time() < end and not self.stopping:
                for p in self.obs.poll():
                    self.trails.add(p.uav, p.x, p.y)
                self.track()
                if loop.time() >= next_push:
                    next_push = loop.time() + PUSH_PERIOD
                    if self.clients:
                        data = json.dumps(self.snapshot(time.time()))
                        for ws in list(self.clients):
                            try:
                                await ws.send(data)
                            except ConnectionClosed:
                                self.clients.discard(ws)
                await asyncio.sleep(POLL_PERIOD)


def _text(status: HTTPStatus, text: str) -> Response:
    body = text.encode()
    return Response(status.value, status.phrase, Headers({"Content-Type": "text/plain; charset=utf-8",
                                                          "Content-Length": str(len(body))}), body)


def serve_web(obs: SwarmObserver, *, host: str = "127.0.0.1", port: int = 8088, duration: float | None = None,
              run_dir: Path | None = None) -> int:
    """Serve the map until Ctrl-C or ``duration`` s; returns the exit code (0, or 130 on Ctrl-C)."""
    if not 0 <= port <= 65535:
        raise GcsError(f"--port {port}: expected 0..65535")
    web = WebMap(obs, host, port, run_dir)

    def ready(bound: int) -> None:
        shown = f"[{host}]" if ":" in host else host
        print(f"live map of swarm {obs.keys.swarm}: http://{shown}:{bound}/ (Ctrl-C stops)", flush=True)

    try:
        asyncio.run(web.run(duration, ready))
    except OSError as exc:
        raise GcsError(f"cannot serve on {host}:{port}: {exc.strerror or exc}") from None
    except KeyboardInterrupt:
        return 130
    return 0
