"""A behaviour of the SDK as the agent's mission: :class:`BehaviourMission`.

The agent knows two internal protocols (``uav_stack.behaviours.base``): a mission's
``velocity(me, members)`` and ``done`` at each control tick, and a cooperative mission's
``topics``, ``receive``, ``outbox`` and ``status``. :class:`BehaviourMission` implements both
around a user's :class:`~uav_stack.sdk.behaviour.Behaviour`, so the agent flies it like a
built-in mission. After each tick the agent reads two attributes: :attr:`BehaviourMission.altitude`
(the altitude target an intent asked for, m above the origin; None: the flight's) and
:attr:`BehaviourMission.request` (``"land"``: land now).

It guards the UAV against the user's code: an exception in ``setup``/``step``, a step over its
time budget (``mission.budget_ms`` of CPU time, so that a step the machine's load descheduled is
not blamed; a step that waits, on a sleep or I/O, once it takes :data:`WAIT_FACTOR` budgets of
wall time) or an intent that is not one is a *fault*, counted and logged. ``mission.max_faults``
faults in a row, or twice that within :data:`FAULT_WINDOW_S`, and the behaviour is stopped: the
UAV holds where it is for ``mission.hold_s``, then lands, and an incident goes into the stats
file (``behaviour.incidents``), whence into the run's summary. A step that never returns is
interrupted after :data:`HARD_LIMIT_FACTOR` times its budget (at least 1 s) by a timer signal,
where the agent runs in the main thread (it does in every UAV process).

Messages: a behaviour's topics are the keys of its ``messages``; what it sends goes out at once
on the swarm node (broadcast ``mrs/<swarm>/<src>/msg/<topic>``, unicast
``mrs/<swarm>/<src>/to/<dst>/<topic>``: under the sender's own id, so access control and netem
apply), its body the message Struct as plain values. What arrives is decoded into the topic's
type; a message that does not fit is rejected and counted. Per topic: sent, received, rejected,
send errors and the age of what arrived (mean and max, ms), in the stats file's ``behaviour``
section.

Records: what the behaviour records (``ctx.record``) goes into ``behaviour_uav<N>.csv``, and
with the message counters onto the UAV's own key ``mrs/<swarm>/<uav>/behaviour`` once a second
(:mod:`uav_stack.sdk.reports`), whence the run's recorder writes them into the flight recording.
A value that cannot be recorded (a bad name or value, too many names) is refused and counted,
never raised into the step.

Sensors and actuators: the UAV's :class:`~uav_stack.sensors.Payload` (the one given, else its
agent's), read and driven through the Context (``ctx.reading``, ``ctx.actuate``); no-fly zones
likewise (``ctx.blocked``). A mission that no agent drives (a simulation calls ``velocity``
itself) has no swarm node: what its behaviour broadcasts waits in :meth:`BehaviourMission.outbox`
for the simulation to deliver, in the envelope an agent would send.
"""

from __future__ import annotations

import logging
import math
import signal
import threading
import time
from collections import deque
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

import msgspec

from groundfloor.errors import MrswarmError
from swarmnet.messages import VALUE_NAME_RE, TopicCounts, wire_time
from uav_stack.behaviours.base import SelfState, Vec2
from uav_stack.recorder import AppendLog
from uav_stack.sdk import loader
from uav_stack.sdk.behaviour import Behaviour
from uav_stack.sdk.context import Context, Message, Neighbour, Outbox
from uav_stack.sdk.intents import Altitude, GoTo, Hold, Intent, Land, Velocity, intent_problem
from uav_stack.sdk.reports import FINAL_LINGER_S, VALUES_HEADER, BehaviourReporter
from uav_stack.sensors import Payload, SensorReading

if TYPE_CHECKING:
    from uav_stack.agent import Agent
    from uav_stack.behaviours.zones import ZoneField
    from uav_stack.config import AgentConfig

log = logging.getLogger(__name__)

FAULT_WINDOW_S = 30.0  # s: 2 * max_faults faults within this stop the behaviour too
WAIT_FACTOR = 10.0  # a step that waits (sleep, I/O) overruns once it takes this many budgets of wall time
HARD_LIMIT_FACTOR = 50.0  # a step running this many budgets (at least HARD_LIMIT_MIN_S) is interrupted
HARD_LIMIT_MIN_S = 1.0
APPROACH_GAIN = 0.8  # 1/s: GoTo's speed = gain * distance, capped by the cruise speed
MAX_DECEL = 1.5  # m/s^2 assumed to stop at a GoTo point (speed <= sqrt(2 * a * d))
MAX_INBOX = 256  # messages per topic kept between two steps (the oldest dropped beyond)
MAX_VALUES = 64  # distinct names of record()
_NAME = VALUE_NAME_RE
_ZERO: Vec2 = (0.0, 0.0)


class StepTimeout(MrswarmError):  # noqa: N818 - raised into a user's step, read as "step timeout"
    """Raised into a step that ran past its hard limit."""


class TopicCounters:
    """One topic's message counts."""

    __slots__ = ("sent", "send_errors", "received", "rejected", "age_sum", "age_max", "dropped")

    def __init__(self) -> None:
        self.sent = self.send_errors = self.received = self.rejected = self.dropped = 0
        self.age_sum = 0.0
        self.age_max = 0.0

    def as_dict(self) -> dict[str, Any]:
        return {"sent": self.sent, "send_errors": self.send_errors, "received": self.received, "rejected": self.rejected,
                "dropped": self.dropped,
                "age_mean_ms": round(1000.0 * self.age_sum / self.received, 2) if self.received else None,
                "age_max_ms": round(1000.0 * self.age_max, 2) if self.received else None}

    def counts(self) -> TopicCounts:
        """As a behaviour report carries them (swarmnet.messages)."""
        d = self.as_dict()
        return TopicCounts(self.sent, self.send_errors, self.received, self.rejected, self.dropped, d["age_mean_ms"],
                           d["age_max_ms"])


def _towards(x: float, y: float, gx: float, gy: float, speed: float) -> Vec2:
    dx, dy = gx - x, gy - y
    d = math.hypot(dx, dy)
    if d < 1e-6 or not math.isfinite(d):
        return _ZERO
    v = min(speed, APPROACH_GAIN * d, math.sqrt(2.0 * MAX_DECEL * d))
    return (dx * v / d, dy * v / d)


class BehaviourMission:
    """The agent's mission (``velocity``/``done``) and cooperative mission (``topics``/``receive``/
    ``outbox``/``status``) around one user behaviour, guarded. See the module's docstring."""

    sdk = True  # what the agent asks to tell it from its other missions

    def __init__(self, cfg: AgentConfig, behaviour: Behaviour[Any], spec: str | None = None,
                 payload: Payload | None = None, zones: ZoneField | None = None) -> None:
        m = cfg.mission
        self.payload = payload  # None: the agent's
        self.zones = zones  # None: the agent's
        self.cfg = cfg
        self.behaviour = behaviour
        self.spec = spec or m.behaviour or ""
        cls = type(behaviour)
        self.types: dict[str, type[msgspec.Struct]] = dict(cls.messages)
        self.topics: tuple[str, ...] = tuple(self.types)
        self.max_bytes = min(cls.max_message_bytes, loader.SWARM_MAX_MESSAGE_BYTES - 512)
        self.period = 1.0 / cls.rate_hz
        self.avoid = cls.avoidance
        self.budget_s = m.budget_ms / 1000.0
        self.max_faults = m.max_faults
        self.hold_s = m.hold_s
        self.speed = cfg.speed
        self.min_alt, self.max_alt = cfg.gcs.min_alt, cfg.gcs.max_alt
        # read by the agent after each tick
        self.altitude: float | None = None  # m above the origin; None: the flight's altitude
        self.request: str | None = None  # "land": land now
        self.agent: Agent | None = None
        self._unsent: list[tuple[str, Any]] = []  # broadcasts of a mission no agent drives (outbox)
        self._actuate_errors = 0
        self.log = logging.getLogger(f"behaviour.uav{cfg.uav}")
        self.ctx = Context(cfg.uav, cfg.swarm, cfg.realm, cfg.speed, cfg.altitude,
                           m.area if m.area != (-1.0, 1.0, -1.0, 1.0) else None, m.goal, Outbox(self._send), self.log,
                           self._neighbours, self._sensors, self._record_value, self._actuate, self._blocked)
        self.counters: dict[str, TopicCounters] = {t: TopicCounters() for t in self.topics}
        self._inbox: dict[str, list[Message[Any]]] = {t: [] for t in self.topics}
        self._intent: Intent = Velocity(0.0, 0.0)
        self._anchor: Vec2 = (math.nan, math.nan)  # the hold point of Hold/Altitude, set when the intent came
        self._next_step = -math.inf
        self._last_step_t: float | None = None
        self._started_at: float | None = None
        self._set_up = False
        self.steps = 0
        self.exceptions = 0
        self.overruns = 0
        self.bad_intents = 0
        self.in_a_row = 0
        self._recent: deque[float] = deque()
        self.step_s_sum = 0.0
        self.step_s_max = 0.0
        self.state = "running"  # running, holding (stopped after faults), landing, done
        self.last_error = ""
        self.incidents: list[dict[str, Any]] = []
        self._stopped_at = math.nan
        self._hold_point: Vec2 = (math.nan, math.nan)
        self.values: dict[str, float] = {}
        self.reporter = BehaviourReporter(cfg.uav, self.log)  # the values and counters onto the network, 1 Hz
        self.reporter.active = bool(self.topics)
        self._refusals: dict[str, int] = {}  # why ctx.record calls were refused
        self._limit = _HardLimit(max(HARD_LIMIT_MIN_S, HARD_LIMIT_FACTOR * self.budget_s))
        self.records: AppendLog | None = None
        if cfg.record_dir:
            self.records = AppendLog(Path(cfg.record_dir) / f"behaviour_uav{cfg.uav}.csv", VALUES_HEADER)

    # ---- the agent's side -----------------------------------------------------------------
    def attach(self, agent: Agent) -> None:
        """Bound to its agent once (``Agent.__init__``): the node sends, the link's state is read,
        the counters join the stats file, and a behaviour that opted out of avoidance flies without it."""
        self.agent = agent
        agent.stats_sources["behaviour"] = self.stats
        if not self.avoid:
            agent.avoidance = None

    @property
    def done(self) -> bool:
        if self.state != "running":
            return False
        try:
            return bool(self.behaviour.done)
        except Exception as exc:  # noqa: BLE001 - user code never stops the agent
            self._fault("exception", f"done: {type(exc).__name__}: {exc}", time.time())
            return False

    @property
    def status(self) -> str:
        if self.state == "holding":
            return f"behaviour stopped ({self.last_error[:60]}): holding"
        if self.state == "landing":
            return "behaviour stopped: landing"
        try:
            return str(self.behaviour.status)[:80]
        except Exception:  # noqa: BLE001
            return type(self.behaviour).__name__

    def outbox(self) -> list[tuple[str, Any]]:
        """Empty under an agent (Context.send sends at once: unicast needs the node's own send); without
        one, the broadcasts since the last call, ``(topic, [sent_at, 0, fields])``, for a simulation to deliver."""
        out, self._unsent = self._unsent, []
        return out

    def receive(self, src: int, topic: str, body: Any, now: float) -> None:
        """A swarm message on one of the topics (``body`` untrusted: ``[sent_at, dst, payload]``)."""
        c = self.counters.get(topic)
        if c is None:
            return
        try:
            sent_at, dst, payload = body
            sent_at = float(sent_at)
            item = msgspec.convert(payload, self.types[topic])
            if not math.isfinite(sent_at):
                raise ValueError("sent_at is not finite")
        except (msgspec.ValidationError, TypeError, ValueError) as exc:
            c.rejected += 1
            if c.rejected == 1 or c.rejected % 100 == 0:
                self.log.warning("UAV %d: message on %s from UAV %d rejected (%d so far): %s", self.cfg.uav, topic, src,
                                 c.rejected, exc)
            return
        age = max(0.0, now - sent_at)
        self._take(c, Message(src=src, topic=topic, body=item, sent_at=sent_at, age=age, unicast=dst == self.cfg.uav))

    def _take(self, c: TopicCounters, msg: Message[Any]) -> None:
        c.received += 1
        c.age_sum += msg.age
        c.age_max = max(c.age_max, msg.age)
        box = self._inbox[msg.topic]
        box.append(msg)
        if len(box) > MAX_INBOX:
            del box[0]
            c.dropped += 1

    def velocity(self, me: SelfState, members: Sequence[int]) -> Vec2:
        """The velocity of the current intent, after a step when one is due."""
        now = me.t
        if self.state == "running" and now + 1e-3 >= self._next_step:
            self._next_step = max(self._next_step + self.period, now)
            self._run_step(me, members, now)
        if self.state != "running":
            return self._stopped(me, now)
        return self._follow(me)

    # ---- stepping -------------------------------------------------------------------------
    def _refresh_context(self, me: SelfState, members: Sequence[int], now: float) -> None:
        ctx = self.ctx
        ctx.t = now
        ctx.dt = 0.0 if self._last_step_t is None else now - self._last_step_t
        self._last_step_t = now
        if self._started_at is None:
            self._started_at = now
        ctx.mission_t = now - self._started_at
        ctx.members = tuple(members)
        ctx.x, ctx.y = me.pos
        ctx.vx, ctx.vy = me.vel
        a = self.agent
        if a is not None:
            o, st = a.own, a.link.state
            ctx.z, ctx.vz, ctx.yaw = o.z, o.vz, o.yaw
            ctx.lat, ctx.lon, ctx.alt = st.lat, st.lon, st.alt
            ctx.battery = st.battery
            ctx.sim_t = st.position_boot_s
            ctx.phase = str(a.phase)
            ctx.altitude = a.flight.alt_target
        inbox = self._inbox
        self._inbox = {t: [] for t in self.topics}
        ctx._refresh(inbox)

    def _run_step(self, me: SelfState, members: Sequence[int], now: float) -> None:
        self._refresh_context(me, members, now)
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            with self._limit:
                if not self._set_up:
                    self._set_up = True
                    self.behaviour.setup(self.ctx)
                intent = self.behaviour.step(self.ctx)
        except Exception as exc:  # noqa: BLE001 - user code never stops the agent
            self.exceptions += 1
            self._intent = Hold()  # this tick: stay where it is
            self._anchor = me.pos
            self._fault("exception", f"{type(exc).__name__}: {exc}", now, exc)
            return
        finally:
            took = time.perf_counter() - t0
            cpu = time.thread_time() - c0
            self.steps += 1
            self.step_s_sum += took
            self.step_s_max = max(self.step_s_max, took)
        if intent is not None:
            problem = intent_problem(intent)
            if problem:
                self.bad_intents += 1
                self._fault("bad_intent", problem, now)
                return
            self._take_intent(intent, me)
        if cpu > self.budget_s or took > WAIT_FACTOR * self.budget_s:
            self.overruns += 1
            self._fault("overrun", f"step took {1000.0 * cpu:.1f} ms of CPU ({1000.0 * took:.1f} ms wall), over its "
                                   f"{1000.0 * self.budget_s:g} ms budget", now)
        else:
            self.in_a_row = 0  # a good step ends a run of faults

    def _take_intent(self, intent: Intent, me: SelfState) -> None:
        self._intent = intent
        if isinstance(intent, (Hold, Altitude)):
            self._anchor = me.pos
        z = intent.z if isinstance(intent, (Velocity, GoTo, Altitude)) else None
        if z is not None:
            self.altitude = min(max(float(z), self.min_alt), self.max_alt)
        if isinstance(intent, Land):
            self.request = "land"
            self.state = "landing"

    def _follow(self, me: SelfState) -> Vec2:
        i = self._intent
        x, y = me.pos
        if isinstance(i, Velocity):
            vx, vy = float(i.vx), float(i.vy)
            n = math.hypot(vx, vy)
            if n > self.speed:
                vx, vy = vx * self.speed / n, vy * self.speed / n
            return (vx, vy)
        if isinstance(i, GoTo):
            return _towards(x, y, float(i.x), float(i.y), self.speed)
        if isinstance(i, (Hold, Altitude)):
            return _towards(x, y, self._anchor[0], self._anchor[1], self.speed)
        return _ZERO

    # ---- the guard ------------------------------------------------------------------------
    def _fault(self, kind: str, detail: str, now: float, exc: BaseException | None = None) -> None:
        self.in_a_row += 1
        self.last_error = detail
        n = self.exceptions + self.overruns + self.bad_intents
        if exc is not None and (n <= 3 or n % 100 == 0):
            self.log.error("UAV %d: behaviour %s: %s (%d faults so far)", self.cfg.uav, self.spec, detail, n, exc_info=exc)
        elif n <= 3 or n % 100 == 0:
            self.log.warning("UAV %d: behaviour %s: %s: %s (%d faults so far)", self.cfg.uav, self.spec, kind, detail, n)
        recent = self._recent
        recent.append(now)
        while recent and recent[0] < now - FAULT_WINDOW_S:
            recent.popleft()
        if self.state == "running" and (self.in_a_row >= self.max_faults or len(recent) >= 2 * self.max_faults):
            self._stop(kind, detail, now)

    def _stop(self, kind: str, detail: str, now: float) -> None:
        self.state = "holding"
        self._stopped_at = now
        a = self.agent
        self._hold_point = (a.own.x, a.own.y) if a is not None else (math.nan, math.nan)
        why = (f"{self.in_a_row} faults in a row" if self.in_a_row >= self.max_faults
               else f"{len(self._recent)} faults within {FAULT_WINDOW_S:g} s")
        text = f"behaviour {self.spec} stopped after {why} (last: {kind}: {detail}); holding {self.hold_s:g} s, then landing"
        self.log.error("UAV %d: %s", self.cfg.uav, text)
        self.incidents.append({"t": now, "kind": "behaviour_stopped", "fault": kind, "detail": text[:300]})

    def _stopped(self, me: SelfState, now: float) -> Vec2:
        if self.state == "holding" and now - self._stopped_at >= self.hold_s:
            self.state = "landing"
            self.request = "land"
        if not (math.isfinite(self._hold_point[0]) and math.isfinite(self._hold_point[1])):
            self._hold_point = me.pos
        return _towards(me.pos[0], me.pos[1], self._hold_point[0], self._hold_point[1], self.speed)

    # ---- what the context offers ----------------------------------------------------------
    def _send(self, topic: str, msg: msgspec.Struct, to: int | None) -> bool:
        c = self.counters.get(topic)
        if c is None:
            self._send_error(None, f"topic {topic!r} is not among the behaviour's messages ({', '.join(self.topics)})")
            return False
        if not isinstance(msg, self.types[topic]):
            self._send_error(c, f"{topic}: expected a {self.types[topic].__name__}, got {type(msg).__name__}")
            return False
        now = self.ctx.t if self.agent is None else self.agent.clock()
        try:
            body = [now, to or 0, msgspec.to_builtins(msg)]
            if to is not None and to == self.cfg.uav:  # to itself: no network to cross
                self._take(c, Message(src=to, topic=topic, body=msg, sent_at=now, age=0.0, unicast=True))
                c.sent += 1
                return True
            node = self.agent.node if self.agent is not None else None
            if node is None and to is None:  # no agent (a simulation drives the mission): it delivers the outbox
                if len(msgspec.msgpack.encode(body)) > self.max_bytes:
                    raise ValueError(f"over the behaviour's {self.max_bytes}-byte limit (max_message_bytes)")
                self._unsent.append((topic, body))
                del self._unsent[:-MAX_INBOX]
                c.sent += 1
                return True
            if node is None:
                raise ValueError("not attached to a swarm node")
            if to is not None and not 1 <= to <= 65535:
                raise ValueError(f"no UAV {to!r}: ids are 1..65535")
            size = len(msgspec.msgpack.encode(body))
            if size > self.max_bytes:
                raise ValueError(f"{size} bytes, over the behaviour's {self.max_bytes}-byte limit (max_message_bytes)")
            node.send(topic, body, to=to)
        except (ValueError, TypeError, OverflowError, msgspec.EncodeError) as exc:
            self._send_error(c, f"{topic}: {exc}")
            return False
        except Exception as exc:  # noqa: BLE001 - a transport error (session closing) never stops the agent
            self._send_error(c, f"{topic}: {type(exc).__name__}: {exc}")
            return False
        c.sent += 1
        return True

    def _send_error(self, c: TopicCounters | None, why: str) -> None:
        if c is not None:
            c.send_errors += 1
        n = sum(x.send_errors for x in self.counters.values())
        if n <= 3 or n % 100 == 0:
            self.log.warning("UAV %d: cannot send: %s", self.cfg.uav, why)

    def _neighbours(self, now: float) -> list[Neighbour]:
        a = self.agent
        if a is None:
            return []
        stale = a.cfg.stale_after
        out = []
        for n in a.node.neighbours.snapshot():
            p = n.pose
            age = now - p.t_wall
            if now - n.last_recv > stale:
                continue
            out.append(Neighbour(p.uav, p.x, p.y, p.z, p.vx, p.vy, p.vz, age if age > 0.0 else 0.0, p.realm.label))
        return out

    def _payload(self) -> Payload | None:
        if self.payload is not None:
            return self.payload
        return self.agent.payload if self.agent is not None else None

    def _sensors(self) -> Mapping[str, SensorReading | None]:
        p = self._payload()
        if p is None:
            return {}
        return {name: s.latest() for name, s in p.sensors.items()}

    def _actuate(self, name: str, amount: float) -> bool:
        p = self._payload()
        act = p.actuators.get(name) if p is not None else None
        if act is None:
            self._actuate_errors += 1
            if self._actuate_errors <= 3 or self._actuate_errors % 100 == 0:
                self.log.warning("UAV %d: no actuator %r (it has: %s)", self.cfg.uav, name,
                                 ", ".join(sorted(p.actuators)) if p is not None and p.actuators else "none")
            return False
        act.actuate(amount)
        return True

    def _blocked(self, x: float, y: float) -> bool:
        zones = self.zones if self.zones is not None else (self.agent.zones if self.agent is not None else None)
        return zones is not None and zones.blocked((x, y), self.ctx.altitude)

    def _record_value(self, name: str, value: float) -> bool:
        if not isinstance(name, str) or not _NAME.match(name):
            what = repr(name)[:80] if isinstance(name, str) else f"of type {type(name).__name__}"
            return self._refuse("bad_name", f"name {what}: up to 64 characters of [A-Za-z0-9_.-]")
        try:  # a number: int, float, bool, numpy's; a text is not one, even "1.5"
            v = None if isinstance(value, (str, bytes, bytearray)) else float(value)
        except Exception:  # noqa: BLE001 - anything the user passes (an int beyond a float, a __float__ that raises)
            v = None
        if v is None:
            return self._refuse("bad_value", f"{name}: a {type(value).__name__} is not a number")
        if name not in self.values and len(self.values) >= MAX_VALUES:
            return self._refuse("too_many_names", f"{name}: at most {MAX_VALUES} names")
        self.values[name] = v
        t = wire_time(self.ctx.t)  # the instant as its report carries it: the CSV and run.mcap agree
        self.reporter.add(t, name, v)
        if self.records is not None:
            self.records.add(f"{t:.3f},{name},{v!r}\n")
        return True

    def _refuse(self, why: str, detail: str) -> bool:
        self._refusals[why] = self._refusals.get(why, 0) + 1
        r = self.reporter
        r.refused += 1
        r.active = True
        if r.refused <= 3 or r.refused % 100 == 0:
            self.log.warning("UAV %d: record refused (%d so far): %s", self.cfg.uav, r.refused, detail)
        return False

    def report(self, now: float) -> None:
        """Called by the agent at every tick: the values recorded and the counters onto the network when due."""
        a = self.agent
        if a is not None and self.reporter.due(now):
            self.reporter.send(a.node, {t: c.counts() for t, c in self.counters.items()}, now)

    def final_report(self, now: float) -> None:
        """The last report, when the agent closes (its node still open): what was recorded since the previous one."""
        a = self.agent
        if a is not None and self.reporter.active and \
                self.reporter.send(a.node, {t: c.counts() for t, c in self.counters.items()}, now):
            time.sleep(FINAL_LINGER_S)  # the node closes next: its session drops what has not left yet

    # ---- reports --------------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        """The stats file's ``behaviour`` section (written every second; the records flushed with it)."""
        if self.records is not None:
            self.records.flush()
        return {
            "behaviour": self.spec,
            "class": f"{type(self.behaviour).__module__}:{type(self.behaviour).__qualname__}",
            "state": self.state,
            "steps": self.steps,
            "faults": {"exceptions": self.exceptions, "overruns": self.overruns, "bad_intents": self.bad_intents},
            "budget_ms": round(1000.0 * self.budget_s, 3),
            "step_ms": {"mean": round(1000.0 * self.step_s_sum / self.steps, 3) if self.steps else None,
                        "max": round(1000.0 * self.step_s_max, 3)},
            "last_error": self.last_error,
            "actuate_errors": self._actuate_errors,
            "incidents": list(self.incidents),
            "topics": {t: c.as_dict() for t, c in self.counters.items()},
            "values": dict(self.values),
            "records_refused": dict(self._refusals),
            "reports": self.reporter.as_dict(),
        }

    def close(self) -> None:
        if self.records is not None:
            self.records.close()


class _HardLimit:
    """A timer signal that raises :class:`StepTimeout` into a step still running after ``limit_s``.

    Only in the main thread, where Python runs signal handlers. The handler stays installed
    between steps (two system calls a step instead of five); a SIGALRM outside a step goes to
    the handler that was there before, or does what SIGALRM does by default (the UAV process's
    shutdown watchdog ends the process with it). A timer that was running, due sooner than the
    limit, is never postponed, and comes back after the step."""

    def __init__(self, limit_s: float) -> None:
        self.limit_s = limit_s
        self.installed = False
        self.in_step = False
        self.prev_handler: Any = None
        self.prev_timer = (0.0, 0.0)
        self.t0 = 0.0

    def _installed(self) -> bool:
        if not self.installed:
            if threading.current_thread() is not threading.main_thread():
                return False
            self.prev_handler = signal.signal(signal.SIGALRM, self._on_alarm)
            self.installed = True
        return True

    def _on_alarm(self, signum: int, frame: FrameType | None) -> None:
        if self.in_step:
            raise StepTimeout(f"step still running after {self.limit_s:g} s: interrupted")
        prev = self.prev_handler
        if callable(prev):
            prev(signum, frame)
        elif prev != signal.SIG_IGN:  # the default action: end the process
            signal.signal(signal.SIGALRM, signal.SIG_DFL)
            signal.raise_signal(signal.SIGALRM)

    def __enter__(self) -> _HardLimit:
        if self._installed():
            self.prev_timer = signal.setitimer(signal.ITIMER_REAL, self.limit_s)
            if 0.0 < self.prev_timer[0] < self.limit_s:  # a timer due sooner (the shutdown watchdog): not postponed
                signal.setitimer(signal.ITIMER_REAL, self.prev_timer[0])
            self.t0 = time.monotonic()
            self.in_step = True
        return self

    def __exit__(self, *exc: object) -> None:
        if not self.in_step:
            return
        self.in_step = False
        took = time.monotonic() - self.t0
        ours = min(self.limit_s, self.prev_timer[0]) if self.prev_timer[0] > 0.0 else self.limit_s
        if signal.getitimer(signal.ITIMER_REAL)[0] > ours - took + 0.05:
            return  # armed again during the step (a stop signal's shutdown watchdog): that one stands
        left = self.prev_timer[0]
        if left > 0.0:  # a timer was running: it goes on, less the time the step took
            signal.setitimer(signal.ITIMER_REAL, max(1e-3, left - took), self.prev_timer[1])
        else:
            signal.setitimer(signal.ITIMER_REAL, 0.0)


def make_behaviour_mission(cfg: AgentConfig, payload: Payload | None = None, zones: ZoneField | None = None) \
        -> BehaviourMission:
    """The mission of ``cfg.mission.behaviour`` with its parameters (this UAV's ``per_uav`` ones over the mission's),
    reading ``payload`` and ``zones`` (None: its agent's)."""
    m = cfg.mission
    assert m.behaviour is not None
    cls, params = loader.load(m.behaviour, m.params, "mission")
    try:
        behaviour: Behaviour[Any] = cls(params)
    except Exception as exc:  # noqa: BLE001 - its constructor failed: every step fails, the guard holds then lands
        log.exception("UAV %d: behaviour %s could not be made", cfg.uav, m.behaviour)
        behaviour = _Unmade(cls, exc)
    return BehaviourMission(cfg, behaviour, payload=payload, zones=zones)


class _Unmade(Behaviour[Any]):
    """Stands for a behaviour whose constructor raised: each step raises that again."""

    def __init__(self, cls: type[Behaviour[Any]], exc: Exception) -> None:
        super().__init__(None)
        self.why = f"{cls.__name__}(params) raised {type(exc).__name__}: {exc}"

    def step(self, ctx: Context) -> Intent | None:
        raise RuntimeError(self.why)
