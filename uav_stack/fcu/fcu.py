"""VirtualFcu: a fleet of N virtual vehicles stepped together, one MAVLink link per vehicle.

A vehicle's link is a UDP socket, or, for a vehicle whose agent runs in the FCU's own process (a
pool of virtual UAVs), an in-process channel (``VehicleConfig.inproc``, :mod:`uav_stack.inproc`).

Single-threaded and non-blocking. A host loop calls ``poll_io()`` when a socket is readable
and ``service()`` when the deadline it returned has come (``run()`` does this with a
selector); a virtual UAV process instead calls both once per tick of its fixed-rate loop
(:func:`uav_stack.runtime.run_loop`), and the FCU catches up on the steps that fell due.
"""

from __future__ import annotations

import logging
import math
import selectors
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from uav_stack.fcu.clock import SimClock
from uav_stack.fcu.config import FcuConfig
from uav_stack.fcu.dynamics import MultirotorArray
from uav_stack.fcu.handlers import HANDLERS, Handler, addressed_to
from uav_stack.fcu.link import InprocLink, UdpLink
from uav_stack.fcu.stats import FcuStats
from uav_stack.fcu.vehicle import FleetContext, Vehicle
from uav_stack.rtf import RtfMeter

log = logging.getLogger("uav_stack.fcu")

SUPERVISOR_HZ = 10.0
ERROR_LOG_FIRST = 5  # per message type, then every 1000th


@dataclass
class VehicleTruth:
    """Ground truth of one vehicle, for loggers (sim time, local NED at the initial home)."""

    sysid: int
    sim_time: float
    pos_ned: tuple[float, float, float]
    vel_ned: tuple[float, float, float]
    yaw: float
    armed: bool
    mode: str
    landed: bool
    battery_remaining: float  # 0..1
    lat: float
    lon: float
    alt_amsl: float


class VirtualFcu:
    def __init__(self, config: FcuConfig, clock: Callable[[], float] = time.monotonic):
        self.config = config
        self._wall = clock
        self.stats = FcuStats()
        # a late host drops backlog in whole 0.1 s: the telemetry's 10 Hz grid (StreamSet) keeps its phase
        self.clock = SimClock(config.physics_hz, config.target_rtf, config.max_catchup_s,
                              phase_steps=max(1, round(0.1 * config.physics_hz)))
        # the sim clock is read exactly (no network jitter): a short span already measures well
        self._meter = RtfMeter(sample_every_s=0.25, min_span_s=0.05)
        yaws = np.array([float(v.yaw) for v in config.vehicles])
        self.dyn = MultirotorArray(len(config.vehicles), config.dynamics, yaw=yaws)
        self.ctx = FleetContext(
            clock=self.clock,
            dyn=self.dyn,
            stats=self.stats,
            rtf=lambda: self.rtf,
            wall=clock,
            unix_at_start=time.time(),
            log=log,
        )
        self.vehicles: list[Vehicle] = []
        self._dirty: list[UdpLink] = []  # links with queued (coalesced) output
        for i, vc in enumerate(config.vehicles):
            link = (InprocLink if vc.inproc else UdpLink)(
                tuple(vc.listen),  # type: ignore[arg-type]
                tuple(vc.remotes),
                config.max_peers,
                config.peer_timeout_s,
                owner=tuple(vc.owner) if vc.owner is not None else None,  # type: ignore[arg-type]
                owner_only=vc.owner_only,
                stats=self.stats,
                coalesce=config.coalesce_datagrams,
                dirty=self._dirty,
            )
            self.vehicles.append(Vehicle(i, vc, self.ctx, config.stream_rates, link))
        self._by_fd: dict[int, Vehicle] = {}
        # message type -> handler(vehicle, msg); per instance, so a host can add its own
        self.handlers: dict[str, Handler] = dict(HANDLERS)
        self._sup_every = max(1, round(config.physics_hz / SUPERVISOR_HZ))
        self._batch_steps = max(1, int(config.max_step_batch_s * config.physics_hz + 1e-9))
        self._next_hb_wall = math.inf
        self._next_peer_check = 0.0
        self._opened = False

    # ----------------------------------------------------------- lifecycle
    def open(self, start: float | None = None) -> list[tuple[str, int]]:
        """Bind every vehicle's socket (or open its in-process channel); return the bound (host, port)
        per vehicle (an in-process one's address, ``("inproc:<name>", 0)``; ``link.url`` is what its agent opens).

        ``start``: the time on the FCU's clock (s, at most a step or so before now) from which
        the simulation runs, so that its steps, and the telemetry on every 10 Hz step, fall on a
        grid of the caller's (aligned ticks); default now."""
        if self._opened:
            return [v.link.address for v in self.vehicles]
        addrs: list[tuple[str, int]] = []
        try:
            for v in self.vehicles:
                addrs.append(v.link.open())
        except OSError:
            for v in self.vehicles:
                v.link.close()
            raise
        self._by_fd = {v.link.fileno(): v for v in self.vehicles if v.link.fileno() >= 0}
        now = self._wall()
        self.clock.start(now if start is None else min(start, now))
        self._meter.restart()
        self._meter.add(now, 0.0)
        self.ctx.unix_at_start = time.time()
        n = len(self.vehicles)
        for k, v in enumerate(self.vehicles):  # the first heartbeat when the boot sends it; spread over 1 s
            first = max(0.0, v.boot.at["heartbeat"]) / self.config.target_rtf
            v.next_hb_wall = now + first + self.config.heartbeat_offset_s + (k / n) * min(1.0, v.hb_interval_wall)
        self._next_hb_wall = min(v.next_hb_wall for v in self.vehicles)
        self._opened = True
        return addrs

    def fds(self) -> list[int]:
        """The sockets' descriptors (an in-process link has none)."""
        return [fd for fd in (v.link.fileno() for v in self.vehicles) if fd >= 0]

    def close(self) -> None:
        self._flush()
        for v in self.vehicles:
            v.link.close()

    def __enter__(self) -> VirtualFcu:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- I/O
    def poll_io(self, ready_fds: Iterable[int] | None = None, vehicles: Iterable[Vehicle] | None = None) -> None:
        """Read and handle every pending datagram (optionally only on the given fds, or of the given vehicles)."""
        if ready_fds is not None:
            vehicles = [self._by_fd[fd] for fd in ready_fds if fd in self._by_fd]
        elif vehicles is None:
            vehicles = self.vehicles
        wall = self._wall()
        if self._opened:
            self._advance(wall)  # handle messages against the state at their arrival
        for v in vehicles:
            for data, addr in v.link.recv():
                self._on_datagram(v, data, addr, wall)
        self._flush()

    def _on_datagram(self, v: Vehicle, data: bytes, addr: tuple[str, int], wall: float) -> None:
        st = self.stats
        st.datagrams_in += 1
        st.bytes_in += len(data)
        if not v.link.admits(addr):
            st.foreign_datagrams += 1
            return
        msgs, clean = v.parser.parse(data)
        if not clean:
            st.bad_datagrams += 1
        if not msgs:
            return
        if v.link.note_peer(addr, wall) and v.now >= v.boot.at["heartbeat"]:
            v.send_heartbeat()  # a new peer learns about us at once (fast discovery), once the boot sends heartbeats
        for m in msgs:
            name = m.get_type()
            st.messages_in[name] += 1
            if m.get_srcSystem() == v.sysid and m.get_srcComponent() == v.compid:
                continue  # our own echo
            handler = self.handlers.get(name)
            if handler is None:
                continue
            try:
                if not addressed_to(v, m):
                    st.not_for_us += 1
                    continue
                handler(v, m)
            except Exception:
                self._handler_error(v, name)

    def _handler_error(self, v: Vehicle, where: str) -> None:
        st = self.stats
        st.handler_errors += 1
        st.handler_errors_by_type[where] += 1
        k = st.handler_errors_by_type[where]
        if k <= ERROR_LOG_FIRST or k % 1000 == 0:
            log.exception("sysid %d: handling %s failed (%d so far); vehicle continues", v.sysid, where, k)

    # ------------------------------------------------------------ service
    def _next_tel_step(self) -> int:
        vs = self.vehicles
        tel = vs[0].streams.next_any if len(vs) == 1 else min(v.streams.next_any for v in vs)  # (a UAV's FCU has one)
        return math.ceil(tel * self.clock.physics_hz - 1e-6) if tel < math.inf else 1 << 62

    def _advance(self, now: float) -> None:
        """Run the physics steps due by ``now``; supervisor ticks and telemetry at their steps.

        Steps between two such events are handed to the dynamics as one multi-step call.
        """
        clock, dyn, vehicles = self.clock, self.dyn, self.vehicles
        n = clock.due_steps(now)
        dt = clock.dt
        sup = self._sup_every
        while n > 0:
            steps = clock.steps
            k = min(n, (steps // sup + 1) * sup - steps, max(1, self._next_tel_step() - steps))
            dyn.step(dt, k)
            clock.advance(k)
            n -= k
            sim = clock.sim_time
            if clock.steps % sup == 0:
                for v in vehicles:
                    try:
                        v.tick(sim)
                    except Exception:
                        self._handler_error(v, "supervisor")
            for v in vehicles:
                try:
                    v.send_due_telemetry(sim)
                except Exception:
                    self._handler_error(v, "telemetry")
        self.stats.physics_steps = clock.steps
        self.stats.dropped_wall_s = clock.dropped_wall_s

    def _flush(self) -> None:
        dirty = self._dirty
        while dirty:
            dirty.pop().flush()

    def service(self, now: float | None = None) -> float:
        """Run due physics steps, supervisor ticks (failsafes) and telemetry.

        Returns the wall time of the next deadline: the next step at which telemetry or a
        supervisor tick is due, or a heartbeat, and at most ``max_step_batch_s`` away.
        Physics steps in between are run in a batch then, each with its own fixed sim dt
        (fewer wake-ups: a sleeping loop's wake-up costs more than a warm step).
        """
        if not self._opened:
            raise RuntimeError("VirtualFcu.open() first")
        if now is None:
            now = self._wall()
        self._advance(now)
        clock, vehicles = self.clock, self.vehicles
        self._meter.add(now, clock.sim_time)
        # heartbeats are paced on wall time: link liveness must not depend on the RTF
        if now >= self._next_hb_wall:
            nxt = math.inf
            for v in vehicles:
                if now >= v.next_hb_wall:
                    try:
                        v.send_heartbeat()
                    except Exception:
                        self._handler_error(v, "heartbeat")
                        v.next_hb_wall = now + v.hb_interval_wall
                nxt = min(nxt, v.next_hb_wall)
            self._next_hb_wall = nxt
            if now >= self._next_peer_check:
                self._next_peer_check = now + 1.0
                for v in vehicles:
                    v.link.expire_peers(now)
        self._flush()
        # next step that must happen at its own wall time; heartbeats ride along (<= one
        # batch late) unless no step wake-up comes soon enough
        steps = clock.steps
        k = (steps // self._sup_every + 1) * self._sup_every
        k = min(k, steps + self._batch_steps, max(steps + 1, self._next_tel_step()))
        wake = min(clock.wall_of_step(k), self._next_hb_wall + self.config.max_step_batch_s)
        clock.plan_wake(wake)
        return wake

    def run(self, duration: float | None = None, stop: threading.Event | None = None) -> None:
        """Standalone loop: service + select on the sockets until duration/stop."""
        if any(isinstance(v.link, InprocLink) for v in self.vehicles):  # nothing would wake the loop for them
            raise RuntimeError("VirtualFcu.run: in-process links have no socket to wait on; the host's loop "
                               "drives them (poll_io, service)")
        if not self._opened:
            self.open()
        sel = selectors.DefaultSelector()
        for fd in self.fds():
            sel.register(fd, selectors.EVENT_READ)
        end = self._wall() + duration if duration is not None else math.inf
        max_wait = 0.25  # bounds the reaction to ``stop``; normally the FCU's own deadlines come first
        try:
            while stop is None or not stop.is_set():
                now = self._wall()
                if now >= end:
                    break
                nxt = self.service(now)
                timeout = min(max(0.0, nxt - self._wall()), end - now, max_wait)
                events = sel.select(timeout)
                if events:
                    self.poll_io([key.fd for key, _ in events])
        finally:
            sel.close()

    # ------------------------------------------------------------- observe
    @property
    def rtf(self) -> float:
        """Measured RTF over the last ~5 s of wall time; NaN until measured."""
        return self._meter.value

    @property
    def rtf_total(self) -> float:
        return self.clock.rtf_total(self._wall())

    @property
    def sim_time(self) -> float:
        return self.clock.sim_time

    def truth(self, i: int = 0) -> VehicleTruth:
        v = self.vehicles[i]
        d = self.dyn
        lat, lon, alt = v.geodetic()
        return VehicleTruth(
            sysid=v.sysid,
            sim_time=self.clock.sim_time,
            pos_ned=tuple(d.pos[i].tolist()),
            vel_ned=tuple(d.vel[i].tolist()),
            yaw=float(d.yaw[i]),
            armed=v.armed,
            mode=v.mode.name,
            landed=bool(d.landed[i]),
            battery_remaining=float(d.battery[i]),
            lat=lat,
            lon=lon,
            alt_amsl=alt,
        )
