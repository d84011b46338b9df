"""The agent's MAVLink link to its flight controller, whatever it is.

The agent reaches its FCU only through a pymavlink connection string, so one agent flies a
real Pixhawk (``serial:/dev/ttyACM0:921600``), PX4/ArduPilot SITL (``udpin:127.0.0.1:14540``)
or our virtual FCU (``udpout:127.0.0.1:<port>``; a pooled virtual UAV's ``inproc:<name>``, the same
datagrams through an in-process channel, :mod:`uav_stack.inproc`). Everything here is non-blocking: the
agent's loop calls :meth:`FcuLink.poll` and :meth:`FcuLink.service`; commands return a
:class:`CommandHandle` that resolves when the COMMAND_ACK arrives (retried like MAVSDK:
0.5 s timeout, 3 retries).

The link is locked to its FCU. A UDP link binds to one address (:mod:`uav_stack.fcu_udp`)
and drops datagrams from any other sender than the FCU (``udpout``: the address it sends to;
``udpin``: the sender of the first autopilot heartbeat). The first autopilot heartbeat also
pins the FCU's system and component id: from then on only that (sysid, compid) moves the
agent's view of its vehicle (mode, position, acks), so a forged heartbeat cannot make the
agent yield and a forged position cannot move its swarm pose. Everything ignored is counted
in :attr:`FcuLink.counts` (``foreign_source``, ``foreign_id``: another system or component than
the pinned FCU; ``before_heartbeat``; ``unknown_id``: a message of the FCU itself whose id the
dialect does not know).

Once pinned, the link runs its start-up contract (:mod:`uav_stack.fcu_contract`): it asks the
autopilot for the messages the agent needs and checks that they arrive.

**No position until the autopilot has one.** A GLOBAL_POSITION_INT is taken only when the
autopilot says it is a position: latitude and longitude not both 0 (ArduCopter sends zeros
until its GPS has a fix), the estimator using an absolute horizontal position when it reports
its flags (ArduPilot's EKF_STATUS_REPORT: POS_HORIZ_ABS set, not in constant-position mode nor
uninitialised; PX4's ESTIMATOR_STATUS: POS_HORIZ_ABS set), else a 3D GPS fix when GPS_RAW_INT
says. Any other is counted (``no_position``) and its reason kept (:attr:`FcuState.no_position`).
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from groundfloor.errors import MrswarmError
from groundfloor.net import Addr
from uav_stack.autopilot import (
    PX4_ARMING_SUMMARY,
    PX4_HEALTH_SUMMARY,
    PX4_PROFILE,
    AutopilotProfile,
    firmware_version,
    mode_name,
    profile_for,
    px4_event_text,
)
from uav_stack.fcu_contract import FcuContract
from uav_stack.fcu_udp import FcuUdpSocket, parse_udp_url
from uav_stack.inproc import InprocFcuSocket, parse_inproc_url
from uav_stack.mav import mavlink, mavutil
from uav_stack.mavcodec import MAVLink
from uav_stack.rtf import RtfMeter

log = logging.getLogger(__name__)

COMPANION_COMPONENT = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER  # 191
HEARTBEAT_TIMEOUT = 3.0  # s without a heartbeat = link lost (MAVSDK's default)
ACK_TIMEOUT = 0.5
ACK_RETRIES = 3
_RESULT_NAMES = {
    mavlink.MAV_RESULT_ACCEPTED: "accepted",
    mavlink.MAV_RESULT_TEMPORARILY_REJECTED: "temporarily_rejected",
    mavlink.MAV_RESULT_DENIED: "denied",
    mavlink.MAV_RESULT_UNSUPPORTED: "unsupported",
    mavlink.MAV_RESULT_FAILED: "failed",
    mavlink.MAV_RESULT_IN_PROGRESS: "in_progress",
}
# estimator flags that mean "no usable absolute position", by message (their flag enums differ: PX4
# sets ESTIMATOR_CONST_POS_MODE whenever it is disarmed on the ground, with a good GPS position)
_ESTIMATOR_BAD = {"EKF_STATUS_REPORT": mavlink.EKF_CONST_POS_MODE | mavlink.EKF_UNINITIALIZED, "ESTIMATOR_STATUS": 0}
_POS_HORIZ_ABS = mavlink.EKF_POS_HORIZ_ABS  # == ESTIMATOR_POS_HORIZ_ABS
_PREARM = mavlink.MAV_SYS_STATUS_PREARM_CHECK
_OCCASIONAL = frozenset({"EXTENDED_SYS_STATE", "SYS_STATUS", "GPS_RAW_INT", "EKF_STATUS_REPORT", "ESTIMATOR_STATUS",
                         "HOME_POSITION", "BATTERY_STATUS", "NAMED_VALUE_FLOAT", "COMMAND_ACK", "STATUSTEXT", "EVENT",
                         "AUTOPILOT_VERSION"})
REASON_SEVERITY = mavlink.MAV_SEVERITY_WARNING  # STATUSTEXTs (and PX4 EVENTs) at this level or worse are reasons
# type_mask for a NED velocity setpoint: ignore position, acceleration, yaw and yaw rate
VELOCITY_ONLY_MASK = (
    mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE
    | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
)


class LinkOpenError(OSError, MrswarmError):
    """One of the agent's MAVLink links cannot be opened: the FCU link (a udpin port another
    process holds, a serial device that is not there) or a ground-station endpoint of its router.
    The message names the setting (``fcu``, ``gcs.mavlink_endpoints``) and the link, so that the
    agent stops with one line that says what to change, not a traceback."""

    @classmethod
    def of(cls, setting: str, link: str, what: str, exc: OSError) -> LinkOpenError:
        err = cls(f"{setting}: {link}: cannot {what}: {exc.strerror or exc}")
        err.errno = exc.errno
        return err

    @classmethod
    def udp(cls, setting: str, link: str, mode: str, host: str, port: int, exc: OSError) -> LinkOpenError:
        """A UDP link's socket: a ``udpin`` one listens on host:port, a ``udpout`` one sends there."""
        return cls.of(setting, link, f"{'listen on' if mode == 'udpin' else 'send to'} {host}:{port}", exc)


def parse_fcu_url(url: str) -> Addr:
    """pymavlink connection strings, plus ``serial:<device>[:<baud>]`` (also ``serial://``, as
    MAVSDK writes it), which pymavlink would read as a UDP host:port. Returns (device, baud)."""
    if not url:
        raise ValueError("empty FCU connection string")
    if url.startswith("serial:"):
        rest = url[len("serial:"):]
        if rest.startswith("//"):
            rest = rest[2:]
        device, sep, baud = rest.rpartition(":")
        if not sep or not baud.isdigit():
            device, baud = rest, "57600"
        if not device:
            raise ValueError(f"no serial device in {url!r}; use serial:/dev/ttyACM0:921600")
        return device, int(baud)
    return url, 57600


@dataclass
class CommandHandle:
    """One COMMAND_LONG in flight: resolved by its COMMAND_ACK or by running out of retries."""

    command: int
    params: tuple[float, ...]
    sent_at: float
    attempts: int = 1
    result: int | None = None  # MAV_RESULT once acknowledged
    timed_out: bool = False

    @property
    def done(self) -> bool:
        return self.timed_out or (self.result is not None and self.result != mavlink.MAV_RESULT_IN_PROGRESS)

    @property
    def accepted(self) -> bool:
        return self.result == mavlink.MAV_RESULT_ACCEPTED

    @property
    def status(self) -> str:
        if self.timed_out:
            return "timeout"
        if self.result is None:
            return "pending"
        return _RESULT_NAMES.get(self.result, str(self.result))


@dataclass
class FcuState:
    """The latest telemetry, in the FCU's own terms (geodetic position, NED velocity)."""

    sysid: int = 0
    autopilot: int = 0  # HEARTBEAT.autopilot (MAV_AUTOPILOT_*)
    profile: AutopilotProfile = PX4_PROFILE  # chosen from ``autopilot`` at each heartbeat
    heartbeat_at: float = -math.inf  # wall time of the last heartbeat
    base_mode: int = 0
    custom_mode: int = 0
    mode: str = "UNKNOWN"
    armed: bool = False
    landed_state: int = mavlink.MAV_LANDED_STATE_UNDEFINED
    lat: float = math.nan
    lon: float = math.nan
    alt: float = math.nan  # AMSL, m
    relative_alt: float = math.nan
    vn: float = 0.0
    ve: float = 0.0
    vd: float = 0.0
    yaw: float = 0.0  # rad, NED (0 = north, clockwise)
    position_at: float = -math.inf  # wall time the latest GLOBAL_POSITION_INT arrived
    position_boot_s: float = 0.0  # its time_boot_ms, in s
    home: tuple[float, float, float] | None = None
    battery: float = -1.0  # remaining fraction
    voltage: float = -1.0
    rtf_reported: float = math.nan  # NAMED_VALUE_FLOAT "RTF" if the FCU publishes it
    statustext: deque[str] = field(default_factory=lambda: deque(maxlen=20))
    system_status: int = 0  # HEARTBEAT.system_status (MAV_STATE_*)
    position_ok: bool = False  # the latest GLOBAL_POSITION_INT was a position (see the module's doc)
    no_position: str = "no GLOBAL_POSITION_INT yet"  # why not, "" while it is
    gps_fix: int = -1  # GPS_RAW_INT.fix_type (-1: none seen)
    satellites: int = -1
    estimator: str = ""  # the message the flags came from (EKF_STATUS_REPORT, ESTIMATOR_STATUS)
    estimator_flags: int = -1  # its flags (-1: none seen)
    sensors_present: int = 0  # SYS_STATUS onboard_control_sensors_* (MAV_SYS_STATUS_SENSOR bits)
    sensors_health: int = 0
    sys_status_at: float = -math.inf
    version: str = ""  # "4.7.0-dev (2598e9d4)", from AUTOPILOT_VERSION
    capabilities: int = -1  # AUTOPILOT_VERSION.capabilities (MAV_PROTOCOL_CAPABILITY_*)
    # the autopilot's own words about problems: STATUSTEXT at WARNING or worse (ArduPilot's "Arm: ...",
    # "PreArm: ..."), PX4 EVENTs at WARNING or worse, by name; (wall time, text), newest last
    reasons: deque[tuple[float, str]] = field(default_factory=lambda: deque(maxlen=32))
    px4_checks: list[str] = field(default_factory=list)  # errors of PX4's latest arming-check report

    @property
    def has_position(self) -> bool:
        """A position the autopilot stands by (not zeros before a fix, not an estimator without GPS)."""
        return self.position_ok

    @property
    def prearm_ok(self) -> bool | None:
        """SYS_STATUS's pre-arm check bit: True/False as the autopilot reports it, None before a SYS_STATUS.

        PX4 and ArduPilot (and the virtual FCU) set its health while arming would pass in the current
        mode; PX4 leaves the "present" bit clear, so health alone is read for the autopilots known to
        report it, and the present bit decides for others."""
        if self.sys_status_at == -math.inf:
            return None
        if not (self.sensors_present & _PREARM) and self.autopilot not in (mavlink.MAV_AUTOPILOT_PX4,
                                                                          mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA):
            return None
        return bool(self.sensors_health & _PREARM)

    def reasons_since(self, t: float) -> list[str]:
        """The autopilot's reasons (texts, events) that arrived at or after wall time ``t``, oldest first, once each."""
        out: list[str] = []
        for at, text in self.reasons:
            if at >= t and text not in out:
                out.append(text)
        return out


class FcuLink:
    """Non-blocking MAVLink connection from the companion (agent) to one FCU."""

    def __init__(
        self,
        url: str,
        *,
        source_system: int = 1,
        source_component: int = COMPANION_COMPONENT,
        target_system: int | None = None,
        clock: Callable[[], float] = time.time,
        on_message: Callable[[Any], None] | None = None,
        bind: str | None = None,
        position_hz: float = 10.0,
        ask_streams: bool = True,
    ):
        self.url = url
        self.bind = bind  # local address of a UDP link (None: the one that routes to the FCU)
        self.source_system = source_system
        self.source_component = source_component
        self.target_system = target_system  # None: learn from the first autopilot heartbeat
        self.clock = clock
        self.on_message = on_message
        self.state = FcuState()
        self.rtf = RtfMeter()  # the FCU's time_boot_ms against our wall clock
        self.pending: dict[int, CommandHandle] = {}
        self.counts: dict[str, int] = {"rx": 0, "tx_setpoints": 0, "commands": 0, "bad": 0,
                                       "foreign_source": 0, "foreign_id": 0, "before_heartbeat": 0, "unknown_id": 0,
                                       "no_position": 0}
        self.rx_types: dict[str, int] = {}  # the pinned FCU's messages by type (the start-up contract reads them)
        # the start-up contract (uav_stack/fcu_contract.py): asks for what the agent needs once the FCU is pinned
        self.contract = FcuContract(self.rx_types, self._send_command_long, self._send_data_stream, position_hz=position_hz,
                                    ask=ask_streams, rtf=lambda: self.rtf.value)
        self.conn: Any = None
        # set for datagram links, UDP or in-process (then conn.mav writes through it)
        self.udp: FcuUdpSocket | InprocFcuSocket | None = None
        self.fcu_ids: tuple[int, int] | None = None  # (sysid, compid) pinned by the first autopilot heartbeat
        self._next_heartbeat = 0.0
        self._px4_report = False  # within a PX4 arming-check report (its summary event, then its checks)

    # ---- lifecycle ----------------------------------------------------------------------
    def open(self) -> FcuLink:
        """Open the link. A URL that is not one raises ValueError; a link that cannot be opened
        (a udpin port another process holds, a serial device that is not there) raises
        :class:`LinkOpenError`, which names the setting and the link."""
        name = parse_inproc_url(self.url)
        if name is not None:  # a pooled virtual UAV's vehicle, in this process: the same datagrams, no socket
            try:
                self.udp = InprocFcuSocket(name).open()
            except OSError as exc:
                raise LinkOpenError.of("fcu", self.url, "connect to the in-process FCU", exc) from exc
            self.conn = _UdpConnection(self.udp, self.source_system, self.source_component)
            return self
        udp = parse_udp_url(self.url)
        if udp is not None:
            mode, host, port = udp
            try:
                self.udp = FcuUdpSocket(mode, host, port, bind=self.bind).open()
            except OSError as exc:
                raise LinkOpenError.udp("fcu", self.url, mode, host, port, exc) from exc
            self.conn = _UdpConnection(self.udp, self.source_system, self.source_component)
            return self
        device, baud = parse_fcu_url(self.url)
        try:
            self.conn = mavutil.mavlink_connection(
                device, baud=baud, source_system=self.source_system, source_component=self.source_component, autoreconnect=True
            )
        except OSError as exc:
            raise LinkOpenError.of("fcu", self.url, f"open {device}", exc) from exc
        return self

    def close(self) -> None:
        if self.conn is not None:
            try:
                self.conn.close()
            finally:
                self.conn = None

    def summary(self) -> dict[str, Any]:
        """What the autopilot says of itself and what the start-up contract got (the UAV's status file)."""
        st = self.state
        return {
            "autopilot": st.profile.label if self.fcu_ids is not None else None, "version": st.version or None,
            "mode": st.mode, "system_status": st.system_status, "position": st.no_position or "ok",
            "gps_fix": st.gps_fix, "satellites": st.satellites, "estimator": st.estimator or None,
            "estimator_flags": st.estimator_flags, "prearm_ok": st.prearm_ok,
            "last_reasons": st.reasons_since(-math.inf)[-5:], **self.contract.as_dict(),
        }

    @property
    def local_address(self) -> Addr | None:
        """Where a datagram link sends from (the virtual FCU's owner address); None for other links."""
        return self.udp.local_address if self.udp is not None else None

    @property
    def connected(self) -> bool:
        return self.clock() - self.state.heartbeat_at < HEARTBEAT_TIMEOUT

    @property
    def target(self) -> int:
        return self.target_system or self.state.sysid or 1

    # ---- receive ------------------------------------------------------------------------
    def poll(self, max_messages: int = 500) -> int:
        """Read everything pending (bounded); return the number of messages handled.

        Reads raw bytes (a whole UDP datagram, or what a serial/TCP stream has) and parses
        them with the dialect's ``parse_buffer``, which keeps partial frames between calls.
        mavutil's ``recv_msg`` would make a syscall and run its own bookkeeping per message;
        the agent keeps its own state, so that is skipped.
        """
        n = 0
        conn, udp = self.conn, self.udp
        parse = conn.parse_datagram if udp is not None else conn.mav.parse_buffer
        datagrams: list[tuple[bytes, Addr]] = []  # (UDP: read all at once, then taken one by one)
        while n < max_messages or datagrams:  # (what was read is handled: at most a drain's 64 more)
            src: Addr | None = None
            try:
                if udp is not None:
                    if not datagrams:
                        datagrams = udp.recv_all()
                        if not datagrams:
                            break
                        datagrams.reverse()
                    data, src = datagrams.pop()
                else:
                    data = conn.recv(4096)
            except (OSError, ValueError) as exc:  # a dead serial port
                self.counts["bad"] += 1
                log.debug("fcu link: %s", exc)
                break
            if not data:
                if udp is not None:
                    continue  # an empty datagram
                break
            if udp is not None and src != udp.fcu and udp.fcu is not None:
                self.counts["foreign_source"] += 1  # another local process (or host) posing as the FCU
                continue
            try:
                msgs = parse(data) or ()
            except Exception as exc:  # pymavlink raises on some corrupt frames; count, never crash
                self.counts["bad"] += 1
                log.debug("fcu link: unparsable bytes: %s", exc)
                continue
            for msg in msgs:
                n += 1
                self._handle(msg, src)
        return n

    def _pins(self, msg: Any) -> bool:
        """Is ``msg`` the first heartbeat of an autopilot (ours, if ``target_system`` is set)?"""
        return (msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == mavlink.MAV_COMP_ID_AUTOPILOT1
                and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID and msg.get_srcSystem() != 0
                and (self.target_system is None or msg.get_srcSystem() == self.target_system))

    def _handle(self, msg: Any, src: Addr | None = None) -> None:
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            self.counts["bad"] += 1
            return
        self.counts["rx"] += 1
        ids = (msg.get_srcSystem(), msg.get_srcComponent())
        unknown = ids == (0, 0) and msg.get_msgId() == mavlink.MAVLINK_MSG_ID_UNKNOWN
        if unknown:  # an id the dialect does not know: pymavlink leaves its sender unset, the frame has it
            ids = _frame_ids(msg)
        if self.fcu_ids is None and not self._pin(msg, ids, src):
            return
        if self.on_message is not None:  # e.g. the MAVLink router: every frame of the FCU's link
            self.on_message(msg)
        if ids != self.fcu_ids:  # another component on the link (a camera, a forwarded GCS), or a forgery
            self.counts["foreign_id"] += 1
            return
        if unknown:  # the FCU's own message, of an id mrswarm's dialect lacks: not a forgery, just not understood
            self.counts["unknown_id"] += 1
            return
        types = self.rx_types
        types[mtype] = types.get(mtype, 0) + 1
        st = self.state
        if mtype == "GLOBAL_POSITION_INT":
            why = self._no_position(msg)
            if why:
                self.counts["no_position"] += 1
                st.no_position, st.position_ok = why, False
                return
            st.no_position, st.position_ok = "", True
            now = self.clock()
            st.lat, st.lon = msg.lat * 1e-7, msg.lon * 1e-7
            st.alt, st.relative_alt = msg.alt * 1e-3, msg.relative_alt * 1e-3
            st.vn, st.ve, st.vd = msg.vx * 0.01, msg.vy * 0.01, msg.vz * 0.01
            if msg.hdg != 65535:
                st.yaw = math.radians(msg.hdg * 0.01)
            st.position_at = now
            st.position_boot_s = msg.time_boot_ms * 1e-3
            self.rtf.add(now, st.position_boot_s)
        elif mtype == "ATTITUDE":
            st.yaw = msg.yaw
        elif mtype == "HEARTBEAT":
            self._heartbeat(msg, ids[0])
        elif mtype in _OCCASIONAL:  # one set lookup: a message handled nowhere (LOCAL_POSITION_NED...) costs no chain
            self._occasional(mtype, msg)

    def _pin(self, msg: Any, ids: tuple[int, int], src: Addr | None) -> bool:
        """Before the link is pinned: True if ``msg`` pins it (the autopilot's first heartbeat),
        False (counted) for anything that comes before."""
        if not self._pins(msg):
            self.counts["before_heartbeat"] += 1
            return False
        self.fcu_ids = ids
        if self.udp is not None and self.udp.fcu is None:  # udpin: the FCU is whoever sent its first heartbeat
            self.udp.fcu = src
        log.info("FCU link pinned to sysid %d compid %d%s", ids[0], ids[1], f" at {src[0]}:{src[1]}" if src else "")
        self.contract.start(profile_for(msg.autopilot), self.clock())
        return True

    def _heartbeat(self, msg: Any, sysid: int) -> None:
        st = self.state
        st.sysid = sysid
        if msg.autopilot != st.autopilot:
            st.autopilot = msg.autopilot
            st.profile = profile_for(msg.autopilot)
        st.heartbeat_at = self.clock()
        st.base_mode = msg.base_mode
        st.custom_mode = msg.custom_mode
        st.system_status = msg.system_status
        st.armed = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        st.mode = mode_name(msg)

    def _occasional(self, mtype: str, msg: Any) -> None:
        """The FCU's messages that come at a few Hz or less (state, health, answers, texts)."""
        st = self.state
        if mtype == "EXTENDED_SYS_STATE":
            st.landed_state = msg.landed_state
        elif mtype == "SYS_STATUS":
            self._sys_status(msg)
        elif mtype == "GPS_RAW_INT":
            st.gps_fix, st.satellites = msg.fix_type, msg.satellites_visible
        elif mtype == "EKF_STATUS_REPORT" or mtype == "ESTIMATOR_STATUS":
            st.estimator, st.estimator_flags = mtype, msg.flags
        elif mtype == "HOME_POSITION":
            st.home = (msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3)
        elif mtype == "BATTERY_STATUS":
            if msg.battery_remaining >= 0:
                st.battery = msg.battery_remaining / 100.0
        elif mtype == "NAMED_VALUE_FLOAT":
            if msg.name.rstrip("\x00") == "RTF":
                st.rtf_reported = msg.value
        elif mtype == "COMMAND_ACK":
            self._ack(msg)
        elif mtype == "STATUSTEXT":
            st.statustext.append(msg.text)
            if msg.severity <= REASON_SEVERITY:
                st.reasons.append((self.clock(), msg.text))
        elif mtype == "EVENT":
            self._event(msg)
        elif mtype == "AUTOPILOT_VERSION":
            self._version(msg)

    def _sys_status(self, msg: Any) -> None:
        st = self.state
        if msg.battery_remaining >= 0:
            st.battery = msg.battery_remaining / 100.0
        if msg.voltage_battery != 65535:
            st.voltage = msg.voltage_battery / 1000.0
        st.sensors_present, st.sensors_health = msg.onboard_control_sensors_present, msg.onboard_control_sensors_health
        st.sys_status_at = self.clock()

    def _ack(self, msg: Any) -> None:
        """A COMMAND_ACK addressed to us: a ground station's commands (through the router) are acknowledged on this
        link too, and must not resolve our own command of that number."""
        if msg.target_system not in (0, self.source_system) or msg.target_component not in (0, self.source_component):
            return
        h = self.pending.get(msg.command)
        if h is not None:
            h.result = msg.result
            if h.done:
                del self.pending[msg.command]
        else:
            self.contract.on_ack(msg.command, msg.result)

    def _version(self, msg: Any) -> None:
        """AUTOPILOT_VERSION: capabilities, and the firmware's version with its git hash."""
        st = self.state
        st.capabilities = msg.capabilities
        custom = bytes(msg.flight_custom_version)
        if st.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            custom = custom[::-1]  # PX4: the git hash's first bytes, least significant first
            tag = custom.hex()[:8] if any(custom) else ""
        else:  # ArduPilot: the git hash's first 8 characters
            tag = custom.rstrip(b"\x00").decode("ascii", "replace")
        st.version = firmware_version(msg.flight_sw_version) + (f" ({tag})" if tag else "")


    def _no_position(self, msg: Any) -> str:
        """Why a GLOBAL_POSITION_INT is not a position, "" if it is (see the module's doc)."""
        st = self.state
        if msg.lat == 0 and msg.lon == 0:
            return "latitude and longitude 0 (the autopilot has no position yet)"
        flags = st.estimator_flags
        if flags >= 0:
            bad = flags & _ESTIMATOR_BAD[st.estimator]
            if bad or not flags & _POS_HORIZ_ABS:
                what = ([] if flags & _POS_HORIZ_ABS else ["no absolute horizontal position"]) + \
                    (["constant-position mode"] if bad & mavlink.EKF_CONST_POS_MODE else []) + \
                    (["uninitialised"] if bad & mavlink.EKF_UNINITIALIZED else [])
                return f"the autopilot's estimator does not use GPS yet ({st.estimator} flags 0x{flags:x}: {', '.join(what)})"
        elif self.contract.awaits_estimator:
            return f"waiting for the autopilot's {st.profile.estimator} (does its estimator use GPS?)"
        elif 0 <= st.gps_fix < mavlink.GPS_FIX_TYPE_3D_FIX:
            return f"no 3D GPS fix (GPS_RAW_INT fix_type {st.gps_fix}, {st.satellites} satellites)"
        return ""

    def _event(self, msg: Any) -> None:
        """A PX4 EVENT: the ones at WARNING or worse become reasons (by name); an arming-check report's
        errors are kept until the next report (PX4 sends them when they change, not with each refusal)."""
        st = self.state
        level = msg.log_levels & 0x0F  # external log level (the internal one is the high nibble)
        if msg.id == PX4_ARMING_SUMMARY:
            st.px4_checks, self._px4_report = [], True
        elif msg.id == PX4_HEALTH_SUMMARY:
            self._px4_report = False
        elif self._px4_report and level <= mavlink.MAV_SEVERITY_ERROR:  # a failing check of the report, known or not
            st.px4_checks.append(px4_event_text(msg.id))
        if level <= REASON_SEVERITY:
            st.reasons.append((self.clock(), px4_event_text(msg.id)))

    # ---- send ---------------------------------------------------------------------------
    def service(self) -> None:
        """Heartbeat at 1 Hz, command retries and the start-up contract's checks; call often (every loop iteration)."""
        now = self.clock()
        if now >= self.contract.next_check:
            self.contract.check(now)
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + 1.0
            self.conn.mav.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                         mavlink.MAV_STATE_ACTIVE)
        for cmd, h in list(self.pending.items()):
            if h.result == mavlink.MAV_RESULT_IN_PROGRESS:
                timeout = 3.0
            else:
                timeout = ACK_TIMEOUT
            if now - h.sent_at > timeout:
                if h.attempts > ACK_RETRIES:
                    h.timed_out = True
                    del self.pending[cmd]
                else:
                    h.attempts += 1
                    h.sent_at = now
                    self._send_command_long(cmd, h.params, confirmation=h.attempts - 1)

    def write(self, data: bytes) -> None:
        """Raw MAVLink frames to the FCU as they are (the router forwards ground-station traffic)."""
        self.conn.write(data)

    def _send_command_long(self, command: int, params: tuple[float, ...], confirmation: int = 0) -> None:
        # unused params are 0, as ground stations send them: ArduPilot turns COMMAND_LONG into COMMAND_INT,
        # params 5 and 6 into integers, and a NaN there is undefined (its SITL stops on the FPE trap)
        p = list(params) + [0.0] * (7 - len(params))
        self.conn.mav.command_long_send(self.target, mavlink.MAV_COMP_ID_AUTOPILOT1, command, confirmation, *p)

    def _send_data_stream(self, stream: int, hz: int) -> None:
        """REQUEST_DATA_STREAM (start): ArduPilot's way to set a group of streams' rate."""
        self.conn.mav.request_data_stream_send(self.target, mavlink.MAV_COMP_ID_AUTOPILOT1, stream, hz, 1)

    def command(self, command: int, *params: float) -> CommandHandle:
        """Send COMMAND_LONG; unused params go out as 0. Replaces a pending one."""
        h = CommandHandle(command, tuple(params), self.clock())
        self.pending[command] = h
        self.counts["commands"] += 1
        self._send_command_long(command, h.params)
        return h

    def arm(self, arm: bool = True, force: bool = False) -> CommandHandle:
        return self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if arm else 0.0, 21196.0 if force else 0.0)

    def takeoff(self, alt_amsl: float, relative_alt: float) -> CommandHandle:
        """Climb to ``alt_amsl`` (m AMSL), i.e. ``relative_alt`` m above home; the autopilot's
        profile says which of the two NAV_TAKEOFF wants."""
        return self.command(mavlink.MAV_CMD_NAV_TAKEOFF, *self.state.profile.takeoff_params(alt_amsl, relative_alt))

    def land(self) -> CommandHandle:
        """NAV_LAND where the UAV is (the profile says how: NaN for PX4, 0 for ArduPilot)."""
        return self.command(mavlink.MAV_CMD_NAV_LAND, *self.state.profile.land_params())

    def return_to_launch(self) -> CommandHandle:
        return self.command(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)

    def set_mode(self, name: str) -> CommandHandle:
        """Mode by name in the autopilot's own terms (PX4: OFFBOARD, HOLD, ...; ArduPilot:
        GUIDED, ...); ValueError for a name the autopilot does not have."""
        return self.command(mavlink.MAV_CMD_DO_SET_MODE, *self.state.profile.set_mode_params(name))

    @property
    def in_offboard(self) -> bool:
        """The FCU follows our setpoints (PX4 OFFBOARD, ArduPilot GUIDED)."""
        return self.state.mode == self.state.profile.offboard_mode

    def send_velocity_ned(self, vn: float, ve: float, vd: float) -> None:
        """Velocity setpoint (OFFBOARD/GUIDED); stream it at >= 2 Hz or the FCU fails safe."""
        boot_ms = int(self.state.position_boot_s * 1000) & 0xFFFFFFFF
        self.conn.mav.set_position_target_local_ned_send(
            boot_ms, self.target, mavlink.MAV_COMP_ID_AUTOPILOT1, mavlink.MAV_FRAME_LOCAL_NED, VELOCITY_ONLY_MASK,
            0, 0, 0, vn, ve, vd, 0, 0, 0, 0, 0,
        )
        self.counts["tx_setpoints"] += 1


def _frame_ids(msg: Any) -> tuple[int, int]:
    """(sysid, compid) from a message's own frame (MAVLink 2 or 1), for one pymavlink could not decode."""
    buf = getattr(msg, "_msgbuf", b"")
    if len(buf) >= 10 and buf[0] == mavlink.PROTOCOL_MARKER_V2:
        return buf[5], buf[6]
    if len(buf) >= 6 and buf[0] == mavlink.PROTOCOL_MARKER_V1:
        return buf[3], buf[4]
    return 0, 0


class _UdpConnection:
    """What :class:`FcuLink` needs of a pymavlink connection, over :class:`FcuUdpSocket` (or its
    in-process twin)."""

    def __init__(self, sock: FcuUdpSocket | InprocFcuSocket, source_system: int, source_component: int):
        self.sock = sock
        self.mav = MAVLink(sock, srcSystem=source_system, srcComponent=source_component)
        self.mav.robust_parsing = True
        self.parse_datagram = self.mav.parse_datagram  # a datagram holds whole frames: nothing carries over

    def write(self, data: bytes) -> None:
        self.sock.write(data)

    def close(self) -> None:
        self.sock.close()
