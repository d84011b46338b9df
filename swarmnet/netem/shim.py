"""The shim: one :class:`Link` per (sender -> this node), one time-ordered heap for all of them.

A receiving node hands every accepted message to :meth:`NetemShim.offer` with the time it
arrived. A link whose profile does nothing answers "deliver now" after bumping two counters
(the no-impairment path). Otherwise the link runs netem's per-packet pipeline and the message
waits in the heap until :meth:`NetemShim.release` is called at or after its time to send.
No threads, no timers: the owner calls ``release`` from its own loop, so delivery to the
controller happens at the owner's poll resolution, while the shim's own times are exact: the
owner offers each message with its arrival stamp and takes each released one with its time
to send, which is its arrival through the emulated link (its transport age counts from there).

Per message, in order (netem's ``netem_enqueue`` plus the wireless stages in front):

1. reachability: partitions; outages of the emulated radios (drop, or hold until the end);
   distance: a Bernoulli draw with the distance model's delivery probability;
2. duplicate, then loss: ``count = 1 + dup - lost``; 0 copies = dropped; a duplicate gets its
   own loss draws (distance and loss model) and its own delay, and is never duplicated again;
3. queue limit (messages of this link in the heap);
4. reorder (netem: sent immediately if ``counter >= gap - 1`` and ``rand < p``, counter reset)
   or delay (distribution, AR(1) correlation), then the rate limit (serialisation after the
   last queued message of the link), FIFO clamp if configured, and an outage hold;
5. into the heap keyed on (time to send, arrival order).

Counters per link: sent (offered), delivered, dropped by reason, duplicated, reordered (RFC
4737: delivered after a message offered later, i.e. with a lower per-link index than one
already delivered), jumps (netem's immediate reorder sends) and the delay histogram
(time to send - arrival, of delivered messages). ``sent + duplicated == delivered + dropped + queued``.
"""

from __future__ import annotations

import heapq
import math
import random
from collections import Counter
from typing import Any

from groundfloor.histogram import LogHistogram
from swarmnet.messages import Realm
from swarmnet.netem.config import LinkProfile, NetemConfig, OutageSpec
from swarmnet.netem.models import DelayGen, LossGen, OutageSchedule


class Link:
    """State of one directed link ``src -> dst``; ``src`` is a UAV id or ``"gcs:<name>"``."""

    __slots__ = (
        "src", "dst", "realm", "cls", "profile", "passthrough", "rng", "delay", "loss", "dup", "reorder", "rate_bps",
        "overhead", "limit", "fifo", "outage", "radios", "distance", "partitioned", "queued", "last_tts", "counter",
        "next_idx", "max_released", "pos", "sent", "delivered", "zero_delay", "duplicated", "reordered", "jumps",
        "dropped", "hist", "no_position",
    )

    def __init__(self, src: int | str, dst: int, realm: Realm | None, seed: int | str):
        self.src, self.dst, self.realm = src, dst, realm
        self.rng = random.Random(f"netem/{seed}/{src}/{dst}")
        self.cls: str | None = None
        self.profile: LinkProfile | None = None
        self.passthrough = True
        self.queued = 0
        self.last_tts = -math.inf
        self.counter = 0  # netem's reorder counter
        self.next_idx = 0
        self.max_released = -1
        self.pos: tuple[float, float, float] | None = None  # sender's latest position (from its poses, before the shim)
        self.sent = self.delivered = self.zero_delay = self.duplicated = self.reordered = self.jumps = self.no_position = 0
        self.dropped: Counter[str] = Counter()
        self.hist = LogHistogram()
        self.partitioned = False
        self._set(None, False)

    def _set(self, profile: LinkProfile | None, partitioned: bool, radios: tuple[OutageSchedule, ...] = ()) -> None:
        self.profile = profile
        self.partitioned = partitioned
        self.passthrough = not partitioned and (profile is None or profile.passthrough)
        p = profile or LinkProfile()
        self.delay = DelayGen(p.delay) if p.delay is not None else None
        self.loss = LossGen(p.loss) if p.loss is not None else None
        self.dup = p.duplicate
        self.reorder = p.reorder
        self.rate_bps = p.rate.kbit * 1000.0 if p.rate is not None else 0.0
        self.overhead = p.rate.overhead_bytes if p.rate is not None else 0
        self.limit = p.limit
        self.fifo = p.delay.fifo if p.delay is not None else False
        self.outage: OutageSpec | None = p.outage
        self.radios = radios if p.outage is not None else ()
        self.distance = p.distance

    def stats(self) -> dict[str, Any]:
        delay = self.hist.to_dict()
        if self.zero_delay:  # pass-through deliveries: delay 0, the underflow bin
            delay["bins"][0] = delay["bins"].get(0, 0) + self.zero_delay
            delay["n"] += self.zero_delay
        return {
            "class": self.cls,
            "profile": self.profile.describe() if self.profile is not None else "no impairment",
            "sent": self.sent,
            "delivered": self.delivered,
            "dropped": dict(self.dropped),
            "duplicated": self.duplicated,
            "reordered": self.reordered,
            "jumps": self.jumps,
            "queued": self.queued,
            "no_position": self.no_position,
            "delay": delay,
        }


class NetemShim:
    """All receive-side links of one node.

    ``me``/``realm``/``role`` describe the receiving node; ``own_pos`` is its latest position
    (the node sets it whenever it publishes a pose) for distance models.
    """

    def __init__(self, config: NetemConfig, me: int, realm: Realm = Realm.VIRTUAL, role: str = "uav"):
        self.config = config
        self.me = me
        self.realm = realm
        self.role = role
        self.own_pos: tuple[float, float, float] | None = None
        self.links: dict[int | str, Link] = {}
        self._heap: list[tuple[float, int, Link, int, float, int, Any, str]] = []
        self._seq = 0
        self._ready: list[tuple[int, Any, str, float]] = []
        self._radios: dict[tuple[int | str, OutageSpec], OutageSchedule] = {}

    # ---- configuration ------------------------------------------------------------------------
    def link_class(self, src: int | str, src_realm: Realm | None) -> str | None:
        """The class of link ``src -> me``; None for links never impaired (physical <-> physical)."""
        me_virtual = self.realm == Realm.VIRTUAL
        if isinstance(src, str):  # a ground station's command
            return "ground" if me_virtual else None
        src_virtual = src_realm != Realm.PHYSICAL  # unknown realm (no pose yet): virtual
        if self.role == "gcs":
            return "ground" if src_virtual else None
        if me_virtual and src_virtual:
            return "v2v"
        if me_virtual or src_virtual:
            return "v2p"
        return None

    def _configure(self, link: Link) -> None:
        cfg = self.config
        cls = self.link_class(link.src, link.realm)
        link.cls = cls
        if cls is None:
            link._set(None, False)
            return
        profile = cfg.profile_for(cls, link.src, self.me)
        parts = cfg.partitions
        partitioned = (cls != "ground" and link.src in parts and self.me in parts and parts[link.src] != parts[self.me])
        radios: tuple[OutageSchedule, ...] = ()
        if profile is not None and profile.outage is not None:
            # only the emulated radios: both UAVs for v2v, the virtual one for v2p, the UAV for ground links
            ids: list[int | str] = []
            if cls == "v2v":
                ids = [link.src, self.me]
            elif cls == "v2p":
                ids = [self.me] if self.realm == Realm.VIRTUAL else [link.src]
            else:
                ids = [self.me] if self.role != "gcs" else [link.src]
            radios = tuple(self._radio(u, profile.outage) for u in ids)
        link._set(profile, partitioned, radios)

    def _radio(self, uav: int | str, spec: OutageSpec) -> OutageSchedule:
        key = (uav, spec)
        r = self._radios.get(key)
        if r is None:
            r = self._radios[key] = OutageSchedule(self.config.seed, uav, spec)
        return r

    def reconfigure(self, config: NetemConfig) -> None:
        """Switch every link to a new configuration (queued messages keep their times; model state resets)."""
        self.config = config
        self._radios.clear()
        for link in self.links.values():
            self._configure(link)

    def link(self, src: int | str, realm: Realm | None = None) -> Link:
        """The link from ``src`` (created on first use); a known realm re-classifies it if it changed."""
        lk = self.links.get(src)
        if lk is None:
            lk = self.links[src] = Link(src, self.me, realm, self.config.seed)
            self._configure(lk)
        elif realm is not None and lk.realm is not realm:
            lk.realm = realm
            self._configure(lk)
        return lk

    # ---- the data path ------------------------------------------------------------------------------
    def offer(self, link: Link, now: float, kind: int, item: Any, key: str = "", size: int = 48) -> bool:
        """Give the shim a message that arrived at ``now``. True: deliver it now (pass-through link);
        False: the shim has it (queued for :meth:`release`, or dropped)."""
        link.sent += 1
        if link.passthrough:
            link.max_released = link.next_idx
            link.next_idx += 1
            link.delivered += 1
            link.zero_delay += 1
            return True
        self._impair(link, now, kind, item, key, size)
        return False

    def _lost(self, link: Link) -> str | None:
        """The loss stages one copy goes through (distance, then the loss model): the reason it is lost, or None."""
        rng = link.rng
        dist = link.distance
        if dist is not None:
            a, b = link.pos, self.own_pos
            if a is None or b is None:
                link.no_position += 1
            else:
                p = dist.p_deliver(math.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2))
                if p < 1.0 and rng.random() >= p:
                    return "distance"
        loss = link.loss
        if loss is not None and loss.lost(rng):
            return "loss"
        return None

    def _impair(self, link: Link, now: float, kind: int, item: Any, key: str, size: int) -> None:
        self._advance(now)
        idx = link.next_idx
        link.next_idx = idx + 1
        dropped = link.dropped
        if link.partitioned:
            dropped["partition"] += 1
            return
        hold = 0.0
        if link.radios:
            for radio in link.radios:
                end = radio.down_until(now)
                if end > hold:
                    hold = end
            if hold and link.outage is not None and link.outage.mode == "drop":
                dropped["outage"] += 1
                return
        dup = link.dup > 0.0 and link.rng.random() < link.dup
        why = self._lost(link)
        if why is not None and not dup:
            dropped[why] += 1
            return
        # netem: count = 1 + dup - lost; "duplicated and lost" still sends one copy
        self._enqueue(link, now, kind, item, key, size, idx, hold)
        if dup and why is None:
            link.duplicated += 1  # the clone gets its own loss draws and its own delay, and is never duplicated again
            why = self._lost(link)
            if why is not None:
                dropped[why] += 1
            else:
                self._enqueue(link, now, kind, item, key, size, idx, hold)

    def _enqueue(self, link: Link, now: float, kind: int, item: Any, key: str, size: int, idx: int, hold: float) -> None:
        if link.queued >= link.limit:
            link.dropped["queue"] += 1
            return
        rd = link.reorder
        if rd is not None and link.counter >= rd.gap - 1 and link.rng.random() < rd.p:
            tts = now  # netem: straight to the head of the queue
            link.counter = 0
            link.jumps += 1
        else:
            delay = link.delay.draw(link.rng) if link.delay is not None else 0.0
            base = now
            if link.rate_bps:
                # netem: the last queued message is the reference; its remaining time counts against our delay
                if link.queued and link.last_tts > now:
                    delay = max(0.0, delay - (link.last_tts - now))
                    base = link.last_tts
                delay += (size + link.overhead) * 8.0 / link.rate_bps
            tts = base + delay
            if link.fifo and link.queued and tts < link.last_tts:
                tts = link.last_tts
            link.counter += 1
        if hold > tts:
            tts = hold
        link.queued += 1
        if tts > link.last_tts or link.queued == 1:
            link.last_tts = tts
        self._seq += 1
        heapq.heappush(self._heap, (tts, self._seq, link, idx, now, kind, item, key))

    def _advance(self, now: float) -> None:
        """Move everything due at ``now`` from the heap to the ready list (in time-to-send order)."""
        heap = self._heap
        ready = self._ready
        while heap and heap[0][0] <= now:
            tts, _, link, idx, arrived, kind, item, key = heapq.heappop(heap)
            link.queued -= 1
            link.delivered += 1
            link.hist.add(tts - arrived)
            if idx < link.max_released:
                link.reordered += 1
            else:
                link.max_released = idx
            ready.append((kind, item, key, tts))

    def release(self, now: float) -> list[tuple[int, Any, str, float]]:
        """Everything due at ``now``, in order: ``(kind, item, key, time to send)``, the first three
        as given to :meth:`offer`; the time to send is when the emulated link delivers the item."""
        if self._heap and self._heap[0][0] <= now:
            self._advance(now)
        if not self._ready:
            return []
        out, self._ready = self._ready, []
        return out

    @property
    def pending(self) -> int:
        return len(self._heap) + len(self._ready)

    def next_due(self) -> float | None:
        return self._heap[0][0] if self._heap else None

    def held_until(self, kind: int, since: float) -> float | None:
        """When the last item of ``kind`` that arrived at or after ``since`` (wall time, s) and is
        still held is released (its time to send); None if none is held."""
        last = None
        for tts, _, _, _, arrived, k, _, _ in self._heap:
            if k == kind and arrived >= since and (last is None or tts > last):
                last = tts
        return last

    # ---- reporting --------------------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        return {
            "me": self.me,
            "config": self.config.describe(),
            "preset": self.config.preset,
            "seed": self.config.seed,
            "pending": self.pending,
            "links": {str(src): lk.stats() for src, lk in sorted(self.links.items(), key=lambda kv: str(kv[0]))},
        }
