"""SwarmNode: one Zenoh session per agent, speaking the swarm key space.

Receiving never runs Python code on Zenoh's threads. Every subscription uses a bounded
``RingChannel`` (the oldest sample is dropped when full) which the owner drains with
:meth:`SwarmNode.poll` from its own loop. A slow agent therefore loses old poses instead of
stalling the whole Zenoh connection, which is what a slow zenoh-python *callback* does
(research note zenoh.md §6: one slow callback delayed an unrelated topic by 11 s). Draining
in batches is also much cheaper than waking a Python thread per message.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import zenoh

from swarmnet.connectivity import Connectivity, to_zenoh
from swarmnet.keyspace import SwarmKeys, check_swarm, uav_from_key
from swarmnet.messages import (
    DEFAULT_MAX_MESSAGE_BYTES,
    AgentState,
    Command,
    CommandAck,
    DecodeError,
    Pose,
    Realm,
    SwarmMessage,
    Telemetry,
    decode_command,
    decode_pose,
    decode_pose_batch,
    decode_swarm_message,
    encode_ack,
    encode_pose,
    encode_state,
    encode_swarm_message,
    encode_telemetry,
)
from swarmnet.neighbours import NeighbourTable
from swarmnet.stats import NodeStats

if TYPE_CHECKING:
    from swarmnet.netem import NetemShim

log = logging.getLogger(__name__)

ROLES = ("uav", "gcs", "edge", "observer")
# what the netem shim holds: kinds of delayed items (swarmnet/netem, docs/netem.md)
_POSE, _BROADCAST, _UNICAST, _CMD = 0, 1, 2, 3
_MSG_KIND = {"broadcast": _BROADCAST, "unicast": _UNICAST}


@dataclass(frozen=True)
class NodeIdentity:
    swarm: str
    uav: int  # for non-UAV roles: any id unique within the role
    realm: Realm = Realm.VIRTUAL
    role: str = "uav"

    def __post_init__(self) -> None:
        check_swarm(self.swarm)
        if not 1 <= self.uav <= 65535:
            raise ValueError(f"node id must be in 1..65535, got {self.uav}")
        if self.role not in ROLES:
            raise ValueError(f"role must be one of {ROLES}, got {self.role!r}")


@dataclass
class Inbox:
    """What arrived since the last poll (poses go straight into the neighbour table)."""

    messages: list[SwarmMessage] = field(default_factory=list)
    commands: list[Command] = field(default_factory=list)
    joined: list[str] = field(default_factory=list)  # liveliness keys that appeared
    left: list[str] = field(default_factory=list)  # ... and disappeared



def accept_pose(key: str, data: bytes, stats: NodeStats) -> Pose | None:
    """A pose sample as published under ``mrs/<swarm>/<uav>/pose``, or None (rejected and counted).

    The payload must decode and name the UAV its key names: a node cannot speak for another.
    """
    try:
        pose = decode_pose(data)
    except DecodeError as exc:
        stats.reject(exc.reason, key, exc.detail)
        return None
    if uav_from_key(key) != pose.uav:
        stats.reject("key_mismatch", key, f"payload says UAV {pose.uav}")
        return None
    return pose

class SwarmNode:
    """A UAV's (or ground station's) presence in the swarm.

    Use as a context manager or call :meth:`open`/:meth:`close`. Not thread-safe: one owner
    thread calls ``publish_*``, ``send`` and ``poll``.
    """

    def __init__(
        self,
        identity: NodeIdentity,
        connectivity: Connectivity,
        *,
        pose_rate_hz: float = 10.0,
        stale_after: float = 1.0,
        forget_after: float = 10.0,
        max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
        ring_size: int = 1024,
        pose_feed: str = "direct",
        clock: Callable[[], float] = time.time,
        netem: dict[str, Any] | None = None,
        netem_control: bool = True,
    ):
        if pose_rate_hz <= 0:
            raise ValueError("pose_rate_hz must be > 0")
        if pose_feed not in ("direct", "edge"):
            raise ValueError(f"pose_feed must be 'direct' or 'edge', not {pose_feed!r}")
        self.pose_feed = pose_feed
        self.identity = identity
        self.connectivity = connectivity
        self.keys = SwarmKeys(identity.swarm)
        self.pose_period = 1.0 / pose_rate_hz
        self.max_message_bytes = max_message_bytes
        self.ring_size = ring_size
        self.clock = clock
        self.neighbours = NeighbourTable(stale_after, forget_after)
        self.stats = NodeStats()
        self.alive: set[str] = set()  # liveliness keys currently present
        self.session: zenoh.Session | None = None
        self._decl: list[Any] = []
        self._subs: dict[str, Any] = {}
        self._pubs: dict[str, Any] = {}
        self._seq: dict[str, int] = {"pose": 0, "telemetry": 0, "state": 0, "msg": 0}
        self._next_pose = 0.0
        # netem shim (docs/netem.md): receive-side impairment of UAV and ground-station nodes
        self.netem: NetemShim | None = None
        self.netem_changes: list[dict[str, Any]] = []
        self.netem_control = netem_control and identity.role in ("uav", "gcs")
        self.own_position: tuple[float, float, float] | None = None  # as last published, for distance models
        if netem is not None:
            self.set_netem(netem, source="config")

    # ---- lifecycle ----------------------------------------------------------------------
    def open(self) -> SwarmNode:
        if self.session is not None:
            return self
        ident = self.identity
        bind = getattr(self.connectivity, "bind", None)
        if callable(bind):  # strategies that announce the node (discovery) take its identity
            bind(ident)
        self.session = s = zenoh.open(to_zenoh(self.connectivity.zenoh_config()))
        try:
            k = self.keys
            ring = zenoh.handlers.RingChannel
            if ident.role == "uav":
                u = ident.uav
                self._pubs["pose"] = s.declare_publisher(
                    k.pose(u), congestion_control=zenoh.CongestionControl.DROP, priority=zenoh.Priority.DATA_HIGH, express=True
                )
                self._pubs["telemetry"] = s.declare_publisher(k.telemetry(u))
                self._pubs["state"] = s.declare_publisher(k.state(u))
                self._pubs["ack"] = s.declare_publisher(k.ack(u), priority=zenoh.Priority.INTERACTIVE_HIGH, express=True)
                self._subs["unicast"] = s.declare_subscriber(k.all_unicast(u), ring(64))
                self._subs["cmd"] = s.declare_subscriber(k.cmd(u), ring(64))
                self._subs["swarm_cmd"] = s.declare_subscriber(k.swarm_cmd, ring(64))
            if self.pose_feed == "edge":  # one batch per edge tick instead of a message per neighbour
                self._subs["pose_batch"] = s.declare_subscriber(k.pose_feed, ring(64))
            else:
                self._subs["pose"] = s.declare_subscriber(k.all_poses, ring(self.ring_size), allowed_origin=zenoh.Locality.REMOTE)
            self._subs["broadcast"] = s.declare_subscriber(k.all_broadcast, ring(256), allowed_origin=zenoh.Locality.REMOTE)
            self._subs["alive"] = s.liveliness().declare_subscriber(k.all_alive, ring(256), history=True)
            if self.netem_control:
                self._subs["netem"] = s.declare_subscriber(k.netem_set, ring(16))
            self._token = s.liveliness().declare_token(k.alive(ident.role, ident.uav))
            self.connectivity.attach(s)
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        if self.session is None:
            return
        try:
            self.connectivity.detach()
        finally:
            s, self.session = self.session, None
            self._subs.clear()
            self._pubs.clear()
            try:
                s.close()
            except zenoh.ZError as exc:  # closing twice or a dead runtime must not raise on shutdown
                log.debug("zenoh close: %s", exc)

    def __enter__(self) -> SwarmNode:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def zid(self) -> str:
        assert self.session is not None
        return str(self.session.info.zid())

    def peers(self) -> list[str]:
        """ZIDs of the peers this session has a direct link to."""
        assert self.session is not None
        return [str(z) for z in self.session.info.peers_zid()]

    # ---- publishing ---------------------------------------------------------------------
    def _next(self, stream: str, mod: int) -> int:
        v = self._seq[stream]
        self._seq[stream] = (v + 1) % mod
        return v

    def pose_due(self, now: float) -> bool:
        return now >= self._next_pose

    def publish_pose(
        self, *, t_sim: float, x: float, y: float, z: float, vx: float, vy: float, vz: float, yaw: float, t_wall: float | None = None
    ) -> Pose:
        now = self.clock()
        # keep the schedule on a fixed grid, but never burst after a stall
        self._next_pose = max(self._next_pose + self.pose_period, now)
        pose = Pose(
            uav=self.identity.uav,
            realm=self.identity.realm,
            seq=self._next("pose", 1 << 16),
            t_sim=t_sim,
            t_wall=now if t_wall is None else t_wall,
            x=x, y=y, z=z, vx=vx, vy=vy, vz=vz, yaw=yaw,
        )
        self._pubs["pose"].put(encode_pose(pose))
        self.stats.sent["pose"] += 1
        self.own_position = (x, y, z)
        if self.netem is not None:
            self.netem.own_pos = self.own_position
        return pose

    def publish_telemetry(self, *, mode: str, armed: bool, battery: float, voltage: float, lat: float, lon: float, alt: float, rtf: float) -> None:
        t = Telemetry(
            uav=self.identity.uav, realm=self.identity.realm, seq=self._next("telemetry", 1 << 32), t_wall=self.clock(),
            mode=mode, armed=armed, battery=battery, voltage=voltage, lat=lat, lon=lon, alt=alt, rtf=rtf,
        )
        self._pubs["telemetry"].put(encode_telemetry(t))
        self.stats.sent["telemetry"] += 1

    def publish_state(self, phase: str, behaviour: str, override: str = "", detail: str = "") -> None:
        st = AgentState(
            uav=self.identity.uav, realm=self.identity.realm, seq=self._next("state", 1 << 32), t_wall=self.clock(),
            phase=phase, behaviour=behaviour, override=override, detail=detail,
        )
        self._pubs["state"].put(encode_state(st))
        self.stats.sent["state"] += 1

    def send(self, topic: str, body: Any, to: int | None = None) -> None:
        """Send a swarm message: to one UAV (unicast) or, with ``to=None``, to the whole swarm."""
        assert self.session is not None
        msg = SwarmMessage(src=self.identity.uav, dst=to or 0, topic=topic, seq=self._next("msg", 1 << 32), t_wall=self.clock(), body=body)
        data = encode_swarm_message(msg, self.max_message_bytes)
        key = self.keys.broadcast(topic) if to is None else self.keys.unicast(to, topic)
        self.session.put(key, data)
        self.stats.sent["broadcast" if to is None else "unicast"] += 1

    def ack(self, cmd_id: int, ok: bool, message: str = "") -> None:
        a = CommandAck(uav=self.identity.uav, cmd_id=cmd_id, ok=ok, message=message, t_wall=self.clock())
        self._pubs["ack"].put(encode_ack(a))
        self.stats.sent["ack"] += 1

    # ---- receiving ----------------------------------------------------------------------
    def poll(self, now: float | None = None, max_samples: int = 10_000) -> Inbox:
        """Drain everything that arrived; update the neighbour table; return the rest."""
        if now is None:
            now = self.clock()
        inbox = Inbox()
        subs = self._subs
        if not subs:
            return inbox
        stats = self.stats
        me = self.identity.uav
        if "netem" in subs:
            self._drain_netem_control(subs["netem"], now)
        shim = self.netem
        t_in = shim.arrival_time(now) if shim is not None else now
        # poses: the hot path
        pose_sub = subs.get("pose")
        budget = max_samples
        while pose_sub is not None and budget:
            sample = pose_sub.try_recv()
            if sample is None:
                break
            budget -= 1
            key = str(sample.key_expr)
            data = sample.payload.to_bytes()
            pose = accept_pose(key, data, stats)
            if pose is None:
                continue
            if shim is None or pose.uav == me:
                self._apply_pose(pose, now, key)
            else:
                self._shim_pose(shim, pose, t_in, now, key, len(data))
        batch_sub = subs.get("pose_batch")
        while batch_sub is not None:
            sample = batch_sub.try_recv()
            if sample is None:
                break
            key = str(sample.key_expr)
            try:
                batch = decode_pose_batch(sample.payload.to_bytes())
            except DecodeError as exc:
                stats.reject(exc.reason, key, exc.detail)
                continue
            stats.received["pose_batch"] += 1
            for data in batch.poses:
                try:
                    pose = decode_pose(data)
                except DecodeError as exc:
                    stats.reject(exc.reason, key, exc.detail)
                    continue
                if pose.uav == me and self.identity.role == "uav":
                    continue  # our own pose comes back in the swarm's batch
                if shim is None:
                    self._apply_pose(pose, now, key)
                else:
                    self._shim_pose(shim, pose, t_in, now, key, len(data))
        # swarm messages
        for name in ("broadcast", "unicast"):
            sub = subs.get(name)
            while sub is not None:
                sample = sub.try_recv()
                if sample is None:
                    break
                key = str(sample.key_expr)
                try:
                    msg = decode_swarm_message(sample.payload.to_bytes(), self.max_message_bytes)
                except DecodeError as exc:
                    stats.reject(exc.reason, key, exc.detail)
                    continue
                if name == "unicast" and msg.dst != me:
                    stats.reject("wrong_destination", key, f"dst {msg.dst}")
                    continue
                if uav_from_key(key) is None and msg.dst != 0:
                    stats.reject("wrong_destination", key, "unicast payload on a broadcast key")
                    continue
                if shim is not None and msg.src != me and not shim.offer(
                        shim.link(msg.src), t_in, _MSG_KIND[name], msg, key, len(sample.payload)):
                    continue  # delayed or dropped by the netem shim
                stats.received[name] += 1
                inbox.messages.append(msg)
        # commands
        for name in ("cmd", "swarm_cmd"):
            sub = subs.get(name)
            while sub is not None:
                sample = sub.try_recv()
                if sample is None:
                    break
                key = str(sample.key_expr)
                try:
                    cmd = decode_command(sample.payload.to_bytes())
                except DecodeError as exc:
                    stats.reject(exc.reason, key, exc.detail)
                    continue
                if cmd.target not in (0, me):
                    stats.reject("wrong_destination", key, f"command for UAV {cmd.target}")
                    continue
                if shim is not None and not shim.config.exempt_commands and not shim.offer(
                        shim.link(f"gcs:{cmd.sender}"), t_in, _CMD, cmd, key, len(sample.payload)):
                    continue  # delayed or dropped by the netem shim
                stats.received["cmd"] += 1
                inbox.commands.append(cmd)
        # liveliness
        sub = subs["alive"]
        while True:
            sample = sub.try_recv()
            if sample is None:
                break
            key = str(sample.key_expr)
            if sample.kind == zenoh.SampleKind.PUT:
                if key not in self.alive:
                    self.alive.add(key)
                    inbox.joined.append(key)
            elif key in self.alive:
                self.alive.discard(key)
                inbox.left.append(key)
        if shim is not None:
            for kind, item, key in shim.release(now):
                if kind == _POSE:
                    self._apply_pose(item, now, key)
                elif kind == _CMD:
                    stats.received["cmd"] += 1
                    inbox.commands.append(item)
                else:
                    stats.received["broadcast" if kind == _BROADCAST else "unicast"] += 1
                    inbox.messages.append(item)
        self.neighbours.expire(now)
        return inbox

    def _apply_pose(self, pose: Pose, now: float, key: str) -> None:
        stats = self.stats
        if pose.uav == self.identity.uav and self.identity.role == "uav":
            stats.reject("own_id", key, "another node publishes poses with our UAV id")
            return
        stats.received["pose"] += 1
        if self.neighbours.update(pose, now):
            stats.pose_age.add(now - pose.t_wall)

    # ---- netem shim (docs/netem.md) ----------------------------------------------------------
    def _shim_pose(self, shim: NetemShim, pose: Pose, t_in: float, now: float, key: str, size: int) -> None:
        link = shim.links.get(pose.uav)
        if link is None or link.realm is not pose.realm:
            link = shim.link(pose.uav, pose.realm)
        if link.distance is not None:
            link.pos = (pose.x, pose.y, pose.z)  # the sender's position when it sent this pose
        if shim.offer(link, t_in, _POSE, pose, key, size):
            self._apply_pose(pose, now, key)

    def set_netem(self, config: dict[str, Any] | None, *, source: str = "api", now: float | None = None,
                  msg_id: int | None = None) -> str:
        """Apply a netem configuration (the ``network.netem`` mapping; None: no shim at all, and
        whatever the shim still holds is discarded; ``{"preset": "none"}`` releases it instead).

        Raises :class:`~swarmnet.netem.NetemConfigError` for an invalid one. A missing ``seed``
        keeps the current seed. Returns a one-line description of what now applies.
        """
        from swarmnet.netem import NetemShim, parse_netem

        if self.identity.role not in ("uav", "gcs"):
            raise ValueError(f"a {self.identity.role} node does not impair its links")
        now = self.clock() if now is None else now
        if config is None:
            self.netem = None
            desc = "off"
        else:
            seed = self.netem.config.seed if self.netem is not None else 0
            cfg = parse_netem(config, default_seed=seed)
            if self.netem is None:
                self.netem = NetemShim(cfg, self.identity.uav, self.identity.realm, self.identity.role)
                self.netem.own_pos = self.own_position
            else:
                self.netem.reconfigure(cfg)
            desc = cfg.describe()
        preset = self.netem.config.preset if self.netem is not None else None
        self.netem_changes.append({"t": now, "source": source, "id": msg_id, "preset": preset, "config": desc})
        del self.netem_changes[:-50]  # a bounded history
        return desc

    def _drain_netem_control(self, sub: Any, now: float) -> None:
        from swarmnet.netem import NetemConfigError
        from swarmnet.netem.control import decode_netem_set

        while True:
            sample = sub.try_recv()
            if sample is None:
                return
            key = str(sample.key_expr)
            try:
                m = decode_netem_set(sample.payload.to_bytes())
            except DecodeError as exc:
                self.stats.reject(exc.reason, key, exc.detail)
                continue
            if m.targets is not None and self.identity.uav not in m.targets:
                continue
            try:
                desc = self.set_netem(m.config, source=m.sender, now=now, msg_id=m.id)
            except (NetemConfigError, ValueError, TypeError, KeyError, RecursionError) as exc:  # bad input never crashes the UAV
                self.stats.reject("bad_netem_config", key, str(exc))
                if "ack" in self._pubs:
                    self.ack(m.id, False, f"netem: {exc}"[:200])
                continue
            self.stats.received["netem_set"] += 1
            self.netem_changes[-1]["t_sent"] = m.t_wall
            if "ack" in self._pubs:
                self.ack(m.id, True, f"netem: {desc}"[:200])

    def netem_stats(self) -> dict[str, Any] | None:
        """Per-link statistics and the history of changes, for the stats JSON (None: never configured)."""
        if self.netem is None and not self.netem_changes:
            return None
        out: dict[str, Any] = self.netem.stats() if self.netem is not None else {"config": "off", "links": {}}
        out["changes"] = list(self.netem_changes)
        return out

    def alive_uavs(self) -> set[int]:
        """UAV ids whose liveliness token is present (the node's own included)."""
        prefix = f"{self.keys.prefix}/alive/uav/"
        out = set()
        for key in self.alive:
            if key.startswith(prefix):
                tail = key[len(prefix):]
                if tail.isdigit():
                    out.add(int(tail))
        return out
