"""Test helpers for the virtual FCU: a minimal pymavlink GCS client over a real UDP socket
and a context manager that runs a VirtualFcu in a background thread.

Every wait is bounded by a timeout.
"""

from __future__ import annotations

import math
import select
import socket
import threading
import time
from collections import deque
from collections.abc import Callable

from uav_stack.fcu.config import FcuConfig
from uav_stack.fcu.fcu import VirtualFcu
from uav_stack.fcu.link import DatagramParser
from uav_stack.mav import mavlink

M = mavlink
NAN = math.nan
PX4_MODE_NAMES = {
    (1, 0): "MANUAL", (2, 0): "ALTCTL", (3, 0): "POSCTL", (4, 1): "READY", (4, 2): "TAKEOFF", (4, 3): "HOLD",
    (4, 4): "MISSION", (4, 5): "RTL", (4, 6): "LAND", (5, 0): "ACRO", (6, 0): "OFFBOARD", (7, 0): "STABILIZED",
}  # fmt: skip


def px4_main_sub(custom_mode: int) -> tuple[int, int]:
    """(main, sub) mode of a PX4 HEARTBEAT.custom_mode: the inverse of ``px4_custom_mode``."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


class FcuThread:
    """``with FcuThread(cfg) as ft:`` runs ``ft.fcu.run()`` in a daemon thread; ``ft.addrs``.

    It enters once every vehicle has booted far enough to arm (1 s of sim time with the default short boot),
    as a ground station waits for the vehicle's health; ``ready=False`` enters at boot instead.
    """

    def __init__(self, config: FcuConfig, ready: bool = True):
        self.fcu = VirtualFcu(config)
        self.addrs = self.fcu.open()
        self.ready = ready
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self.fcu.run, kwargs={"stop": self._stop}, daemon=True)

    def __enter__(self) -> FcuThread:
        self._thread.start()
        if self.ready:
            deadline = time.monotonic() + 10.0
            while not all(v.gps_ok for v in self.fcu.vehicles) and time.monotonic() < deadline:
                time.sleep(0.02)
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)
        self.fcu.close()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()


class MavClient:
    """A GCS/companion endpoint: sends to one vehicle, parses every datagram it gets back."""

    def __init__(self, target: tuple[str, int], sysid: int = 245, compid: int = 190, target_sysid: int = 1):
        self.target = target
        self.target_sysid = target_sysid
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.mav = M.MAVLink(None, sysid, compid)
        self._parser = DatagramParser()
        self.latest: dict[str, M.MAVLink_message] = {}
        self.counts: dict[str, int] = {}
        self.statustexts: list[str] = []
        self.events: list[int] = []  # ids of PX4's EVENTs (PX4 sends no STATUSTEXT on its onboard link)
        self.received: list[M.MAVLink_message] = []  # everything, in order (bounded)
        self._queue: deque[M.MAVLink_message] = deque(maxlen=10_000)  # not yet consumed by recv_match

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> MavClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----------------------------------------------------------------- raw
    def send(self, msg: M.MAVLink_message) -> None:
        buf = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) & 0xFF
        self.sock.sendto(buf, self.target)

    def send_raw(self, data: bytes) -> None:
        self.sock.sendto(data, self.target)

    def pump(self, timeout: float) -> list[M.MAVLink_message]:
        """Receive for up to ``timeout`` s (returns early after the first datagram batch)."""
        out: list[M.MAVLink_message] = []
        r, _, _ = select.select([self.sock], [], [], max(0.0, timeout))
        if not r:
            return out
        for _ in range(1000):
            try:
                data, _addr = self.sock.recvfrom(65535)
            except BlockingIOError:
                break
            for m in self._parser.parse(data)[0]:
                t = m.get_type()
                self.latest[t] = m
                self.counts[t] = self.counts.get(t, 0) + 1
                if t == "STATUSTEXT":
                    self.statustexts.append(m.text)
                elif t == "EVENT":
                    self.events.append(m.id)
                if len(self.received) < 100_000:
                    self.received.append(m)
                out.append(m)
        self._queue.extend(out)
        return out

    def recv_match(
        self,
        types: str | tuple[str, ...],
        timeout: float = 2.0,
        cond: Callable[[M.MAVLink_message], bool] | None = None,
    ) -> M.MAVLink_message | None:
        """Next unconsumed message of one of ``types`` (others are skipped, like mavutil)."""
        types = (types,) if isinstance(types, str) else types
        deadline = time.monotonic() + timeout
        q = self._queue
        while True:
            while q:
                m = q.popleft()
                if m.get_type() in types and (cond is None or cond(m)):
                    return m
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.pump(min(left, 0.2))

    def wait(self, pred: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if pred():
                return True
            self.pump(min(0.05, max(0.0, deadline - time.monotonic())))
        return pred()

    def drain(self, seconds: float) -> None:
        """Receive (updating counts/latest) for ``seconds``; forget the unconsumed queue."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.pump(end - time.monotonic())
        self._queue.clear()

    # ------------------------------------------------------------ services
    def request_streams(self, hz: int = 10, also: tuple[str, ...] = ("EXTENDED_SYS_STATE", "HOME_POSITION")) -> None:
        """Ask an ArduPilot for its streams, as a ground station does: REQUEST_DATA_STREAM(ALL) and message
        intervals for the messages in no stream group (PX4 ignores the one and already sends the others)."""
        self.send(self.mav.request_data_stream_encode(self.target_sysid, 1, M.MAV_DATA_STREAM_ALL, hz, 1))
        for name in also:
            mid = getattr(M, f"MAVLINK_MSG_ID_{name}")
            self.send(self.mav.command_long_encode(self.target_sysid, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mid, 1e6 / hz,
                                                   0, 0, 0, 0, 0))  # fmt: skip

    def heartbeat(self, mav_type: int = M.MAV_TYPE_GCS) -> None:
        self.send(self.mav.heartbeat_encode(mav_type, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE))

    def _forget_acks(self, command: int) -> None:
        """Drop ACKs of an earlier ``command`` still queued (PX4 ACKs DO_SET_MODE twice)."""
        self.pump(0.0)
        self._queue = deque((m for m in self._queue if not (m.get_type() == "COMMAND_ACK" and m.command == command)),
                            maxlen=self._queue.maxlen)  # fmt: skip

    def command_long(self, command: int, *params: float, timeout: float = 2.0, confirmation: int = 0) -> int | None:
        self._forget_acks(command)
        p = [float(x) for x in params] + [0.0] * (7 - len(params))  # as ground stations pad them
        self.send(self.mav.command_long_encode(self.target_sysid, 1, command, confirmation, *p))
        ack = self.recv_match("COMMAND_ACK", timeout, lambda m: m.command == command)
        return None if ack is None else ack.result

    def command_int(self, command: int, frame: int, p1: float = NAN, p2: float = NAN, p3: float = NAN,
                    p4: float = NAN, x: int = 0, y: int = 0, z: float = NAN, timeout: float = 2.0) -> int | None:  # fmt: skip
        self._forget_acks(command)
        self.send(self.mav.command_int_encode(self.target_sysid, 1, frame, command, 0, 0, p1, p2, p3, p4, x, y, z))
        ack = self.recv_match("COMMAND_ACK", timeout, lambda m: m.command == command)
        return None if ack is None else ack.result

    def px4_mode(self) -> str | None:
        hb = self.latest.get("HEARTBEAT")
        if hb is None:
            return None
        return PX4_MODE_NAMES.get(px4_main_sub(hb.custom_mode), f"custom {hb.custom_mode}")

    def armed(self) -> bool:
        hb = self.latest.get("HEARTBEAT")
        return bool(hb and hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)

    def set_mode_px4(self, main: int, sub: int = 0) -> int | None:
        return self.command_long(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)

    def setpoint_local(self, x: float = NAN, y: float = NAN, z: float = NAN, vx: float = NAN, vy: float = NAN,
                       vz: float = NAN, yaw: float = NAN, frame: int = M.MAV_FRAME_LOCAL_NED) -> None:  # fmt: skip
        mask = 0
        for bit, val in ((1, x), (2, y), (4, z), (8, vx), (16, vy), (32, vz)):
            if val != val:
                mask |= bit
        mask |= 64 | 128 | 256 | 2048  # no acceleration, no yaw rate
        if yaw != yaw:
            mask |= 1024
        z0 = [0.0 if v != v else v for v in (x, y, z, vx, vy, vz, yaw)]
        self.send(
            self.mav.set_position_target_local_ned_encode(
                0, self.target_sysid, 1, frame, mask, z0[0], z0[1], z0[2], z0[3], z0[4], z0[5], 0, 0, 0, z0[6], 0
            )
        )

    def param_set(self, name: str, value: float, ptype: int = M.MAV_PARAM_TYPE_REAL32, timeout: float = 2.0):
        self.send(self.mav.param_set_encode(self.target_sysid, 1, name.encode(), value, ptype))
        return self.recv_match("PARAM_VALUE", timeout, lambda m: m.param_id == name)

    def param_read(self, name: str = "", index: int = -1, timeout: float = 2.0):
        self.send(self.mav.param_request_read_encode(self.target_sysid, 1, name.encode(), index))
        if index >= 0:
            return self.recv_match("PARAM_VALUE", timeout, lambda m: m.param_index == index)
        return self.recv_match("PARAM_VALUE", timeout, lambda m: m.param_id == name)

    def upload_mission(self, items: list[tuple[int, int, float, float, float, tuple[float, ...]]], timeout: float = 3.0,
                       mission_type: int = 0) -> int | None:  # fmt: skip
        """The mission protocol's upload: items (frame, command, lat deg, lon deg, alt m, params 1-4);
        returns the MISSION_ACK result (None: no answer)."""
        self.send(self.mav.mission_count_encode(self.target_sysid, 1, len(items), mission_type))
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = self.recv_match(("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"), deadline - time.monotonic())
            if m is None:
                return None
            if m.get_type() == "MISSION_ACK":
                return m.type
            frame, cmd, lat, lon, alt, params = items[m.seq]
            p = [float(x) for x in params] + [0.0] * (4 - len(params))
            self.send(self.mav.mission_item_int_encode(self.target_sysid, 1, m.seq, frame, cmd, int(m.seq == 0), 1, *p,
                                                       round(lat * 1e7), round(lon * 1e7), alt, mission_type))  # fmt: skip
        return None
