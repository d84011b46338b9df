"""The netem configuration: schema, validation with errors that name the field, resolution.

The same plain-Python validator runs in the scenario loader (``mrswarm.scenario``), in the
CLI (``mrswarm netem set``) and in the UAV process when a runtime change arrives on
``mrs/<swarm>/netem/set``, so there is one definition of what is valid and the UAV process
needs no pydantic. Every error is a :class:`NetemConfigError` whose message starts with the
dotted path of the offending field, e.g. ``v2v.loss.p: must be in [0, 1], got 1.5``.

Schema (all times in ms or s as named, probabilities in [0, 1]; docs/netem.md explains each)::

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
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any

from swarmnet.netem.presets import PRESETS

CLASSES = ("v2v", "v2p", "ground")
DISTRIBUTIONS = ("uniform", "normal", "pareto", "paretonormal")
LOSS_MODELS = ("bernoulli", "gilbert_elliott", "four_state")
DISTANCE_MODELS = ("range", "log_distance")
OUTAGE_MODES = ("drop", "hold")
PROFILE_KEYS = ("delay", "loss", "duplicate", "reorder", "rate", "limit", "outage", "distance")
TOP_KEYS = ("preset", "seed", "exempt_commands", *CLASSES, "links", "partitions")
DEFAULT_LIMIT = 1000
MAX_DELAY_MS = 60_000.0
SPEED_OF_LIGHT = 299_792_458.0


class NetemConfigError(ValueError):
    """An invalid netem configuration; ``path`` is the dotted field, ``msg`` what is wrong."""

    def __init__(self, path: str, msg: str):
        super().__init__(f"{path}: {msg}" if path else msg)
        self.path = path
        self.msg = msg


# ---- compiled, validated specs ----------------------------------------------------------------
@dataclass(frozen=True)
class DelaySpec:
    ms: float
    jitter_ms: float = 0.0
    distribution: str = "normal"  # ignored when jitter_ms == 0
    correlation: float = 0.0  # AR(1) lag-1 correlation of successive delays
    fifo: bool = False  # never let jitter reorder (each message leaves after the previous one)


@dataclass(frozen=True)
class LossSpec:
    model: str  # bernoulli | gilbert_elliott | four_state
    p: float = 0.0  # bernoulli: loss probability; GE: P(good -> bad)
    r: float = 1.0  # GE: P(bad -> good)
    loss_bad: float = 1.0  # GE: 1-h, loss probability in the bad state
    loss_good: float = 0.0  # GE: 1-k, loss probability in the good state
    p13: float = 0.0
    p31: float = 1.0
    p32: float = 0.0
    p23: float = 1.0
    p14: float = 0.0

    @property
    def expected_rate(self) -> float:
        """Long-run loss rate (closed form; docs/netem.md)."""
        if self.model == "bernoulli":
            return self.p
        if self.model == "gilbert_elliott":
            pb = self.p / (self.p + self.r) if self.p + self.r > 0 else 0.0
            return pb * self.loss_bad + (1.0 - pb) * self.loss_good
        pi = four_state_stationary(self)
        return pi[2] + pi[3]


@dataclass(frozen=True)
class ReorderSpec:
    p: float
    gap: int = 1


@dataclass(frozen=True)
class RateSpec:
    kbit: float
    overhead_bytes: int = 0


@dataclass(frozen=True)
class OutageSpec:
    every_s: float
    duration_min_ms: float
    duration_max_ms: float
    mode: str = "drop"


@dataclass(frozen=True)
class DistanceSpec:
    model: str  # range | log_distance
    range_m: float = 0.0
    full_m: float = 0.0
    exponent: float = 2.0
    sigma_db: float = 0.0
    ref_loss_db: float = 40.05
    tx_dbm: float = 20.0
    gains_dbi: float = 0.0
    sensitivity_dbm: float = -91.0

    def p_deliver(self, d: float) -> float:
        """Probability that a message over ``d`` metres arrives (before any other impairment)."""
        if self.model == "range":
            if d <= self.full_m:
                return 1.0
            if d >= self.range_m:
                return 0.0
            return (self.range_m - d) / (self.range_m - self.full_m)
        # log-distance path loss with log-normal shadowing, reference distance 1 m
        pl = self.ref_loss_db + 10.0 * self.exponent * math.log10(max(d, 1.0))
        margin = self.tx_dbm + self.gains_dbi - pl - self.sensitivity_dbm  # mean received power over the threshold, dB
        if self.sigma_db <= 0.0:
            return 1.0 if margin >= 0.0 else 0.0
        return 0.5 * math.erfc(-margin / (self.sigma_db * math.sqrt(2.0)))

    def nominal_range_m(self) -> float:
        """Distance where the delivery probability is 0.5 (range: the mid-point of the fade)."""
        if self.model == "range":
            return 0.5 * (self.full_m + self.range_m)
        return 10.0 ** ((self.tx_dbm + self.gains_dbi - self.sensitivity_dbm - self.ref_loss_db) / (10.0 * self.exponent))


@dataclass(frozen=True)
class LinkProfile:
    """What one (sender -> receiver) link does to every message."""

    delay: DelaySpec | None = None
    loss: LossSpec | None = None
    duplicate: float = 0.0
    reorder: ReorderSpec | None = None
    rate: RateSpec | None = None
    limit: int = DEFAULT_LIMIT
    outage: OutageSpec | None = None
    distance: DistanceSpec | None = None

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
            l = self.loss
            parts.append(f"loss {l.model} {100 * l.expected_rate:.3g}%")
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
    """A validated configuration. ``data`` is its normalised JSON form (round-trips exactly)."""

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


# ---- validation helpers -------------------------------------------------------------------------
def _num(v: Any, path: str, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False) -> float:
    if type(v) not in (int, float) or not math.isfinite(v):
        raise NetemConfigError(path, f"must be a finite number, got {v!r}")
    if lo is not None and (v <= lo if lo_open else v < lo):
        raise NetemConfigError(path, f"must be {'>' if lo_open else '>='} {lo:g}, got {v!r}")
    if hi is not None and v > hi:
        raise NetemConfigError(path, f"must be <= {hi:g}, got {v!r}")
    return float(v)


def _prob(v: Any, path: str) -> float:
    if type(v) not in (int, float) or not (0.0 <= v <= 1.0):
        raise NetemConfigError(path, f"must be a probability in [0, 1], got {v!r}")
    return float(v)


def _int(v: Any, path: str, lo: int, hi: int) -> int:
    if type(v) is not int or not lo <= v <= hi:
        raise NetemConfigError(path, f"must be an integer in {lo}..{hi}, got {v!r}")
    return v


def _bool(v: Any, path: str) -> bool:
    if type(v) is not bool:
        raise NetemConfigError(path, f"must be true or false, got {v!r}")
    return v


def _mapping(v: Any, path: str, allowed: tuple[str, ...]) -> dict[str, Any]:
    if not isinstance(v, dict):
        raise NetemConfigError(path, f"must be a mapping, got {type(v).__name__}")
    for k in v:
        if k not in allowed:
            raise NetemConfigError(f"{path}.{k}" if path else str(k), f"unknown field (expected one of: {', '.join(allowed)})")
    return v


def _choice(v: Any, path: str, choices: tuple[str, ...]) -> str:
    if v not in choices:
        raise NetemConfigError(path, f"must be one of {', '.join(choices)}, got {v!r}")
    return v


def _uav(v: Any, path: str, wildcard: bool = False) -> int | None:
    if wildcard and v == "*":
        return None
    if type(v) is not int or not 1 <= v <= 65535:
        wild = ' or "*"' if wildcard else ""
        raise NetemConfigError(path, f"must be a UAV id 1..65535{wild}, got {v!r}")
    return v


# ---- components ---------------------------------------------------------------------------------
def _delay(v: Any, path: str) -> DelaySpec:
    m = _mapping(v, path, ("ms", "jitter_ms", "distribution", "correlation", "fifo"))
    if "ms" not in m:
        raise NetemConfigError(f"{path}.ms", "required (mean one-way delay in ms)")
    ms = _num(m["ms"], f"{path}.ms", 0.0, MAX_DELAY_MS)
    jitter = _num(m.get("jitter_ms", 0.0), f"{path}.jitter_ms", 0.0, MAX_DELAY_MS)
    dist = m.get("distribution")
    if jitter > 0.0 and dist is None:
        raise NetemConfigError(f"{path}.distribution", "required with jitter_ms > 0 (uniform, normal, pareto or paretonormal)")
    dist = _choice(dist, f"{path}.distribution", DISTRIBUTIONS) if dist is not None else "normal"
    corr = m.get("correlation", 0.0)
    if type(corr) not in (int, float) or not 0.0 <= corr < 1.0:
        raise NetemConfigError(f"{path}.correlation", f"must be in [0, 1) (AR(1) lag-1 correlation), got {corr!r}")
    return DelaySpec(ms, jitter, dist, float(corr), _bool(m.get("fifo", False), f"{path}.fifo"))


def _loss(v: Any, path: str) -> LossSpec:
    if isinstance(v, dict) and "correlation" in v:
        raise NetemConfigError(f"{path}.correlation", "netem's loss correlation is not supported (it does not keep the loss "
                               "rate: 1% with 25% correlation loses ~0.0003%); use model: gilbert_elliott for bursty loss")
    if not isinstance(v, dict) or "model" not in v:
        raise NetemConfigError(f"{path}.model", f"required: one of {', '.join(LOSS_MODELS)}")
    model = _choice(v["model"], f"{path}.model", LOSS_MODELS)
    if model == "bernoulli":
        m = _mapping(v, path, ("model", "p"))
        if "p" not in m:
            raise NetemConfigError(f"{path}.p", "required (loss probability)")
        return LossSpec("bernoulli", p=_prob(m["p"], f"{path}.p"))
    if model == "gilbert_elliott":
        m = _mapping(v, path, ("model", "p", "r", "loss_bad", "loss_good", "rate", "burst"))
        if "rate" in m or "burst" in m:
            for k in ("p", "r", "loss_bad", "loss_good"):
                if k in m:
                    raise NetemConfigError(f"{path}.{k}", "give either rate + burst or p + r (+ loss_bad, loss_good), not both")
            if "rate" not in m or "burst" not in m:
                raise NetemConfigError(f"{path}.{'burst' if 'rate' in m else 'rate'}", "rate and burst go together")
            rate = _num(m["rate"], f"{path}.rate", 0.0, 0.99)
            burst = _num(m["burst"], f"{path}.burst", 1.0, 1e6)
            r = 1.0 / burst
            return LossSpec("gilbert_elliott", p=rate * r / (1.0 - rate), r=r)
        for k in ("p", "r"):
            if k not in m:
                raise NetemConfigError(f"{path}.{k}", "required (or give rate + burst)")
        p, r = _prob(m["p"], f"{path}.p"), _prob(m["r"], f"{path}.r")
        if p + r == 0.0:
            raise NetemConfigError(f"{path}.r", "p and r cannot both be 0")
        return LossSpec("gilbert_elliott", p=p, r=r, loss_bad=_prob(m.get("loss_bad", 1.0), f"{path}.loss_bad"),
                        loss_good=_prob(m.get("loss_good", 0.0), f"{path}.loss_good"))
    m = _mapping(v, path, ("model", "p13", "p31", "p32", "p23", "p14"))
    if "p13" not in m:
        raise NetemConfigError(f"{path}.p13", "required (P(gap -> burst))")
    p13 = _prob(m["p13"], f"{path}.p13")
    s = LossSpec("four_state", p13=p13, p31=_prob(m.get("p31", 1.0 - p13), f"{path}.p31"),
                 p32=_prob(m.get("p32", 0.0), f"{path}.p32"), p23=_prob(m.get("p23", 1.0), f"{path}.p23"),
                 p14=_prob(m.get("p14", 0.0), f"{path}.p14"))
    if s.p13 + s.p14 > 1.0:
        raise NetemConfigError(f"{path}.p14", "p13 + p14 must be <= 1")
    if s.p31 + s.p32 > 1.0:
        raise NetemConfigError(f"{path}.p32", "p31 + p32 must be <= 1")
    return s


def four_state_stationary(s: LossSpec) -> tuple[float, float, float, float]:
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


def _reorder(v: Any, path: str) -> ReorderSpec:
    m = _mapping(v, path, ("p", "gap"))
    if "p" not in m:
        raise NetemConfigError(f"{path}.p", "required (probability of sending a message immediately)")
    return ReorderSpec(_prob(m["p"], f"{path}.p"), _int(m.get("gap", 1), f"{path}.gap", 1, 1_000_000))


def _rate(v: Any, path: str) -> RateSpec:
    m = _mapping(v, path, ("kbit", "overhead_bytes"))
    if "kbit" not in m:
        raise NetemConfigError(f"{path}.kbit", "required (link rate in kbit/s)")
    return RateSpec(_num(m["kbit"], f"{path}.kbit", 0.0, 1e9, lo_open=True),
                    _int(m.get("overhead_bytes", 0), f"{path}.overhead_bytes", 0, 65535))


def _outage(v: Any, path: str) -> OutageSpec:
    m = _mapping(v, path, ("every_s", "duration_ms", "mode"))
    for k in ("every_s", "duration_ms"):
        if k not in m:
            raise NetemConfigError(f"{path}.{k}", "required")
    every = _num(m["every_s"], f"{path}.every_s", 0.0, 1e7, lo_open=True)
    d = m["duration_ms"]
    if isinstance(d, (list, tuple)):
        if len(d) != 2:
            raise NetemConfigError(f"{path}.duration_ms", "must be a number or [min, max]")
        lo = _num(d[0], f"{path}.duration_ms.0", 0.0, 3.6e6)
        hi = _num(d[1], f"{path}.duration_ms.1", 0.0, 3.6e6)
        if hi < lo:
            raise NetemConfigError(f"{path}.duration_ms", "need min <= max")
    else:
        lo = hi = _num(d, f"{path}.duration_ms", 0.0, 3.6e6)
    if hi / 1000.0 >= every:
        raise NetemConfigError(f"{path}.duration_ms", f"outages of up to {hi:g} ms every {every:g} s would never end")
    return OutageSpec(every, lo, hi, _choice(m.get("mode", "drop"), f"{path}.mode", OUTAGE_MODES))


def friis_ref_loss_db(freq_ghz: float, d0: float = 1.0) -> float:
    lam = SPEED_OF_LIGHT / (freq_ghz * 1e9)
    return 20.0 * math.log10(4.0 * math.pi * d0 / lam)


def _distance(v: Any, path: str) -> DistanceSpec:
    if not isinstance(v, dict) or "model" not in v:
        raise NetemConfigError(f"{path}.model", f"required: one of {', '.join(DISTANCE_MODELS)}")
    model = _choice(v["model"], f"{path}.model", DISTANCE_MODELS)
    if model == "range":
        m = _mapping(v, path, ("model", "range_m", "full_m"))
        if "range_m" not in m:
            raise NetemConfigError(f"{path}.range_m", "required (no delivery beyond this distance)")
        rng = _num(m["range_m"], f"{path}.range_m", 0.0, 1e7, lo_open=True)
        full = _num(m.get("full_m", rng), f"{path}.full_m", 0.0, rng)
        return DistanceSpec("range", range_m=rng, full_m=full)
    m = _mapping(v, path, ("model", "exponent", "sigma_db", "freq_ghz", "ref_loss_db", "tx_dbm", "gains_dbi", "sensitivity_dbm"))
    if "exponent" not in m:
        raise NetemConfigError(f"{path}.exponent", "required (path-loss exponent, 2 = free space)")
    freq = _num(m.get("freq_ghz", 2.4), f"{path}.freq_ghz", 0.0, 300.0, lo_open=True)
    ref = m.get("ref_loss_db")
    ref_db = friis_ref_loss_db(freq) if ref is None else _num(ref, f"{path}.ref_loss_db", 0.0, 200.0)
    return DistanceSpec(
        "log_distance",
        exponent=_num(m["exponent"], f"{path}.exponent", 1.0, 8.0),
        sigma_db=_num(m.get("sigma_db", 0.0), f"{path}.sigma_db", 0.0, 30.0),
        ref_loss_db=ref_db,
        tx_dbm=_num(m.get("tx_dbm", 20.0), f"{path}.tx_dbm", -50.0, 60.0),
        gains_dbi=_num(m.get("gains_dbi", 0.0), f"{path}.gains_dbi", -30.0, 60.0),
        sensitivity_dbm=_num(m.get("sensitivity_dbm", -91.0), f"{path}.sensitivity_dbm", -200.0, 0.0),
    )


def compile_profile(raw: dict[str, Any], path: str) -> LinkProfile:
    m = _mapping(raw, path, PROFILE_KEYS)
    p = lambda k: f"{path}.{k}" if path else k  # noqa: E731
    delay = _delay(m["delay"], p("delay")) if m.get("delay") is not None else None
    reorder = _reorder(m["reorder"], p("reorder")) if m.get("reorder") is not None else None
    if reorder is not None and (delay is None or delay.ms == 0.0):
        raise NetemConfigError(p("reorder"), "reordering needs a delay (delay.ms > 0) to overtake, as in netem")
    dup = m.get("duplicate")
    return LinkProfile(
        delay=delay,
        loss=_loss(m["loss"], p("loss")) if m.get("loss") is not None else None,
        duplicate=_prob(dup, p("duplicate")) if dup is not None else 0.0,
        reorder=reorder,
        rate=_rate(m["rate"], p("rate")) if m.get("rate") is not None else None,
        limit=_int(m.get("limit") if m.get("limit") is not None else DEFAULT_LIMIT, p("limit"), 1, 1_000_000),
        outage=_outage(m["outage"], p("outage")) if m.get("outage") is not None else None,
        distance=_distance(m["distance"], p("distance")) if m.get("distance") is not None else None,
    )


def merge_profile(base: dict[str, Any], patch: dict[str, Any]) -> dict[str, Any]:
    """Merge a profile patch onto a profile (both raw dicts).

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


# ---- top level ----------------------------------------------------------------------------------
def parse_netem(data: Any, default_seed: int | str = 0) -> NetemConfig:
    """Validate ``data`` (the ``network.netem`` mapping) and resolve presets and overrides."""
    if data is None:
        data = {}
    m = _mapping(data, "", TOP_KEYS)
    preset = m.get("preset")
    if preset is not None and (type(preset) is not str or preset not in PRESETS):
        raise NetemConfigError("preset", f"unknown preset {preset!r} (one of: {', '.join(PRESETS)})")
    seed = m.get("seed", default_seed)
    if not ((type(seed) is int and 0 <= seed < 2**63) or (type(seed) is str and 0 < len(seed) <= 64)):
        raise NetemConfigError("seed", f"must be a non-negative integer or a short string, got {seed!r}")
    exempt = _bool(m.get("exempt_commands", True), "exempt_commands")
    base = PRESETS[preset] if preset is not None else {}
    classes: dict[str, dict[str, Any] | None] = {}
    for cls in CLASSES:
        raw = copy.deepcopy(base.get(cls))
        if cls in m:
            patch = m[cls]
            if patch is None:
                raw = None
            else:
                _mapping(patch, cls, PROFILE_KEYS)
                raw = merge_profile(raw or {}, patch)
        classes[cls] = raw
        if raw is not None:
            compile_profile(raw, cls)  # validate now; compiled lazily again by NetemConfig
    overrides = []
    links = m.get("links") or []
    if not isinstance(links, list):
        raise NetemConfigError("links", "must be a list of {src, dst, <profile fields>}")
    for i, lk in enumerate(links):
        path = f"links.{i}"
        lm = _mapping(lk, path, ("src", "dst", "both_ways", *PROFILE_KEYS))
        for k in ("src", "dst"):
            if k not in lm:
                raise NetemConfigError(f"{path}.{k}", "required (a UAV id or \"*\")")
        src, dst = _uav(lm["src"], f"{path}.src", True), _uav(lm["dst"], f"{path}.dst", True)
        if src is None and dst is None:
            raise NetemConfigError(path, "src and dst cannot both be \"*\" (change the class profile instead)")
        patch = {k: v for k, v in lm.items() if k in PROFILE_KEYS}
        for cls in CLASSES:  # the patch must give a valid profile on top of every class
            compile_profile(merge_profile(classes[cls] or {}, patch), path)
        overrides.append(LinkOverride(src, dst, _bool(lm.get("both_ways", False), f"{path}.both_ways"), patch))
    partitions: dict[int, str] = {}
    parts = m.get("partitions") or {}
    if not isinstance(parts, dict):
        raise NetemConfigError("partitions", "must be a mapping of name -> list of UAV ids")
    for name, ids in parts.items():
        path = f"partitions.{name}"
        if type(name) is not str or not name:
            raise NetemConfigError(path, "partition names must be non-empty strings")
        if not isinstance(ids, list):
            raise NetemConfigError(path, "must be a list of UAV ids")
        for j, u in enumerate(ids):
            uid = _uav(u, f"{path}.{j}")
            assert uid is not None
            if uid in partitions and partitions[uid] != name:
                raise NetemConfigError(f"{path}.{j}", f"UAV {uid} is already in partition {partitions[uid]!r}")
            partitions[uid] = name
    norm = copy.deepcopy(dict(m))
    norm["seed"] = seed
    return NetemConfig(seed=seed, exempt_commands=exempt, preset=preset, classes=classes, overrides=tuple(overrides),
                       partitions=partitions, data=norm)
