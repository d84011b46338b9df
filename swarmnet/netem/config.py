"""The netem configuration: its schema (msgspec Structs), presets merged with patches, per-link resolution.

One definition of what is valid, used by the scenario loader (``network.netem`` is a
:class:`NetemSpec`), by ``mrswarm netem set`` and by the UAV process when a runtime change
arrives on ``mrs/<swarm>/netem/set``. Errors are :class:`NetemConfigError`, whose message
starts with the dotted path of the field, e.g. ``v2v.loss.p: must be a number <= 1, got 1.5``.

What is written (docs/netem.md explains every knob)::

    preset: none | lan | 5g-campus | lte | degraded | wifi-mesh     # base profiles per class
    seed: 7                      # per-link RNG seeds derive from it (default: scenario seed)
    exempt_commands: true        # ground-station commands bypass the shim
    v2v | v2p | ground:          # merged onto the preset's profile for that class (null: none)
      delay:     {ms, jitter_ms: 0, distribution: uniform|normal|pareto|paretonormal,
                  correlation: 0, fifo: false}
      loss:      {model: bernoulli, p}
               | {model: gilbert_elliott, p, r, loss_bad: 1, loss_good: 0}
               | {model: gilbert_elliott, rate, burst}
               | {model: four_state, p13, p31: 1-p13, p32: 0, p23: 1, p14: 0}
      duplicate: 0.01
      reorder:   {p, gap: 1}
      rate:      {kbit, overhead_bytes: 0}
      limit:     1000            # queue limit per link, messages
      outage:    {every_s, duration_ms: X | [min, max], mode: drop | hold}
      distance:  {model: range, range_m, full_m: range_m}
               | {model: log_distance, exponent, sigma_db: 0, freq_ghz: 2.4, ref_loss_db: Friis,
                  tx_dbm: 20, gains_dbi: 0, sensitivity_dbm: -91}
    links:                       # per-link overrides, merged onto the class profile in order
      - {src: 3, dst: 5, both_ways: false, <profile fields>}     # src/dst: UAV id or "*"
    partitions: {north: [1, 2, 3], south: [4, 5]}   # UAVs in different partitions never hear each other

A class entry or a link override is a *patch*: its components are merged onto the profile
below it (:func:`merge_profile`) and only the result must be a valid :class:`LinkProfile`. So
:class:`ProfilePatch` holds components as plain mappings, and :class:`LinkProfile` (with
:class:`DelaySpec`, the loss models, ...) is what the shim runs.
"""

from __future__ import annotations

import copy
import math
import typing
from dataclasses import dataclass, field
from typing import Annotated, Any, ClassVar, Literal

import msgspec
from msgspec import UNSET, Meta, UnsetType
from msgspec.structs import force_setattr

from groundfloor.schema import Config, ConfigError, join, to_builtins
from groundfloor.schema import convert as _convert
from swarmnet.netem.presets import PRESETS

CLASSES = ("v2v", "v2p", "ground")
PROFILE_KEYS = ("delay", "loss", "duplicate", "reorder", "rate", "limit", "outage", "distance")
DEFAULT_LIMIT = 1000
MAX_DELAY_MS = 60_000.0
SPEED_OF_LIGHT = 299_792_458.0

Preset = Literal["none", "lan", "5g-campus", "lte", "degraded", "wifi-mesh"]
assert set(typing.get_args(Preset)) == set(PRESETS), "the Preset choices must name swarmnet/netem/presets.py's presets"
Distribution = Literal["uniform", "normal", "pareto", "paretonormal"]
Probability = Annotated[float, Meta(ge=0.0, le=1.0, description="probability")]
DelayMs = Annotated[float, Meta(ge=0.0, le=MAX_DELAY_MS, description="ms")]
OutageMs = Annotated[float, Meta(ge=0.0, le=3.6e6, description="ms")]
UavId = Annotated[int, Meta(ge=1, le=65535, description="UAV id")]
Seed = Annotated[int, Meta(ge=0, le=2**63 - 1)] | Annotated[str, Meta(min_length=1, max_length=64)]


class NetemConfigError(ConfigError):
    """An invalid netem configuration; ``path`` is the dotted field, ``msg`` what is wrong."""


def convert(data: Any, type_: Any, at: str = "") -> Any:
    """:func:`groundfloor.schema.convert` raising :class:`NetemConfigError`, the path prefixed with ``at``."""
    try:
        return _convert(data, type_, error=NetemConfigError)
    except NetemConfigError as exc:
        raise NetemConfigError(join(at, exc.path), exc.msg) from None


# ---- what a link runs: the validated profile and its components --------------------------------------
class DelaySpec(Config, frozen=True):
    ms: DelayMs  # mean one-way delay added
    jitter_ms: DelayMs = 0.0  # sd (normal, pareto, paretonormal) or half-width (uniform)
    distribution: Distribution | None = None  # required with jitter_ms > 0
    correlation: Annotated[float, Meta(ge=0.0, lt=1.0, description="AR(1) lag-1 correlation of successive delays")] = 0.0
    fifo: bool = False  # never let jitter reorder (each message leaves after the previous one)

    def __post_init__(self) -> None:
        if self.jitter_ms > 0.0 and self.distribution is None:
            raise NetemConfigError("distribution", "required with jitter_ms > 0 (uniform, normal, pareto or paretonormal)")


class BernoulliLoss(Config, tag_field="model", tag="bernoulli", frozen=True):
    model: ClassVar[str] = "bernoulli"
    p: Probability  # loss probability

    @property
    def expected_rate(self) -> float:
        return self.p


class GilbertElliottLoss(Config, tag_field="model", tag="gilbert_elliott", frozen=True):
    """Two states; given as ``p, r (, loss_bad, loss_good)`` or calibrated from ``rate, burst``.

    After validation ``p``, ``r``, ``loss_bad`` and ``loss_good`` always hold the chain (the
    ``rate``/``burst`` form fills them in: r = 1/burst, p = rate r / (1 - rate)).
    """

    model: ClassVar[str] = "gilbert_elliott"
    p: Probability | None = None  # P(good -> bad) per message
    r: Probability | None = None  # P(bad -> good) per message
    loss_bad: Probability | None = None  # 1-h, loss probability in the bad state (default 1)
    loss_good: Probability | None = None  # 1-k, loss probability in the good state (default 0)
    rate: Annotated[float, Meta(ge=0.0, le=0.99, description="long-run loss rate")] | None = None
    burst: Annotated[float, Meta(ge=1.0, le=1e6, description="mean burst length, messages")] | None = None

    def __post_init__(self) -> None:
        if self.rate is not None or self.burst is not None:
            for k in ("p", "r", "loss_bad", "loss_good"):
                if getattr(self, k) is not None:
                    raise NetemConfigError(k, "give either rate + burst or p + r (+ loss_bad, loss_good), not both")
            if self.rate is None or self.burst is None:
                raise NetemConfigError("burst" if self.rate is not None else "rate", "rate and burst go together")
            r = 1.0 / self.burst
            force_setattr(self, "r", r)
            force_setattr(self, "p", self.rate * r / (1.0 - self.rate))
        else:
            for k in ("p", "r"):
                if getattr(self, k) is None:
                    raise NetemConfigError(k, "required (or give rate + burst)")
            if self.p == 0.0 and self.r == 0.0:
                raise NetemConfigError("r", "p and r cannot both be 0")
        if self.loss_bad is None:
            force_setattr(self, "loss_bad", 1.0)
        if self.loss_good is None:
            force_setattr(self, "loss_good", 0.0)

    @property
    def expected_rate(self) -> float:
        p, r = typing.cast(float, self.p), typing.cast(float, self.r)
        pb = p / (p + r) if p + r > 0 else 0.0
        return pb * typing.cast(float, self.loss_bad) + (1.0 - pb) * typing.cast(float, self.loss_good)


class FourStateLoss(Config, tag_field="model", tag="four_state", frozen=True):
    """netem's ``loss state``: 1 gap, 2 burst (delivered), 3 burst (lost), 4 isolated loss."""

    model: ClassVar[str] = "four_state"
    p13: Probability
    p31: Probability = -1.0  # default 1 - p13 (filled in)
    p32: Probability = 0.0
    p23: Probability = 1.0
    p14: Probability = 0.0

    def __post_init__(self) -> None:
        if self.p31 < 0.0:
            force_setattr(self, "p31", 1.0 - self.p13)
        if self.p13 + self.p14 > 1.0:
            raise NetemConfigError("p14", "p13 + p14 must be <= 1")
        if self.p31 + self.p32 > 1.0:
            raise NetemConfigError("p32", "p31 + p32 must be <= 1")

    @property
    def expected_rate(self) -> float:
        pi = four_state_stationary(self)
        return pi[2] + pi[3]


LossSpec = BernoulliLoss | GilbertElliottLoss | FourStateLoss


class ReorderSpec(Config, frozen=True):
    p: Probability  # probability of sending a message immediately (once gap - 1 were delayed)
    gap: Annotated[int, Meta(ge=1, le=1_000_000)] = 1


class RateSpec(Config, frozen=True):
    kbit: Annotated[float, Meta(gt=0.0, le=1e9, description="link rate, kbit/s")]
    overhead_bytes: Annotated[int, Meta(ge=0, le=65535)] = 0


class OutageSpec(Config, frozen=True):
    every_s: Annotated[float, Meta(gt=0.0, le=1e7, description="mean time between outages, s")]
    # a duration, or [min, max] of a uniform one. The single number's range is checked below: a
    # union of a constrained number and a tuple crashes msgspec 0.22's garbage collection
    # (a case of https://github.com/msgspec/msgspec/issues/717)
    duration_ms: float | tuple[OutageMs, OutageMs]
    mode: Literal["drop", "hold"] = "drop"

    def __post_init__(self) -> None:
        d = self.duration_ms
        if not isinstance(d, tuple) and not 0.0 <= d <= 3.6e6:
            raise NetemConfigError("duration_ms", f"must be a number >= 0 and <= 3.6e+06 (ms), got {d!r}")
        if self.duration_max_ms < self.duration_min_ms:
            raise NetemConfigError("duration_ms", "need min <= max")
        if self.duration_max_ms / 1000.0 >= self.every_s:
            raise NetemConfigError("duration_ms", f"outages of up to {self.duration_max_ms:g} ms every {self.every_s:g} s "
                                   "would never end")

    @property
    def duration_min_ms(self) -> float:
        d = self.duration_ms
        return d[0] if isinstance(d, tuple) else d

    @property
    def duration_max_ms(self) -> float:
        d = self.duration_ms
        return d[1] if isinstance(d, tuple) else d


class RangeDistance(Config, tag_field="model", tag="range", frozen=True):
    """Delivery probability 1 up to ``full_m``, falling linearly to 0 at ``range_m``."""

    model: ClassVar[str] = "range"
    range_m: Annotated[float, Meta(gt=0.0, le=1e7, description="no delivery beyond this distance, m")]
    full_m: Annotated[float, Meta(ge=0.0, description="full delivery up to this distance, m (default range_m)")] = -1.0

    def __post_init__(self) -> None:
        if self.full_m < 0.0:
            force_setattr(self, "full_m", self.range_m)
        if self.full_m > self.range_m:
            raise NetemConfigError("full_m", f"must be <= range_m ({self.range_m:g}), got {self.full_m:g}")

    def p_deliver(self, d: float) -> float:
        """Probability that a message over ``d`` metres arrives (before any other impairment)."""
        if d <= self.full_m:
            return 1.0
        if d >= self.range_m:
            return 0.0
        return (self.range_m - d) / (self.range_m - self.full_m)

    def nominal_range_m(self) -> float:
        """The mid-point of the fade (delivery probability 0.5)."""
        return 0.5 * (self.full_m + self.range_m)


class LogDistance(Config, tag_field="model", tag="log_distance", frozen=True):
    """Log-distance path loss with log-normal shadowing, reference distance 1 m."""

    model: ClassVar[str] = "log_distance"
    exponent: Annotated[float, Meta(ge=1.0, le=8.0, description="path-loss exponent, 2 = free space")]
    sigma_db: Annotated[float, Meta(ge=0.0, le=30.0, description="shadowing sd, dB")] = 0.0
    freq_ghz: Annotated[float, Meta(gt=0.0, le=300.0)] = 2.4
    ref_loss_db: Annotated[float, Meta(ge=0.0, le=200.0, description="path loss at 1 m, dB (default Friis)")] = -1.0
    tx_dbm: Annotated[float, Meta(ge=-50.0, le=60.0)] = 20.0
    gains_dbi: Annotated[float, Meta(ge=-30.0, le=60.0)] = 0.0
    sensitivity_dbm: Annotated[float, Meta(ge=-200.0, le=0.0)] = -91.0

    def __post_init__(self) -> None:
        if self.ref_loss_db < 0.0:
            force_setattr(self, "ref_loss_db", friis_ref_loss_db(self.freq_ghz))

    def p_deliver(self, d: float) -> float:
        """Probability that a message over ``d`` metres arrives (before any other impairment)."""
        pl = self.ref_loss_db + 10.0 * self.exponent * math.log10(max(d, 1.0))
        margin = self.tx_dbm + self.gains_dbi - pl - self.sensitivity_dbm  # mean received power over the threshold, dB
        if self.sigma_db <= 0.0:
            return 1.0 if margin >= 0.0 else 0.0
        return 0.5 * math.erfc(-margin / (self.sigma_db * math.sqrt(2.0)))

    def nominal_range_m(self) -> float:
        """Distance where the delivery probability is 0.5."""
        return 10.0 ** ((self.tx_dbm + self.gains_dbi - self.sensitivity_dbm - self.ref_loss_db) / (10.0 * self.exponent))


DistanceSpec = RangeDistance | LogDistance


class LinkProfile(Config, frozen=True):
    """What one (sender -> receiver) link does to every message."""

    delay: DelaySpec | None = None
    loss: LossSpec | None = None
    duplicate: Probability = 0.0
    reorder: ReorderSpec | None = None
    rate: RateSpec | None = None
    limit: Annotated[int, Meta(ge=1, le=1_000_000, description="queue limit, messages")] = DEFAULT_LIMIT
    outage: OutageSpec | None = None
    distance: DistanceSpec | None = None

    def __post_init__(self) -> None:
        if self.reorder is not None and (self.delay is None or self.delay.ms == 0.0):
            raise NetemConfigError("reorder", "reordering needs a delay (delay.ms > 0) to overtake, as in netem")

    @property
    def passthrough(self) -> bool:
        """True when the profile does nothing, so the shim can deliver without any work."""
        return (
            (self.delay is None or (self.delay.ms == 0.0 and self.delay.jitter_ms == 0.0))
            and (self.loss is None or self.loss.expected_rate == 0.0)
            and self.duplicate == 0.0 and self.reorder is None and self.rate is None
            and self.outage is None and self.distance is None
        )

    def describe(self) -> str:
        parts = []
        d = self.delay
        if d is not None and (d.ms or d.jitter_ms):
            s = f"delay {d.ms:g}ms"
            if d.jitter_ms:
                s += f" {d.jitter_ms:g}ms {d.distribution}"
            if d.correlation:
                s += f" rho {d.correlation:g}"
            parts.append(s)
        if self.loss is not None:
            loss = self.loss
            parts.append(f"loss {loss.model} {100 * loss.expected_rate:.3g}%")
        if self.duplicate:
            parts.append(f"duplicate {100 * self.duplicate:g}%")
        if self.reorder:
            parts.append(f"reorder {100 * self.reorder.p:g}% gap {self.reorder.gap}")
        if self.rate:
            parts.append(f"rate {self.rate.kbit:g}kbit")
        if self.outage:
            o = self.outage
            parts.append(f"outage every {o.every_s:g}s {o.duration_min_ms:g}-{o.duration_max_ms:g}ms {o.mode}")
        if self.distance:
            parts.append(f"distance {self.distance.model} (50% at {self.distance.nominal_range_m():.0f} m)")
        return ", ".join(parts) or "no impairment"


def four_state_stationary(s: FourStateLoss) -> tuple[float, float, float, float]:
    """Stationary probabilities of states 1 (gap, delivered), 2 (burst, delivered), 3 (burst, lost),
    4 (isolated loss) of the 4-state chain."""
    # balance equations: pi4 = p14 pi1; pi2 p23 = p32 pi3; pi3 (p31 + p32) = p13 pi1 + p23 pi2
    # => pi3 p31 = p13 pi1, so pi3 = p13/p31 pi1, pi2 = p32/p23 pi3
    if s.p13 == 0.0 and s.p14 == 0.0:
        return (1.0, 0.0, 0.0, 0.0)
    if s.p31 == 0.0 or (s.p32 > 0.0 and s.p23 == 0.0):
        # absorbing burst: everything ends up in states 2/3
        if s.p32 == 0.0:
            return (0.0, 0.0, 1.0, 0.0)
        return (0.0, 1.0, 0.0, 0.0) if s.p23 == 0.0 else (0.0, s.p23 / (s.p23 + s.p32), s.p32 / (s.p23 + s.p32), 0.0)
    w1 = 1.0
    w3 = s.p13 / s.p31
    w2 = s.p32 / s.p23 * w3 if s.p32 > 0.0 else 0.0
    w4 = s.p14
    tot = w1 + w2 + w3 + w4
    return (w1 / tot, w2 / tot, w3 / tot, w4 / tot)


def friis_ref_loss_db(freq_ghz: float, d0: float = 1.0) -> float:
    lam = SPEED_OF_LIGHT / (freq_ghz * 1e9)
    return 20.0 * math.log10(4.0 * math.pi * d0 / lam)


def compile_profile(raw: dict[str, Any], path: str) -> LinkProfile:
    """Validate a merged profile (plain mapping) into the :class:`LinkProfile` a link runs."""
    loss = raw.get("loss") if isinstance(raw, dict) else None
    if isinstance(loss, dict) and "correlation" in loss:
        raise NetemConfigError(join(path, "loss.correlation"), "netem's loss correlation is not supported (it does not "
                               "keep the loss rate: 1% with 25% correlation loses ~0.0003%); use model: gilbert_elliott "
                               "for bursty loss")
    return typing.cast(LinkProfile, convert(raw, LinkProfile, path))


def merge_profile(base: dict[str, Any], patch: dict[str, Any]) -> dict[str, Any]:
    """Merge a profile patch onto a profile (both plain mappings).

    A component given as ``null`` is removed. Mapping components are merged field by field,
    except that a patch naming a different ``model`` (loss, distance) replaces the component.
    Scalars (duplicate, limit) are replaced.
    """
    out = copy.deepcopy(base)
    for k, v in patch.items():
        if v is None:
            out.pop(k, None)
        elif isinstance(v, dict) and isinstance(out.get(k), dict) and v.get("model", out[k].get("model")) == out[k].get("model"):
            merged = dict(out[k])
            merged.update(copy.deepcopy(v))
            if k == "loss" and merged.get("model") == "gilbert_elliott":
                # rate + burst and p + r describe the same thing: the patch's form wins
                if "rate" in v or "burst" in v:
                    for kk in ("p", "r", "loss_bad", "loss_good"):
                        merged.pop(kk, None)
                elif "p" in v or "r" in v:
                    merged.pop("rate", None)
                    merged.pop("burst", None)
            out[k] = merged
        else:
            out[k] = copy.deepcopy(v)
    return out


# ---- what is written: network.netem --------------------------------------------------------------------
Component = dict[str, Any] | None | UnsetType  # merged onto the profile below, validated as a LinkProfile


class ProfilePatch(Config, omit_defaults=True, frozen=True):
    """A class entry (``v2v``, ``v2p``, ``ground``) as written: components to merge onto the preset's.

    A component left out keeps the preset's; ``null`` removes it.
    """

    delay: Component = UNSET
    loss: Component = UNSET
    duplicate: Probability | None | UnsetType = UNSET
    reorder: Component = UNSET
    rate: Component = UNSET
    limit: Annotated[int, Meta(ge=1, le=1_000_000)] | None | UnsetType = UNSET
    outage: Component = UNSET
    distance: Component = UNSET

    def patch(self) -> dict[str, Any]:
        """The components given, as a plain mapping for :func:`merge_profile` (None: remove)."""
        return {k: v for k in PROFILE_KEYS if (v := getattr(self, k)) is not UNSET}


class LinkPatch(ProfilePatch, kw_only=True, frozen=True):
    """A per-link override: a patch for the links ``src -> dst`` (and back with ``both_ways``)."""

    src: UavId | Literal["*"]
    dst: UavId | Literal["*"]
    both_ways: bool = False

    def __post_init__(self) -> None:
        if self.src == "*" and self.dst == "*":
            raise NetemConfigError("", "src and dst cannot both be \"*\" (change the class profile instead)")


class NetemSpec(Config, omit_defaults=True, frozen=True):
    """The ``network.netem`` mapping (docs/netem.md). Decoding it validates the whole configuration."""

    preset: Preset | None = None  # base profiles for every class
    seed: Seed | None = None  # per-link RNG seeds derive from it; None: the scenario's (or the node's current) seed
    exempt_commands: bool = True  # ground-station commands bypass the shim
    v2v: ProfilePatch | None | UnsetType = UNSET  # null: no impairment
    v2p: ProfilePatch | None | UnsetType = UNSET
    ground: ProfilePatch | None | UnsetType = UNSET
    links: tuple[LinkPatch, ...] = ()
    partitions: dict[Annotated[str, Meta(min_length=1)], tuple[UavId, ...]] = msgspec.field(default_factory=dict)

    def __post_init__(self) -> None:
        resolve(self)  # every profile it implies must be valid: errors name the field here, not at the UAV


# ---- resolved: per class and per link ----------------------------------------------------------------
@dataclass(frozen=True)
class LinkOverride:
    src: int | None  # None = any
    dst: int | None
    both_ways: bool
    patch: dict[str, Any]

    def matches(self, src: int | str, dst: int) -> bool:
        if self._one(src, dst):
            return True
        return self.both_ways and self._one(dst, src)

    def _one(self, src: int | str, dst: int | str) -> bool:
        return (self.src is None or self.src == src) and (self.dst is None or self.dst == dst)


@dataclass(frozen=True)
class NetemConfig:
    """A validated configuration, resolved per class. ``data`` is its normalised form (round-trips exactly)."""

    seed: int | str
    exempt_commands: bool
    preset: str | None
    classes: dict[str, dict[str, Any] | None]  # resolved raw profile per class (preset + patch)
    overrides: tuple[LinkOverride, ...]
    partitions: dict[int, str]
    data: dict[str, Any] = field(compare=False)
    _compiled: dict[str, LinkProfile | None] = field(default_factory=dict, compare=False, repr=False)

    def class_profile(self, cls: str) -> LinkProfile | None:
        if cls not in self._compiled:
            raw = self.classes.get(cls)
            self._compiled[cls] = None if raw is None else compile_profile(raw, cls)
        return self._compiled[cls]

    def profile_for(self, cls: str, src: int | str, dst: int) -> LinkProfile | None:
        """The profile of link ``src -> dst`` of class ``cls`` (None: not impaired at all)."""
        patches = [o.patch for o in self.overrides if o.matches(src, dst)]
        if not patches:
            return self.class_profile(cls)
        raw: dict[str, Any] = dict(self.classes.get(cls) or {})
        for p in patches:
            raw = merge_profile(raw, p)
        return compile_profile(raw, f"links[{src}->{dst}]")

    def describe(self) -> str:
        head = f"preset {self.preset}" if self.preset else "custom"
        per = "; ".join(f"{c}: {p.describe() if (p := self.class_profile(c)) else 'no impairment'}" for c in CLASSES)
        extra = f"; {len(self.overrides)} link override(s)" if self.overrides else ""
        extra += f"; partitions {sorted(set(self.partitions.values()))}" if self.partitions else ""
        return f"{head} ({per}{extra})"


def resolve(spec: NetemSpec, default_seed: int | str = 0) -> NetemConfig:
    """Merge the preset, the class patches and the link overrides; check every profile they give."""
    seed = spec.seed if spec.seed is not None else default_seed
    base = PRESETS[spec.preset] if spec.preset is not None else {}
    classes: dict[str, dict[str, Any] | None] = {}
    for cls in CLASSES:
        raw = copy.deepcopy(base.get(cls))
        patch = getattr(spec, cls)
        if patch is None:
            raw = None
        elif isinstance(patch, ProfilePatch):
            raw = merge_profile(raw or {}, patch.patch())
        classes[cls] = raw
        if raw is not None:
            compile_profile(raw, cls)  # validate now; compiled lazily again by NetemConfig
    overrides = []
    for i, lk in enumerate(spec.links):
        patch = lk.patch()
        for cls in CLASSES:  # the patch must give a valid profile on top of every class
            compile_profile(merge_profile(classes[cls] or {}, patch), f"links.{i}")
        overrides.append(LinkOverride(None if lk.src == "*" else lk.src, None if lk.dst == "*" else lk.dst, lk.both_ways,
                                      patch))
    partitions: dict[int, str] = {}
    for name, ids in spec.partitions.items():
        for j, uid in enumerate(ids):
            if uid in partitions and partitions[uid] != name:
                raise NetemConfigError(f"partitions.{name}.{j}", f"UAV {uid} is already in partition {partitions[uid]!r}")
            partitions[uid] = name
    data = to_builtins(spec)
    data["seed"] = seed
    return NetemConfig(seed=seed, exempt_commands=spec.exempt_commands, preset=spec.preset, classes=classes,
                       overrides=tuple(overrides), partitions=partitions, data=data)


def parse_netem(data: Any, default_seed: int | str = 0) -> NetemConfig:
    """Validate ``data`` (the ``network.netem`` mapping, or a :class:`NetemSpec`) and resolve it."""
    spec = data if isinstance(data, NetemSpec) else convert({} if data is None else data, NetemSpec)
    return resolve(spec, default_seed)
