"""The agent's MAVLink router: the FCU's stream to ground stations, their commands to the FCU.

A companion computer normally runs mavlink-router so that QGroundControl, MAVProxy or a
MAVSDK script can reach the flight controller next to the swarm agent. This module does the
same job inside the agent's loop (no thread, no extra process): :meth:`MavlinkRouter.from_fcu`
is :class:`~uav_stack.fcu_link.FcuLink`'s ``on_message`` hook, :meth:`MavlinkRouter.poll` reads
the ground-station sockets and :meth:`MavlinkRouter.flush` sends what the tick collected.

Frames are forwarded as received (``get_msgbuf()``), never re-encoded, so sequence numbers,
CRCs and signatures stay the sender's. Within one tick the frames for one endpoint are
coalesced into datagrams of at most 1400 bytes, as PX4 does; every MAVLink parser reads all
frames of a datagram.

Routing rules (mavlink.io's routing guide, as mavlink-router implements them):

* every channel (the FCU, each endpoint) learns the ``(sysid, compid)`` pairs it *receives*;
* a message is never sent to a channel that already knows its source (no echo, no loops,
  even when two routers are cross-connected);
* broadcasts (no target, or target system 0) go to every other channel; addressed messages
  only to channels where the target system (and component, unless 0) has been seen;
* messages addressed to the agent itself (its sysid and companion compid 191) stay here.

Locked by default (docs/security.md): every endpoint sends telemetry, but takes commands only
from ground stations that sign them.

* every socket is bound to one address: a ``udpin`` endpoint to the host of its spec, a
  ``udpout`` endpoint to the local address that routes to its ground station (or ``bind``),
  never to all interfaces unless a spec says ``0.0.0.0``;
* a ``udpout`` endpoint takes datagrams only from its ground station's address;
* :class:`SigningPolicy`: with a key, frames to the ground stations are signed (MAVLink 2
  signing) and only frames signed with it go anywhere; unsigned, badly signed and replayed
  frames, and frames whose id the dialect does not know, are dropped and counted. Without a
  key the router is telemetry only: nothing from a ground station is routed. Only
  :data:`UNSIGNED` (``gcs.allow_unsigned``, asked for by name) routes unsigned frames;
* a ``udpin`` endpoint answers a sender once it has sent a well-formed frame: one whose frames
  are accepted is a ground station (:data:`MAX_PEERS`), one whose frames are refused only
  listens (telemetry, at most :data:`MAX_LISTENERS`, never at the expense of a ground
  station); garbage makes neither;
* SETUP_SIGNING from a ground station never reaches the FCU: keys are set from files, not
  over the air.

A ``udpout`` ground station that is not running (its port answers ICMP port unreachable, as
on the same machine) gets one datagram a second instead of one a tick, until it listens
(:meth:`UdpEndpoint.refused`, counted in ``RouterStats.unheard``).

The allocation of MAVLink system ids for more than 250 UAVs is :func:`uav_stack.sysid.allocate_sysid`.
"""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from groundfloor.net import Addr
from uav_stack.fcu_link import LinkOpenError
from uav_stack.mav import mavlink
from uav_stack.mavlink_signing import REFUSED_REASONS, Signer, VerifyingParser, is_signed
from uav_stack.udp import clear_errors, drain, report_refusals, source_address_for

log = logging.getLogger(__name__)

MAX_DATAGRAM = 1400
MAX_PEERS = 4  # server endpoints: ground stations whose frames were accepted, answered at once
MAX_LISTENERS = 4  # server endpoints: senders of well-formed but refused (unsigned) frames, sent telemetry only
PEER_TIMEOUT = 30.0  # s: a silent server-endpoint peer is forgotten
MAX_SOURCES = 1024  # (sysid, compid) pairs remembered per channel
PROBE_EVERY_S = 1.0  # s between the datagrams to a udpout ground station whose port refused the last one
_M = mavlink

# Commands from a ground station that move the vehicle or change its mode: when one passes
# through the router to our FCU, a human has taken over, even if the mode name stays the same
# (ArduPilot GUIDED is both the agent's mode and MAVProxy's "guided").
TAKEOVER_COMMANDS = frozenset({
    _M.MAV_CMD_DO_REPOSITION, _M.MAV_CMD_DO_SET_MODE, _M.MAV_CMD_NAV_TAKEOFF, _M.MAV_CMD_NAV_LAND,
    _M.MAV_CMD_NAV_RETURN_TO_LAUNCH, _M.MAV_CMD_NAV_LOITER_UNLIM, _M.MAV_CMD_COMPONENT_ARM_DISARM,
    _M.MAV_CMD_MISSION_START, _M.MAV_CMD_DO_CHANGE_SPEED,
})
TAKEOVER_MESSAGES = frozenset({"SET_MODE", "SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT",
                               "SET_ATTITUDE_TARGET", "MANUAL_CONTROL"})


@dataclass(frozen=True)
class SigningPolicy:
    """What the ground-station endpoints accept. ``key`` (32 bytes, see
    :func:`uav_stack.mavlink_signing.read_key_file`): frames are signed both ways and only
    frames signed with it are routed; None: nothing is routed (telemetry only), unless
    ``allow_unsigned``. ``allow_unsigned``: unsigned frames are routed too (counted)."""

    key: bytes | None = None
    allow_unsigned: bool = False

    @property
    def mode(self) -> str:
        """``signed``, ``telemetry-only`` or ``unsigned-allowed`` (the stats' and the summary's word for it)."""
        if self.allow_unsigned:
            return "unsigned-allowed"
        return "signed" if self.key is not None else "telemetry-only"


LOCKED = SigningPolicy()  # no key: telemetry to every ground station, nothing from them
UNSIGNED = SigningPolicy(allow_unsigned=True)  # no key, every frame routed: any process that reaches an endpoint commands


def parse_endpoint(spec: str) -> tuple[str, str, int]:
    """``udpout:HOST:PORT`` (send to a GCS that listens, e.g. QGC on 14550) or ``udpin:HOST:PORT``
    (listen; answer whoever sends, like mavlink-router's server mode). Returns (mode, host, port)."""
    parts = spec.split(":")
    if len(parts) != 3 or parts[0] not in ("udpout", "udpin"):
        raise ValueError(f"MAVLink endpoint {spec!r}: expected udpout:HOST:PORT or udpin:HOST:PORT")
    mode, host, port_s = parts
    try:
        port = int(port_s)
    except ValueError:
        raise ValueError(f"MAVLink endpoint {spec!r}: port {port_s!r} is not a number") from None
    if not (0 <= port <= 65535) or (mode == "udpout" and port == 0):
        raise ValueError(f"MAVLink endpoint {spec!r}: port out of range")
    if not host:
        raise ValueError(f"MAVLink endpoint {spec!r}: empty host")
    return mode, host, port


@dataclass
class RouterStats:
    to_gcs: int = 0  # messages forwarded FCU -> endpoints (counted per endpoint)
    to_fcu: int = 0  # messages forwarded endpoint -> FCU
    gcs_to_gcs: int = 0
    datagrams_out: int = 0
    send_errors: int = 0
    bad_datagrams: int = 0  # garbage, truncated or CRC-failing input from an endpoint
    dropped_loop: int = 0  # the destination already knows the source: an echo or a routing loop
    dropped_unknown_target: int = 0
    dropped_for_us: int = 0  # addressed to the agent's own id
    spoofed_own_id: int = 0  # a GCS frame claiming the agent's or the FCU's id
    foreign_source: int = 0  # datagrams to a udpout endpoint from another address than its ground station's
    peers_evicted: int = 0  # udpin: a ground station forgotten to make room for another
    setup_signing_dropped: int = 0  # SETUP_SIGNING from a ground station (keys come from files)
    signed: int = 0  # frames with a good signature
    bad_signature: int = 0  # wrong signature (or a signed frame with no key to check it): refused
    replayed: int = 0  # a good signature with a timestamp already seen on its stream, or too old: refused
    unsigned_refused: int = 0  # unsigned frames refused (every one, unless unsigned frames are allowed)
    unsigned_commands_refused: int = 0  # of those, COMMAND_LONG, COMMAND_INT and SET_MODE
    unknown_id_refused: int = 0  # frames whose id the dialect does not know (never routed unless unsigned is allowed)
    unsigned_accepted: int = 0  # unsigned frames routed (gcs.allow_unsigned)
    listeners_evicted: int = 0  # udpin: a sender of refused frames forgotten to make room for another
    unsignable: int = 0  # frames that could not be signed for a signed link (outside our dialect): not sent
    unheard: int = 0  # frames not sent to a udpout ground station whose port refuses them (nobody listens there)
    signing: str = LOCKED.mode  # the policy (SigningPolicy.mode)

    def as_dict(self) -> dict[str, int | str]:
        return dict(self.__dict__)


@dataclass
class Channel:
    """What one side of the router has shown us: the (sysid, compid) pairs it sent."""

    name: str
    seen: set[tuple[int, int]] = field(default_factory=set)
    seen_sys: set[int] = field(default_factory=set)

    def learn(self, src: tuple[int, int]) -> None:
        if src not in self.seen and len(self.seen) < MAX_SOURCES:  # bounded: spoofed ids cannot grow it forever
            self.seen.add(src)
            self.seen_sys.add(src[0])

    def accepts(self, src: tuple[int, int], tsys: int, tcomp: int) -> int:
        """0 = send, 1 = loop (source known here), 2 = target unknown here."""
        if src in self.seen:
            return 1
        if tsys == 0:
            return 0
        if tcomp == 0:
            return 0 if tsys in self.seen_sys else 2
        return 0 if (tsys, tcomp) in self.seen else 2


class UdpEndpoint(Channel):
    """One ground-station endpoint: its socket, the ground stations it answers, its decoder
    (verifying signatures, unless the policy routes everything unsigned) and its signer."""

    def __init__(self, spec: str, clock: Callable[[], float], *, bind: str | None = None,
                 signing: SigningPolicy = LOCKED, link_id: int = 0):
        super().__init__(spec)
        self.spec = spec
        self.mode, self.host, self.port = parse_endpoint(spec)
        self.clock = clock
        self.bind = bind
        self.sock: socket.socket | None = None
        self.dest: Addr | None = None
        self.peers: dict[Addr, float] = {}  # udpin: ground stations whose frames were accepted
        self.listeners: dict[Addr, float] = {}  # udpin: senders of well-formed refused frames (telemetry only)
        self.verifying = signing != UNSIGNED
        self.parser: Any = VerifyingParser(signing.key, signing.allow_unsigned) if self.verifying else mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.signer = Signer(signing.key, link_id) if signing.key is not None else None
        self._out: list[bytes | bytearray] = []
        self._out_len = 0
        self.rx_datagrams = 0
        # udpout: nobody listened at the ground station's port (ICMP port unreachable) until
        # ``absent_until`` (wall s); meanwhile its frames are dropped (RouterStats.unheard)
        self.absent_until = 0.0
        self.quiet = False  # dropping now: set at each poll
        self._reports_refusals = False

    def open(self) -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if self.mode == "udpin":
                # no SO_REUSEADDR: no other process can bind this port beside us and read our ground stations' traffic
                s.bind((self.host, self.port))
                if self.host in ("0.0.0.0", ""):
                    log.warning("MAVLink endpoint %s listens on every interface; anyone who reaches it can command "
                                "the UAV unless signing is required (docs/security.md)", self.spec)
            else:
                self.dest = (socket.gethostbyname(self.host), self.port)
                s.bind((self.bind or source_address_for(self.dest[0]), 0))
                self._reports_refusals = report_refusals(s)
            s.setblocking(False)
        except OSError as exc:
            s.close()
            raise LinkOpenError.udp("gcs.mavlink_endpoints", self.spec, self.mode, self.host, self.port, exc) from exc
        self.sock = s

    @property
    def address(self) -> Addr:
        assert self.sock is not None
        return self.sock.getsockname()[:2]

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def recv(self, stats: RouterStats, max_datagrams: int = 64) -> list[tuple[bytes, Addr]]:
        """Pending datagrams; a udpout endpoint keeps only those from its ground station (and
        learns whether its port refused what was sent: :meth:`refused`)."""
        out = []
        if self._reports_refusals:
            self.quiet = self.clock() < self.absent_until
        for data, a in drain(self.sock, max_datagrams, self.refused if self._reports_refusals else None):
            if self.mode == "udpout" and a != self.dest:
                stats.foreign_source += 1
                continue
            self.rx_datagrams += 1
            out.append((data, a))
        return out

    def refused(self) -> None:
        """udpout: the ground station's port refused a datagram (ICMP port unreachable: no
        ground station runs there). Its frames are dropped for :data:`PROBE_EVERY_S`, then one
        datagram goes to see whether one listens now: QGroundControl started later sees the UAV
        within about a second. Why: every UAV of a run routes to a ground-station port by
        default, each tick, whether or not one runs; a datagram and the port-unreachable it
        draws cost about 25 us of CPU, and the routing before it more."""
        self.absent_until = self.clock() + PROBE_EVERY_S
        self.quiet = True
        if self.sock is not None:
            clear_errors(self.sock)

    def note_peer(self, a: Addr, stats: RouterStats) -> None:
        """udpin: answer ``a`` from now on (it sent a frame we accepted); the least recently heard goes."""
        if self.mode != "udpin":
            return
        self.listeners.pop(a, None)
        if a not in self.peers and len(self.peers) >= MAX_PEERS:
            del self.peers[min(self.peers, key=self.peers.__getitem__)]
            stats.peers_evicted += 1
        self.peers[a] = self.clock()

    def note_listener(self, a: Addr, stats: RouterStats) -> None:
        """udpin: send telemetry to ``a`` (it sent a well-formed frame we refused: a ground station
        without the key). Listeners make room only for each other, never for a peer."""
        if self.mode != "udpin":
            return
        if a in self.peers:  # a ground station stays one by its accepted frames
            return
        if a not in self.listeners and len(self.listeners) >= MAX_LISTENERS:
            del self.listeners[min(self.listeners, key=self.listeners.__getitem__)]
            stats.listeners_evicted += 1
        self.listeners[a] = self.clock()

    def targets(self) -> list[Addr]:
        if self.mode == "udpout":
            return [self.dest] if self.dest else []
        now = self.clock()
        for table in (self.peers, self.listeners):
            for a in [a for a, t in table.items() if now - t > PEER_TIMEOUT]:
                del table[a]
        return [*self.peers, *self.listeners]

    def queue(self, msg: Any, stats: RouterStats) -> bool:
        """Queue ``msg``'s frame (signed, on a signed link); False if it cannot be sent here."""
        buf: bytes | bytearray | None  # pymavlink's own frames are bytearrays
        if self.signer is not None:
            buf = self.signer.sign(msg)
            if buf is None:
                stats.unsignable += 1
                return False
        else:
            buf = msg.get_msgbuf()
        if self._out_len + len(buf) > MAX_DATAGRAM:
            self.flush(stats)
        self._out.append(buf)
        self._out_len += len(buf)
        return True

    def flush(self, stats: RouterStats) -> None:
        if not self._out:
            return
        if self.quiet:
            stats.unheard += len(self._out)
            self._out.clear()
            self._out_len = 0
            return
        data = b"".join(self._out)
        self._out.clear()
        self._out_len = 0
        s = self.sock
        if s is None:
            return
        for addr in self.targets():
            try:
                s.sendto(data, addr)
                stats.datagrams_out += 1
            except ConnectionRefusedError:  # the port refused an earlier datagram: nobody listens
                stats.send_errors += 1
                if self._reports_refusals:
                    self.refused()
            except OSError:  # buffer full: drop, like UDP
                stats.send_errors += 1


class MavlinkRouter:
    """Routes between one FCU (through the agent's :class:`FcuLink`) and ground-station endpoints.

    ``write_fcu`` sends raw bytes to the FCU (``FcuLink.write``); ``own`` is the agent's
    (sysid, compid) on the FCU link.
    """

    def __init__(self, endpoints: list[str] | tuple[str, ...], write_fcu: Callable[[bytes], None], *,
                 own: tuple[int, int] = (1, mavlink.MAV_COMP_ID_ONBOARD_COMPUTER), clock: Callable[[], float] = time.time,
                 bind: str | None = None, signing: SigningPolicy = LOCKED):
        self.endpoints = [UdpEndpoint(e, clock, bind=bind, signing=signing, link_id=i) for i, e in enumerate(endpoints)]
        self.signing = signing
        self.write_fcu = write_fcu
        self.own = own
        self.clock = clock
        self.fcu = Channel("fcu")
        self.stats = RouterStats(signing=signing.mode)
        # the latest ground-station command that moves our vehicle or changes its mode:
        # (wall time, description); the agent treats it as a human taking over
        self.takeover: tuple[float, str] | None = None
        self._to_fcu: list[bytes] = []
        self._to_fcu_len = 0
        self._all_quiet = False  # every endpoint dropping (as of the last poll): frames from the FCU stop here

    # ---- lifecycle ----------------------------------------------------------------------
    def open(self) -> MavlinkRouter:
        """Open every endpoint, or none: :class:`~uav_stack.fcu_link.LinkOpenError` names the one that failed."""
        try:
            for ep in self.endpoints:
                ep.open()
        except OSError:
            self.close()
            raise
        return self

    def close(self) -> None:
        for ep in self.endpoints:
            ep.close()

    def addresses(self) -> dict[str, Addr]:
        return {ep.spec: ep.address for ep in self.endpoints if ep.sock is not None}

    # ---- FCU -> ground stations (FcuLink's on_message hook) ---------------------------------
    def from_fcu(self, msg: Any) -> None:
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        self.fcu.learn(src)
        if self._all_quiet:  # no ground station listens at any endpoint (UdpEndpoint.refused)
            self.stats.unheard += 1
            return
        tsys = getattr(msg, "target_system", 0)
        tcomp = getattr(msg, "target_component", 0)
        if tsys == self.own[0] and tcomp == self.own[1]:
            self.stats.dropped_for_us += 1
            return
        stats = self.stats
        for ep in self.endpoints:
            if ep.quiet:  # nobody listens there (UdpEndpoint.refused)
                stats.unheard += 1
                continue
            verdict = ep.accepts(src, tsys, tcomp)
            if verdict == 0:
                if ep.queue(msg, stats):
                    stats.to_gcs += 1
            elif verdict == 1:
                stats.dropped_loop += 1
            else:
                stats.dropped_unknown_target += 1

    # ---- ground stations -> FCU (and to each other) -----------------------------------------
    def poll(self) -> int:
        """Read every endpoint (bounded, non-blocking) and route what arrived; returns messages routed."""
        n = 0
        for ep in self.endpoints:
            for data, addr in ep.recv(self.stats):
                n += self._route_datagram(ep, data, addr)
        self._all_quiet = bool(self.endpoints) and all(ep.quiet for ep in self.endpoints)
        if self.signing != UNSIGNED:
            self._sum_signing()
        return n

    def _sum_signing(self) -> None:
        st = self.stats
        for name in _VERIFIER_COUNTERS:
            setattr(st, name, sum(getattr(ep.parser, name) for ep in self.endpoints))

    def _route_datagram(self, ep: UdpEndpoint, data: bytes, addr: Addr) -> int:
        p = ep.parser
        if ep.verifying:
            p.heard_refused = False
        try:
            msgs = p.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - a decoder failure is bad input, never a crash
            msgs = []
            self.stats.bad_datagrams += 1
        # a datagram holds whole frames: never carry a partial frame into the next one
        p.buf = bytearray()
        p.buf_index = 0
        p.expected_length = mavlink.HEADER_LEN_V1 + 2
        p.have_prefix_error = False
        n = 0
        bad = False
        for m in msgs:
            if isinstance(m, mavlink.MAVLink_bad_data):
                bad = bad or m.reason not in REFUSED_REASONS  # refused by the policy: counted by the parser
                continue
            if not ep.verifying and not is_signed(m.get_msgbuf()):
                self.stats.unsigned_accepted += 1  # (a verifying parser counts its own)
            self._route_from_gcs(ep, m)
            n += 1
        if bad or (not msgs and data):
            self.stats.bad_datagrams += 1
        if n:
            ep.note_peer(addr, self.stats)
        elif ep.verifying and p.heard_refused:  # a ground station without the key: it may watch, not command
            ep.note_listener(addr, self.stats)
        return n

    def _route_from_gcs(self, ep: UdpEndpoint, m: Any) -> None:
        stats = self.stats
        src = (m.get_srcSystem(), m.get_srcComponent())
        if src == self.own or src in self.fcu.seen:
            stats.spoofed_own_id += 1  # an echo of the FCU's own stream, or a GCS using our ids
            return
        if m.get_type() == "SETUP_SIGNING":  # a key over the air would let whoever sends first lock the others out
            stats.setup_signing_dropped += 1
            return
        ep.learn(src)
        tsys = getattr(m, "target_system", 0)
        tcomp = getattr(m, "target_component", 0)
        buf = m.get_msgbuf()
        if tsys == self.own[0] and tcomp == self.own[1]:
            stats.dropped_for_us += 1
            return
        verdict = self.fcu.accepts(src, tsys, tcomp)
        if verdict == 0:
            if self._to_fcu_len + len(buf) > MAX_DATAGRAM:
                self._flush_fcu()
            self._to_fcu.append(buf)
            self._to_fcu_len += len(buf)
            stats.to_fcu += 1
            if tsys != 0:
                self._note_takeover(m)
        elif verdict == 2:
            stats.dropped_unknown_target += 1
        for other in self.endpoints:
            if other is ep:
                continue
            if other.accepts(src, tsys, tcomp) == 0 and other.queue(m, stats):
                stats.gcs_to_gcs += 1

    def _note_takeover(self, m: Any) -> None:
        mtype = m.get_type()
        what = None
        if mtype in ("COMMAND_LONG", "COMMAND_INT"):
            if m.command in TAKEOVER_COMMANDS:
                what = _command_name(m.command)
        elif mtype in TAKEOVER_MESSAGES:
            what = mtype
        elif mtype in ("MISSION_ITEM", "MISSION_ITEM_INT") and m.current == 2:
            what = "guided " + mtype
        if what is not None:
            self.takeover = (self.clock(), what)

    def flush(self) -> None:
        """Send everything this tick collected (one datagram per endpoint, usually)."""
        self._flush_fcu()
        for ep in self.endpoints:
            ep.flush(self.stats)

    def _flush_fcu(self) -> None:
        if self._to_fcu:
            data = b"".join(self._to_fcu)
            self._to_fcu.clear()
            self._to_fcu_len = 0
            try:
                self.write_fcu(data)
            except OSError as exc:
                self.stats.send_errors += 1
                log.debug("router -> fcu: %s", exc)


_VERIFIER_COUNTERS = ("signed", "bad_signature", "replayed", "unsigned_refused", "unsigned_commands_refused",
                      "unknown_id_refused", "unsigned_accepted")


def _command_name(cmd: int) -> str:
    e = mavlink.enums["MAV_CMD"].get(cmd)
    return e.name.removeprefix("MAV_CMD_") if e is not None else str(cmd)
