"""Holding the virtual FCU to recordings of the real firmware (tests/captures.py).

A :class:`Replay` boots one virtual vehicle on the firmware's own timeline (``boot="firmware"``), often
faster than real time, and talks to it over real UDP MAVLink as the recorder talked to the real
autopilot: as sysid 255 / compid 190, with a GCS HEARTBEAT every second, listening from launch (the FCU
streams to the replay's socket as SITL streamed to the recorder's). Everything is timed on the FCU's
sim clock, so a capture's "t = 10 s after launch" is 10 s of sim time whatever the RTF; every message
received is stamped with the sim time it arrived at. The comparisons below read their expected values
from the capture's summary.json, and allow for what cannot match exactly (rates measured over a window
of a few seconds, a sim that steps in 20 ms).
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from tests import captures
from tests.fcu_helpers import FcuThread, MavClient
from uav_stack.fcu import FcuConfig, VehicleConfig
from uav_stack.geo import GeoPoint

# The homes the captures were flown from (ArduCopter SITL's --home; PX4 SIH's default)
HOMES = {captures.ARDUPILOT: (GeoPoint(-35.363261, 149.165230, 584.09), math.radians(353.0)),
         captures.PX4: (GeoPoint(47.3977433, 8.5455924, 489.5), 0.0)}  # fmt: skip
FLAVOUR = {captures.ARDUPILOT: "ardupilot", captures.PX4: "px4"}
GCS_SYSID, GCS_COMPID = 255, 190
# Messages that come when something happens, not at a rate: never compared as streams
EVENT_LIKE = frozenset({"STATUSTEXT", "PARAM_VALUE", "COMMAND_ACK", "EVENT", "GPS_GLOBAL_ORIGIN", "MESSAGE_INTERVAL",
                        "AUTOPILOT_VERSION", "MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK", "MISSION_COUNT",
                        "MISSION_ITEM_INT", "MISSION_ITEM_REACHED", "HEARTBEAT"})  # fmt: skip
# (HEARTBEAT is checked apart: assert_heartbeat_rate)


@dataclass(frozen=True)
class Sent:
    """One message the recorder sent (not its heartbeats): seconds after launch, and the message."""

    t: float
    msg: Any


def launch_offset(autopilot: str, capture: str) -> float:
    """tlog wall time minus the summary's t (s after launch), from the first vehicle heartbeat."""
    s = captures.summary(autopilot, capture)
    first = s["first_heartbeat_t"] if autopilot == captures.PX4 else s["first_of_each_rx_type"]["HEARTBEAT"]["t"]
    for f in captures.frames(autopilot, capture):
        if f.msg.get_type() == "HEARTBEAT" and f.msg.get_srcSystem() == 1:
            return float(f.t - first)
    raise AssertionError(f"{autopilot}/{capture}: no vehicle heartbeat")


def sent_by_recorder(autopilot: str, capture: str, skip: tuple[str, ...] = ("HEARTBEAT",)) -> list[Sent]:
    """What the recorder sent in a capture, in order, from its tlog (the summaries list the same)."""
    off = launch_offset(autopilot, capture)
    return [Sent(round(f.t - off, 3), f.msg) for f in captures.frames(autopilot, capture)
            if f.msg.get_srcSystem() == GCS_SYSID and f.msg.get_type() not in skip]  # fmt: skip


def received_in_capture(autopilot: str, capture: str) -> Iterator[tuple[float, Any]]:
    """What the vehicle sent in a capture: (seconds after launch, message)."""
    off = launch_offset(autopilot, capture)
    for f in captures.frames(autopilot, capture):
        if f.msg.get_srcSystem() == 1:
            yield round(f.t - off, 3), f.msg


def rate_windows(autopilot: str, capture: str) -> list[tuple[str, float, float, dict[str, float]]]:
    """(label, t from, t to, rates in Hz by message type) of each window the summary measured."""
    s = captures.summary(autopilot, capture)
    if autopilot == captures.ARDUPILOT:
        return [(w["label"], float(w["t_start"]), float(w["t_end"]), w["rates_hz"]) for w in s["rate_windows"]]
    return [(k, float(w["t_from"]), float(w["t_to"]), w["rates_hz"]) for k, w in s["window_rates"].items()]


class Replay:
    """One virtual vehicle of a capture's firmware, and a recorder-like GCS on real UDP beside it."""

    def __init__(self, autopilot: str, rtf: float = 4.0, physics_hz: float = 50.0, boot: str = "firmware",
                 params: dict[str, float] | None = None, gcs_heartbeat: bool = True) -> None:  # fmt: skip
        home, yaw = HOMES[autopilot]
        self.autopilot = autopilot
        self.client = MavClient(("127.0.0.1", 9), sysid=GCS_SYSID, compid=GCS_COMPID)  # target set below
        local = self.client.sock.getsockname()[:2]
        vc = VehicleConfig(sysid=1, home=home, yaw=yaw, flavour=FLAVOUR[autopilot], boot=boot, params=dict(params or {}),
                           remotes=((local[0], local[1]),))  # fmt: skip
        self.ft = FcuThread(FcuConfig([vc], physics_hz=physics_hz, target_rtf=rtf), ready=False)
        self.client.target = self.ft.addrs[0]
        self.vehicle = self.ft.fcu.vehicles[0]
        self.rx: list[tuple[float, Any]] = []  # (sim s, message) of everything received
        self.hb_wall: list[float] = []  # wall time of each vehicle heartbeat
        self.gcs_heartbeat = gcs_heartbeat
        self._next_gcs_hb = 0.0
        self._seen_vehicle = False

    def __enter__(self) -> Replay:
        self.ft.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.ft.__exit__(*exc)
        self.client.close()

    # ------------------------------------------------------------------ time
    @property
    def now(self) -> float:
        """The FCU's sim time (s after launch)."""
        return self.ft.fcu.sim_time

    def pump(self, wall_s: float = 0.02) -> None:
        for m in self.client.pump(wall_s):
            self.rx.append((self.now, m))
            self._seen_vehicle = True  # the recorder heartbeats from the vehicle's first packet on
            if m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1:
                self.hb_wall.append(time.monotonic())
        if self.gcs_heartbeat and self._seen_vehicle and self.now >= self._next_gcs_hb:
            self._next_gcs_hb = self.now + 1.0  # the recorder's 1 Hz, on the sim clock
            self.client.heartbeat()

    def until(self, t: float, wall_limit: float = 120.0) -> None:
        """Run (receiving, heartbeating) until the sim clock reaches ``t``."""
        deadline = time.monotonic() + wall_limit
        while self.now < t:
            assert time.monotonic() < deadline, f"sim time {self.now:.1f} s never reached {t:.1f} s"
            self.pump()

    def wait_for(self, pred: Callable[[], bool], sim_s: float, wall_limit: float = 120.0) -> bool:
        end = self.now + sim_s
        deadline = time.monotonic() + wall_limit
        while self.now < end and time.monotonic() < deadline:
            if pred():
                return True
            self.pump()
        return pred()

    def send(self, msg: Any) -> None:
        self.client.send(msg)

    def replay(self, sent: list[Sent], until: float | None = None) -> None:
        """Send the recorder's messages at their times after launch (then run until ``until``)."""
        for s in sent:
            self.until(s.t)
            self.send(resend(self.client, s.msg))
        if until is not None:
            self.until(until)

    def upload(self, items: list[Any]) -> list[tuple[str, int]]:
        """The mission protocol's upload, answering each of the vehicle's requests with the item it names;
        returns the requests as (message type, seq). The vehicle's MISSION_ACK ends it."""
        t0 = self.now
        self.send(self.client.mav.mission_count_encode(1, 1, len(items), 0))
        answered: list[tuple[str, int]] = []

        def requests() -> list[tuple[str, int]]:
            return [(m.get_type(), m.seq) for t, m in self.rx if t >= t0 and m.get_srcSystem() == 1
                    and m.get_type() in ("MISSION_REQUEST", "MISSION_REQUEST_INT")]  # fmt: skip

        def acked() -> bool:
            return any(m.get_srcSystem() == 1 for _, m in self.of("MISSION_ACK", t0))

        while not acked():
            n = len(answered)
            assert self.wait_for(lambda k=n: len(requests()) > k or acked(), 2.0), "the upload stalled"
            for req in requests()[n:]:
                self.send(resend(self.client, items[req[1]]))
                answered.append(req)
        return answered

    def download(self, count: int) -> dict[int, Any]:
        """The mission protocol's download: MISSION_REQUEST_LIST, then each item by MISSION_REQUEST_INT."""
        t0 = self.now
        self.send(self.client.mav.mission_request_list_encode(1, 1, 0))
        assert self.wait_for(lambda: bool(self.of("MISSION_COUNT", t0)), 2.0)
        got: dict[int, Any] = {}
        for seq in range(count):
            self.send(self.client.mav.mission_request_int_encode(1, 1, seq, 0))
            assert self.wait_for(lambda q=seq: any(m.seq == q for _, m in self.of("MISSION_ITEM_INT", t0)), 2.0)
            got[seq] = next(m for _, m in self.of("MISSION_ITEM_INT", t0) if m.seq == seq)
        self.send(self.client.mav.mission_ack_encode(1, 1, 0, 0))
        return got

    # ------------------------------------------------------------- results
    def of(self, name: str, t0: float = -math.inf, t1: float = math.inf) -> list[tuple[float, Any]]:
        return [(t, m) for t, m in self.rx if m.get_type() == name and t0 <= t < t1]

    def rates(self, t0: float, t1: float) -> dict[str, float]:
        n = Counter(m.get_type() for t, m in self.rx if t0 <= t < t1 and m.get_srcSystem() == 1)
        return {k: c / (t1 - t0) for k, c in n.items()}

    def texts(self) -> list[tuple[float, int, str]]:
        return [(t, m.severity, m.text) for t, m in self.of("STATUSTEXT")]

    def acks(self) -> list[tuple[int, int]]:
        return [(m.command, m.result) for _, m in self.of("COMMAND_ACK")]

    def heartbeat_states(self) -> list[tuple[float, int, int, int]]:
        """(t, custom_mode, base_mode, system_status) at every change, as the summaries list them."""
        out: list[tuple[float, int, int, int]] = []
        for t, m in self.of("HEARTBEAT"):
            key = (m.custom_mode, m.base_mode, m.system_status)
            if not out or out[-1][1:] != key:
                out.append((t, *key))
        return out

    def field_changes(self, name: str, field: str) -> list[tuple[float, Any]]:
        out: list[tuple[float, Any]] = []
        for t, m in self.of(name):
            v = getattr(m, field)
            if not out or out[-1][1] != v:
                out.append((t, v))
        return out


def resend(client: MavClient, msg: Any) -> Any:
    """A captured message, as the replay's client's own (its fields, our sequence numbers)."""
    name = msg.get_type().lower()
    fields = [v.encode() if isinstance(v, str) else v for v in (getattr(msg, f) for f in msg.get_fieldnames())]
    return getattr(client.mav, f"{name}_encode")(*fields)


def extra_heartbeats(r: Replay, period: float = 1.0) -> list[float]:
    """Times of the heartbeats sent besides the 1 Hz cadence: sooner than a period after the last regular one
    (the regular ones are a period apart or a little more)."""
    extra, last = [], -math.inf
    for t, m in r.of("HEARTBEAT"):
        if m.get_srcSystem() != 1:
            continue
        if t - last >= 0.97 * period:
            last = t
        else:
            extra.append(t)
    return extra


def assert_heartbeat_rate(r: Replay, t0: float, t1: float) -> None:
    """HEARTBEAT at 1 Hz of sim time (the emulator keeps at least 1 Hz of wall time too: a sim behind its
    target RTF sends a little more often)."""
    n = sum(1 for t, m in r.of("HEARTBEAT", t0, t1) if m.get_srcSystem() == 1)
    assert 0.85 <= n / (t1 - t0) <= 1.35, n / (t1 - t0)


def capture_heartbeats(autopilot: str, capture: str) -> list[tuple[float, int, int, int]]:
    s = captures.summary(autopilot, capture)
    return [(h["t"], h["custom_mode"], h["base_mode"], h["system_status"]) for h in s["heartbeat_transitions"]]


def capture_acks(autopilot: str, capture: str) -> list[tuple[int, int]]:
    return [(a["command"], a["result"]) for a in captures.summary(autopilot, capture)["command_acks"]]


def assert_rates_like(expected: dict[str, float], got: dict[str, float], window_s: float, where: str,
                      ignore: frozenset[str] = frozenset()) -> None:  # fmt: skip
    """Every stream of the capture at its rate, and no stream it lacks: within 10 %, or a message and a half
    over the window, whichever is more (windows of 10-20 s measure to about 0.1 Hz)."""
    skip = EVENT_LIKE | ignore
    names = {n for n in expected if n not in skip and expected[n] >= 0.3} | {
        n for n in got if n not in skip and got[n] >= 0.3}
    bad = {}
    for n in sorted(names):
        e, g = expected.get(n, 0.0), got.get(n, 0.0)
        if abs(g - e) > max(0.1 * e, 1.5 / window_s, 0.15):
            bad[n] = (round(e, 2), round(g, 2))
    assert not bad, f"{where}: rates (capture, emulator) differ: {bad}"


def transitions_like(expected: list[tuple[float, int, int, int]], got: list[tuple[float, int, int, int]],
                     t_tol: float | None = None) -> None:  # fmt: skip
    """The same heartbeat states in the same order (and, with ``t_tol``, at about the same times)."""
    assert [e[1:] for e in expected] == [g[1:] for g in got], f"heartbeat states: capture {expected}, emulator {got}"
    if t_tol is not None:
        for e, g in zip(expected, got, strict=True):
            assert abs(e[0] - g[0]) <= t_tol, f"heartbeat state {e[1:]} at {g[0]:.2f} s, capture {e[0]:.2f} s"

