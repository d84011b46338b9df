"""The start-up contract with any MAVLink autopilot: what the agent asks for once its link is pinned.

A real autopilot does not necessarily stream what a companion needs. ArduCopter with factory
defaults sends nothing but HEARTBEAT until asked (its stream rates, ``MAV1_*``, are 0); PX4
streams a lot on its onboard link unasked. So once :class:`~uav_stack.fcu_link.FcuLink` has
pinned its FCU, :class:`FcuContract`:

1. looks for :data:`OBSERVE_S` at what arrives unasked, and leaves alone what already comes at the
   rate the agent needs (PX4's 50 Hz GLOBAL_POSITION_INT is not slowed down);
2. asks for each message that does not, with SET_MESSAGE_INTERVAL (answered by a COMMAND_ACK, on
   PX4 and ArduPilot alike), and once for AUTOPILOT_VERSION with REQUEST_MESSAGE;
3. checks that the rates arrive and asks again, up to :data:`MAX_TRIES` times, falling back from the
   second try on to REQUEST_DATA_STREAM for the stream that carries the message in ArduPilot's
   grouping (ArduPilot honours it; PX4 ignores it, so it is not sent there);
4. then watches on a slow timer (:data:`STEADY_S`): a message that stops (the autopilot rebooted, a
   ground station sent its own REQUEST_DATA_STREAM) is asked for again, and after giving up it
   asks again every :data:`GIVE_UP_RETRY_S`.

:meth:`FcuContract.waiting_for` says in one line what the agent waits for (``no
GLOBAL_POSITION_INT from the autopilot: requested at 10 Hz, 3 tries``): the agent's phase detail,
hence its log, status file and ``mrswarm gcs watch``. ``mrswarm preflight`` runs the same contract
(``ask=False`` only looks). It runs at start-up and on its timer, never on the agent's every tick:
:meth:`check` is due at :attr:`FcuContract.next_check`.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from uav_stack.mav import mavlink

if TYPE_CHECKING:
    from uav_stack.autopilot import AutopilotProfile

log = logging.getLogger(__name__)

OBSERVE_S = 1.5  # s of looking at what arrives unasked, before asking for anything
CHECK_S = 2.0  # s after asking before the rate is judged (or longer: three periods of the message)
STEADY_S = 5.0  # s between two looks at messages that arrive as asked
MAX_TRIES = 3  # requests per message before the agent says it gave up (and asks only every GIVE_UP_RETRY_S)
GIVE_UP_RETRY_S = 30.0
ENOUGH = 0.7  # a message arrives as asked at 70 % of the rate asked for, or faster
VERSION_TRIES = 3

# the MAV_DATA_STREAM that carries a message in ArduPilot's grouping (REQUEST_DATA_STREAM, the fallback)
ARDUPILOT_STREAMS: dict[str, int] = {
    "GLOBAL_POSITION_INT": mavlink.MAV_DATA_STREAM_POSITION,
    "SYS_STATUS": mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
    "GPS_RAW_INT": mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
    "EKF_STATUS_REPORT": mavlink.MAV_DATA_STREAM_EXTRA3,
    "ATTITUDE": mavlink.MAV_DATA_STREAM_EXTRA1,
}
_REFUSED = frozenset({mavlink.MAV_RESULT_DENIED, mavlink.MAV_RESULT_UNSUPPORTED, mavlink.MAV_RESULT_FAILED})
_RESULT = {mavlink.MAV_RESULT_ACCEPTED: "accepted", mavlink.MAV_RESULT_TEMPORARILY_REJECTED: "temporarily rejected",
           mavlink.MAV_RESULT_DENIED: "denied", mavlink.MAV_RESULT_UNSUPPORTED: "unsupported",
           mavlink.MAV_RESULT_FAILED: "failed", mavlink.MAV_RESULT_IN_PROGRESS: "in progress"}


@dataclass(frozen=True)
class Want:
    """A message the agent needs from its autopilot, at what rate, and what for."""

    name: str  # the MAVLink message
    hz: float
    required: bool  # the agent cannot fly without it (it waits in ``init``)
    why: str

    @property
    def msgid(self) -> int:
        return int(getattr(mavlink, f"MAVLINK_MSG_ID_{self.name}"))


def wants_for(profile: AutopilotProfile, position_hz: float = 10.0) -> tuple[Want, ...]:
    """What the agent asks of an autopilot with this profile; ``position_hz`` is its pose rate."""
    wants = [
        Want("GLOBAL_POSITION_INT", position_hz, True, "position, velocity"),
        Want("SYS_STATUS", 1.0, False, "battery, pre-arm checks"),
        Want("EXTENDED_SYS_STATE", 1.0, False, "landed state"),
        Want("HOME_POSITION", 0.5, False, "take-off altitude"),
        Want("GPS_RAW_INT", 1.0, False, "GPS fix"),
    ]
    if profile.estimator:
        wants.append(Want(profile.estimator, 1.0, False, "estimator uses GPS"))
    return tuple(wants)


@dataclass
class Stream:
    """How one wanted message arrives, and what was done about it."""

    want: Want
    since: float  # start of the window being looked at
    count_at: int  # the message's count at ``since``
    tries: int = 0
    asked_at: float = -math.inf
    hz: float = math.nan  # measured over the last whole window
    status: str = "unseen"  # unseen | ok | slow | missing | refused
    ack: str = ""  # the autopilot's answer to the last SET_MESSAGE_INTERVAL
    warned: bool = False

    @property
    def window(self) -> float:
        """s a window must last before the rate is judged: three periods, at least CHECK_S."""
        return max(CHECK_S if self.status != "ok" else STEADY_S, 3.0 / self.want.hz)


class FcuContract:
    """The start-up contract of one :class:`~uav_stack.fcu_link.FcuLink` (see the module's doc)."""

    def __init__(self, counts: dict[str, int], send_command: Callable[[int, tuple[float, ...]], None],
                 send_data_stream: Callable[[int, int], None], position_hz: float = 10.0, ask: bool = True,
                 rtf: Callable[[], float] = lambda: 1.0):
        self.counts = counts  # messages of the pinned FCU by type (FcuLink.rx_types)
        self._send_command = send_command  # (command, params): one COMMAND_LONG, no retries
        self._send_data_stream = send_data_stream  # (stream id, rate Hz): REQUEST_DATA_STREAM
        self.position_hz = position_hz
        self.ask = ask
        # the FCU's real-time factor: rates are of its time (a virtual FCU at RTF 0.4 sends 10 Hz as 4 per wall second)
        self._rtf = rtf
        self.streams: dict[str, Stream] = {}
        self.profile: AutopilotProfile | None = None
        self.started_at = math.nan
        self.next_check = math.inf  # nothing to do until start()
        self.requests = 0  # commands and REQUEST_DATA_STREAMs sent
        self.version_tries = 0
        self._first_look = False
        self.awaits_estimator = False  # the profile's estimator message may still come: no position before it
        self.version_ack = ""  # the autopilot's answer to REQUEST_MESSAGE(AUTOPILOT_VERSION): it hears this link
        self._acks: deque[str] = deque(maxlen=32)  # SET_MESSAGE_INTERVALs awaiting their ACK, in order

    # ---- lifecycle ----------------------------------------------------------------------
    def start(self, profile: AutopilotProfile, now: float) -> None:
        """The FCU is pinned: look at what arrives unasked for OBSERVE_S, then ask for the rest."""
        self.profile = profile
        self.started_at = now
        self.streams = {w.name: Stream(w, now, self.counts.get(w.name, 0)) for w in wants_for(profile, self.position_hz)}
        self.next_check = now + OBSERVE_S
        self._first_look = True
        self.awaits_estimator = profile.estimator_first and not self.counts.get(profile.estimator)

    def check(self, now: float) -> None:
        """Judge each message's rate over its window and ask for what does not arrive; sets next_check."""
        if self.profile is None:
            return
        first, self._first_look = self._first_look, False
        for s in self.streams.values():
            self._judge(s, now, first)
        if self.version_tries < VERSION_TRIES and not self.counts.get("AUTOPILOT_VERSION"):  # (asks nothing of its streams)
            self.version_tries += 1
            self._request(mavlink.MAV_CMD_REQUEST_MESSAGE, float(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION))
        if self.awaits_estimator:
            self.awaits_estimator = self.pending(self.profile.estimator)
        self.next_check = min((s.since + s.window for s in self.streams.values()), default=now + STEADY_S)
        self.next_check = max(self.next_check, now + 0.2)

    def _judge(self, s: Stream, now: float, first: bool) -> None:
        n = self.counts.get(s.want.name, 0) - s.count_at
        window = now - s.since
        whole = window >= s.window - 1e-6
        if whole:
            s.hz = n / window if window > 0 else math.nan
        k = self._rtf()
        k = k if 0.0 < k < 1.0 else 1.0  # (NaN before it is measured)
        if whole and n >= max(1, math.floor(ENOUGH * s.want.hz * k * window)):
            if s.status != "ok" and s.tries:
                log.info("FCU: %s arrives at %.1f Hz (asked for %g Hz%s)", s.want.name, s.hz, s.want.hz,
                         f" of the FCU's time, RTF {k:.2f}" if k < 1.0 else "")
            s.status, s.tries, s.warned = "ok", 0, False
            s.since, s.count_at = now, n + s.count_at
            return
        if not whole and not (first and n == 0 and s.want.hz * OBSERVE_S >= 1.0):
            return  # its whole window first (one seen already, asked a moment ago, or slower than the first look)
        if s.status == "ok" and n > 0:
            s.status = "slow"  # it came as asked before: say so, ask again
        elif s.status != "refused":
            s.status = "missing" if n == 0 else "slow"
        s.since, s.count_at = now, n + s.count_at
        if not self.ask:
            return
        if s.status == "refused" and s.want.name not in ARDUPILOT_STREAMS:
            if not s.warned:  # the autopilot has no such message: nothing else to try
                s.warned = True
                log.log(logging.WARNING if s.want.required else logging.INFO, "FCU: %s", self.describe(s))
            return
        if s.tries < MAX_TRIES or now - s.asked_at >= GIVE_UP_RETRY_S:
            self._ask(s, now)
        elif not s.warned:
            s.warned = True
            log.log(logging.WARNING if s.want.required else logging.INFO, "FCU: %s", self.describe(s))

    def _ask(self, s: Stream, now: float) -> None:
        s.tries += 1
        s.asked_at = now
        self._acks.append(s.want.name)
        self._request(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, float(s.want.msgid), 1e6 / s.want.hz)
        stream = ARDUPILOT_STREAMS.get(s.want.name)
        assert self.profile is not None
        if stream is not None and self.profile.data_streams and (s.tries >= 2 or s.status == "refused"):
            # ArduPilot's own way (MAV1_* stream rates). It sets every message of that stream to the
            # stream's rate: the fastest any wanted message of that stream needs
            hz = max(w.want.hz for w in self.streams.values() if ARDUPILOT_STREAMS.get(w.want.name) == stream)
            self.requests += 1
            self._send_data_stream(stream, max(1, math.ceil(hz)))
        log.info("FCU: asked for %s at %g Hz (try %d)", s.want.name, s.want.hz, s.tries)

    def _request(self, command: int, *params: float) -> None:
        self.requests += 1
        self._send_command(command, params)

    def on_ack(self, command: int, result: int) -> None:
        """A COMMAND_ACK addressed to us for SET_MESSAGE_INTERVAL (in the order they were sent) or REQUEST_MESSAGE."""
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            self.version_ack = _RESULT.get(result, str(result))
            return
        if command != mavlink.MAV_CMD_SET_MESSAGE_INTERVAL or not self._acks:
            return
        s = self.streams.get(self._acks.popleft())
        if s is None:
            return
        s.ack = _RESULT.get(result, str(result))
        if result in _REFUSED and s.status != "ok":
            s.status = "refused"
            if self.awaits_estimator and self.profile is not None and s.want.name == self.profile.estimator:
                self.awaits_estimator = self.pending(s.want.name)

    def pending(self, name: str) -> bool:
        """May this wanted message still come: not seen yet, and neither refused nor given up on?"""
        s = self.streams.get(name)
        if s is None or self.counts.get(name):
            return False
        if not self.ask:
            return s.status == "unseen"
        return s.status != "refused" and (s.tries < MAX_TRIES or s.status == "unseen")

    # ---- what it says ---------------------------------------------------------------------
    def describe(self, s: Stream) -> str:
        w = s.want
        asked = f"requested at {w.hz:g} Hz, {s.tries} tr{'y' if s.tries == 1 else 'ies'}" if s.tries else \
            ("not asked for yet" if self.ask else "not asked for (mrswarm preflight --set-streams asks)")
        if s.status == "refused":
            return f"no {w.name} from the autopilot: it refused SET_MESSAGE_INTERVAL ({s.ack}), {asked}"
        if s.status == "slow":
            return f"{w.name} at {s.hz:.1f} Hz from the autopilot: {asked}"
        return f"no {w.name} from the autopilot: {asked}"

    def waiting_for(self) -> str:
        """What the agent cannot fly without and does not have, in one line; "" when nothing."""
        for s in self.streams.values():
            if s.want.required and s.status in ("missing", "refused"):
                return self.describe(s)
            if s.want.required and s.status == "unseen" and not self.counts.get(s.want.name):
                return f"no {s.want.name} from the autopilot yet"
        return ""

    def problems(self) -> list[str]:
        """Every wanted message that does not arrive as asked (those the agent needs, and the others)."""
        return [self.describe(s) for s in self.streams.values() if s.status in ("missing", "slow", "refused")]

    def as_dict(self) -> dict[str, Any]:
        """For the UAV's status file: each message's measured rate, status, tries and the autopilot's answer."""
        return {
            "requests": self.requests,
            "streams": {name: {"hz": None if math.isnan(s.hz) else round(s.hz, 2), "asked_hz": s.want.hz,
                               "status": s.status, "tries": s.tries, "ack": s.ack}
                        for name, s in self.streams.items()},
            "waiting_for": self.waiting_for(),
        }
