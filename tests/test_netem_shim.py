"""Statistical tests of the netem shim: each impairment does what its configuration says.

Deterministic and fast: a fake clock drives one shim (no network), releases happen exactly at
each message's time to send, and every random draw comes from the seeded per-link RNGs, so a
test either always passes or always fails. Tolerances are set from the sampling error of the
sizes used (several standard errors), not tuned to the seed.
"""

from __future__ import annotations

import bisect
import math
import random
from typing import Any

import msgspec
import numpy as np
import pytest
from scipy import integrate, stats

from swarmnet.messages import Realm
from swarmnet.netem import NetemConfigError, NetemShim, parse_netem
from swarmnet.netem.config import FourStateLoss, LossSpec, four_state_stationary
from swarmnet.netem.models import PARETONORMAL_SD, OutageSchedule
from swarmnet.netem.shim import Link


def shim_for(profile: dict[str, Any] | None, seed: int | str = 1, me: int = 2, **top: Any) -> NetemShim:
    """A shim at UAV ``me`` with ``profile`` for virtual <-> virtual links (None: the preset's)."""
    cfg = dict(top) if profile is None else {"v2v": profile, **top}
    return NetemShim(parse_netem(cfg, default_seed=seed), me)


def drive(shim: NetemShim, link: Link, n: int, interval: float = 0.01, size: int = 48,
          t0: float = 1000.0) -> list[tuple[int, float, float]]:
    """Offer n messages every ``interval``; release each exactly at its time to send.

    Returns (index, offered at, delivered at) in delivery order.
    """
    out: list[tuple[int, float, float]] = []
    i = 0
    t_next = t0
    while i < n or shim.pending:
        due = shim.next_due()
        if i < n and (due is None or t_next < due):
            if shim.offer(link, t_next, 0, (i, t_next), "", size):
                out.append((i, t_next, t_next))
            i += 1
            t_next = t0 + i * interval
        else:
            assert due is not None
            for _, (j, t_off), _, _ in shim.release(due):
                out.append((j, t_off, due))
    return out


def delays_ms(out: list[tuple[int, float, float]]) -> np.ndarray:
    return np.array([1000.0 * (b - a) for _, a, b in out])


def one_link(profile: dict[str, Any] | None, seed: int | str = 1, **top: Any) -> tuple[NetemShim, Link]:
    shim = shim_for(profile, seed, **top)
    return shim, shim.link(1, Realm.VIRTUAL)


# ---- delay ---------------------------------------------------------------------------------------
def test_normal_delay_has_the_configured_mean_sd_and_shape() -> None:
    shim, link = one_link({"delay": {"ms": 50, "jitter_ms": 10, "distribution": "normal"}})
    d = delays_ms(drive(shim, link, 20_000))
    assert len(d) == 20_000
    assert d.mean() == pytest.approx(50.0, rel=0.05)
    assert d.std(ddof=1) == pytest.approx(10.0, rel=0.05)
    assert stats.kstest(d, "norm", args=(50.0, 10.0)).pvalue > 0.01


def test_uniform_jitter_is_netems_half_width() -> None:
    shim, link = one_link({"delay": {"ms": 50, "jitter_ms": 10, "distribution": "uniform"}})
    d = delays_ms(drive(shim, link, 20_000))
    assert d.min() >= 40.0 and d.max() < 60.0
    assert stats.kstest(d, "uniform", args=(40.0, 20.0)).pvalue > 0.01
    assert d.std() == pytest.approx(10.0 / math.sqrt(3.0), rel=0.05)


def test_pareto_delay_is_netems_shape_scaled_to_the_jitter() -> None:
    shim, link = one_link({"delay": {"ms": 50, "jitter_ms": 10, "distribution": "pareto"}})
    d = delays_ms(drive(shim, link, 40_000))
    # delay = mu + sigma * (X - 1.5) / sqrt(0.75), X ~ Pareto(shape 3, scale 1): netem's table shape
    x = (d - 50.0) / 10.0 * math.sqrt(0.75) + 1.5
    assert stats.kstest(x, "pareto", args=(3.0,)).pvalue > 0.01
    assert d.mean() == pytest.approx(50.0, rel=0.05)
    assert d.std() == pytest.approx(10.0, rel=0.10)  # heavy tail: the sample sd converges slowly
    assert d.min() >= 50.0 - 10.0 * 0.5 / math.sqrt(0.75) - 1e-9  # the long tail is on the right only


def paretonormal_quantile(q: np.ndarray) -> np.ndarray:
    return (0.25 * stats.norm.ppf(q) + (1.0 - q) ** (-1.0 / 3.0) - 1.5) / PARETONORMAL_SD


def test_paretonormal_delay_is_netems_quantile_mix() -> None:
    # the constant that scales the mix to sd 1, recomputed by integration
    cov, _ = integrate.quad(lambda q: stats.norm.ppf(q) * (1 - q) ** (-1 / 3), 0, 1, limit=500)
    assert math.sqrt(0.25**2 + 0.75 + 2 * 0.25 * cov) == pytest.approx(PARETONORMAL_SD, rel=1e-6)
    shim, link = one_link({"delay": {"ms": 50, "jitter_ms": 10, "distribution": "paretonormal"}})
    d = delays_ms(drive(shim, link, 40_000))
    grid = np.linspace(1e-7, 1 - 1e-7, 400_001)
    qs = paretonormal_quantile(grid)

    def cdf(x: np.ndarray) -> np.ndarray:
        return np.interp((np.asarray(x) - 50.0) / 10.0, qs, grid)

    assert stats.kstest(d, cdf).pvalue > 0.01
    assert d.mean() == pytest.approx(50.0, rel=0.05)
    assert d.std() == pytest.approx(10.0, rel=0.10)


def test_correlated_delay_keeps_mean_and_sd_with_lag1_autocorrelation() -> None:
    shim, link = one_link({"delay": {"ms": 100, "jitter_ms": 20, "distribution": "normal", "correlation": 0.6}})
    out = drive(shim, link, 20_000, interval=0.5)  # far apart: no reordering, so index order = draw order
    d = delays_ms(sorted(out))
    assert d.mean() == pytest.approx(100.0, rel=0.05)
    assert d.std() == pytest.approx(20.0, rel=0.05)
    assert np.corrcoef(d[:-1], d[1:])[0, 1] == pytest.approx(0.6, abs=0.03)
    assert stats.kstest(d, "norm", args=(100.0, 20.0)).pvalue > 1e-3  # AR(1) keeps the normal marginal (samples correlated)


def test_delay_is_clipped_at_zero() -> None:
    shim, link = one_link({"delay": {"ms": 5, "jitter_ms": 10, "distribution": "normal"}})
    d = delays_ms(drive(shim, link, 5000))
    assert d.min() == 0.0
    assert np.mean(d == 0.0) == pytest.approx(stats.norm.cdf(-0.5), abs=0.03)


# ---- loss ---------------------------------------------------------------------------------------
def lost_pattern(profile: dict[str, Any], n: int, seed: int = 1) -> np.ndarray:
    shim, link = one_link(profile, seed)
    got = {i for i, _, _ in drive(shim, link, n)}
    return np.array([i not in got for i in range(n)])


def bursts(lost: np.ndarray) -> np.ndarray:
    """Lengths of runs of consecutive losses."""
    x = np.concatenate([[0], lost.astype(int), [0]])
    d = np.diff(x)
    return np.nonzero(d == -1)[0] - np.nonzero(d == 1)[0]


def test_bernoulli_loss_rate() -> None:
    lost = lost_pattern({"loss": {"model": "bernoulli", "p": 0.1}}, 50_000)
    assert lost.mean() == pytest.approx(0.1, abs=4 * math.sqrt(0.1 * 0.9 / 50_000))
    assert bursts(lost).mean() == pytest.approx(1 / 0.9, rel=0.05)  # independent losses: geometric runs


# Bursty loss converges slowly: over 40 seeds, 200k messages of GE(p=0.02, r=0.25) gave a loss
# rate with a relative sd of 2.6 %; at 500k it is ~1.6 %, so +-8 % is about five standard errors.
GE_N = 500_000


def test_gilbert_elliott_long_run_loss_rate_and_mean_burst_length() -> None:
    p, r = 0.02, 0.25
    lost = lost_pattern({"loss": {"model": "gilbert_elliott", "p": p, "r": r}}, GE_N)
    assert lost.mean() == pytest.approx(p / (p + r), rel=0.08)
    assert bursts(lost).mean() == pytest.approx(1 / r, rel=0.05)


def test_gilbert_elliott_calibrated_from_rate_and_burst() -> None:
    """The `degraded` preset's form: 10 % loss in bursts of 3 on average."""
    lost = lost_pattern({"loss": {"model": "gilbert_elliott", "rate": 0.10, "burst": 3}}, GE_N)
    assert lost.mean() == pytest.approx(0.10, rel=0.08)
    assert bursts(lost).mean() == pytest.approx(3.0, rel=0.05)


def test_gilbert_elliott_with_partial_loss_in_each_state() -> None:
    spec = dict(model="gilbert_elliott", p=0.05, r=0.2, loss_bad=0.7, loss_good=0.02)
    lost = lost_pattern({"loss": spec}, GE_N)
    pb = 0.05 / 0.25
    expect = pb * 0.7 + (1 - pb) * 0.02
    assert msgspec.convert(spec, LossSpec).expected_rate == pytest.approx(expect)
    assert lost.mean() == pytest.approx(expect, rel=0.08)


def four_state_matrix(s: FourStateLoss) -> np.ndarray:
    return np.array([
        [1 - s.p13 - s.p14, 0.0, s.p13, s.p14],
        [0.0, 1 - s.p23, s.p23, 0.0],
        [s.p31, s.p32, 1 - s.p31 - s.p32, 0.0],
        [1.0, 0.0, 0.0, 0.0],
    ])


def test_four_state_model_loss_rate_matches_the_markov_chain() -> None:
    spec = {"model": "four_state", "p13": 0.02, "p31": 0.3, "p32": 0.2, "p23": 0.15, "p14": 0.01}
    s = msgspec.convert(spec, FourStateLoss)
    # stationary distribution independently: left eigenvector of the transition matrix
    w, v = np.linalg.eig(four_state_matrix(s).T)
    pi = np.real(v[:, np.argmin(np.abs(w - 1))])
    pi /= pi.sum()
    assert four_state_stationary(s) == pytest.approx(tuple(pi), abs=1e-12)
    lost = lost_pattern({"loss": spec}, GE_N)
    assert lost.mean() == pytest.approx(pi[2] + pi[3], rel=0.08)


def test_four_state_with_only_p13_is_bernoulli() -> None:
    lost = lost_pattern({"loss": {"model": "four_state", "p13": 0.05}}, 100_000)
    assert lost.mean() == pytest.approx(0.05, rel=0.08)
    assert bursts(lost).mean() == pytest.approx(1 / 0.95, rel=0.05)


def test_netem_loss_correlation_is_refused_with_a_pointer_to_gilbert_elliott() -> None:
    with pytest.raises(NetemConfigError, match=r"v2v\.loss\.correlation: .*gilbert_elliott"):
        parse_netem({"v2v": {"loss": {"model": "bernoulli", "p": 0.01, "correlation": 0.25}}})


# ---- duplication, reordering ---------------------------------------------------------------------
def test_duplicate_rate() -> None:
    shim, link = one_link({"delay": {"ms": 10}, "duplicate": 0.05})
    out = drive(shim, link, 50_000)
    assert link.duplicated / link.sent == pytest.approx(0.05, abs=4 * math.sqrt(0.05 * 0.95 / 50_000))
    assert len(out) == link.sent + link.duplicated
    counts = np.bincount([i for i, _, _ in out])
    assert set(counts) == {1, 2} and (counts == 2).sum() == link.duplicated


def test_duplicate_and_loss_follow_netems_count_rule() -> None:
    d, p = 0.5, 0.2
    shim, link = one_link({"delay": {"ms": 10}, "duplicate": d, "loss": {"model": "bernoulli", "p": p}})
    n = 100_000
    out = drive(shim, link, n)
    # count = 1 + dup - lost; the clone draws its own loss
    expect = (1 - d) * (1 - p) + d * p + d * (1 - p) * (2 - p)
    assert len(out) / n == pytest.approx(expect, rel=0.01)
    assert link.sent + link.duplicated == link.delivered + sum(link.dropped.values())


def rfc4737_reordered(order: list[int]) -> int:
    """Messages that arrive after one with a higher index (independent count from the delivery order)."""
    seen = -1
    n = 0
    for i in order:
        if i < seen:
            n += 1
        else:
            seen = i
    return n


@pytest.mark.parametrize("p, gap", [(0.25, 1), (0.25, 5), (0.5, 3)])
def test_reorder_gap_rate(p: float, gap: int) -> None:
    shim, link = one_link({"delay": {"ms": 100}, "reorder": {"p": p, "gap": gap}})
    n = 40_000
    out = drive(shim, link, n)
    immediate = [i for i, a, b in out if b == a]
    # after each immediate send the next gap-1 messages are delayed; then each goes out at once w.p. p
    expect = 1.0 / ((gap - 1) + 1.0 / p)
    assert len(immediate) / n == pytest.approx(expect, rel=0.05)
    assert link.jumps == len(immediate)
    assert link.reordered == rfc4737_reordered([i for i, _, _ in out]) > 0


def test_jitter_reorders_unless_fifo() -> None:
    prof = {"delay": {"ms": 100, "jitter_ms": 50, "distribution": "uniform"}}
    shim, link = one_link(prof)
    out = drive(shim, link, 5000)
    assert link.reordered == rfc4737_reordered([i for i, _, _ in out]) > 500
    shim, link = one_link({"delay": dict(prof["delay"], fifo=True)})
    out = drive(shim, link, 5000)
    assert link.reordered == 0 and [i for i, _, _ in out] == list(range(5000))
    assert delays_ms(out).min() >= 50.0


def test_reorder_without_delay_is_refused() -> None:
    with pytest.raises(NetemConfigError, match=r"v2v\.reorder: reordering needs a delay"):
        parse_netem({"v2v": {"reorder": {"p": 0.1}}})


# ---- rate and queue -------------------------------------------------------------------------------
def test_rate_limit_caps_throughput_with_queueing_and_tail_drop() -> None:
    shim, link = one_link({"rate": {"kbit": 256}, "limit": 200})
    out = drive(shim, link, 20_000, interval=0.001, size=100)  # offered 800 kbit/s
    t = np.array([b for _, _, b in out])
    kbit = len(out) * 100 * 8 / (t[-1] - t[0]) / 1000.0
    assert kbit == pytest.approx(256.0, rel=0.01)
    assert link.dropped["queue"] > 0 and link.delivered + link.dropped["queue"] == 20_000
    d = delays_ms(out)
    assert d.max() == pytest.approx(200 * 100 * 8 / 256.0, rel=0.02)  # a full queue of 200 x 3.125 ms


def test_rate_below_capacity_adds_the_serialisation_time_only() -> None:
    shim, link = one_link({"delay": {"ms": 20}, "rate": {"kbit": 256, "overhead_bytes": 28}})
    d = delays_ms(drive(shim, link, 1000, interval=0.01, size=100))
    assert d == pytest.approx(np.full(1000, 20.0 + 128 * 8 / 256.0))


def test_queue_limit_counts_the_messages_waiting() -> None:
    shim, link = one_link({"delay": {"ms": 1000}, "limit": 100})
    out = drive(shim, link, 2000, interval=0.001)
    assert link.dropped["queue"] == 2000 - len(out)
    assert len(out) == pytest.approx(2000 * 100 / 1000, rel=0.02)  # 100 in flight per second of delay


# ---- distance, partitions, outages ------------------------------------------------------------------
def delivered_fraction_at(shim: NetemShim, link: Link, d: float, n: int) -> float:
    link.pos = (d, 0.0, 20.0)
    shim.own_pos = (0.0, 0.0, 20.0)
    before = link.delivered
    drive(shim, link, n, t0=link.sent * 0.01 + 1000.0)
    return (link.delivered - before) / n


def test_hard_and_soft_range() -> None:
    shim, link = one_link({"distance": {"model": "range", "range_m": 100}})
    assert delivered_fraction_at(shim, link, 99.0, 500) == 1.0
    assert delivered_fraction_at(shim, link, 101.0, 500) == 0.0
    shim, link = one_link({"distance": {"model": "range", "full_m": 50, "range_m": 150}})
    assert delivered_fraction_at(shim, link, 40.0, 500) == 1.0
    assert delivered_fraction_at(shim, link, 100.0, 20_000) == pytest.approx(0.5, abs=0.015)
    assert delivered_fraction_at(shim, link, 125.0, 20_000) == pytest.approx(0.25, abs=0.015)
    assert delivered_fraction_at(shim, link, 151.0, 500) == 0.0


def test_log_distance_delivery_probability_against_distance() -> None:
    model = {"model": "log_distance", "exponent": 2.5, "sigma_db": 6.0, "freq_ghz": 2.4, "tx_dbm": 20, "sensitivity_dbm": -91}
    shim, link = one_link({"distance": model})
    spec = link.distance
    assert spec is not None
    assert spec.ref_loss_db == pytest.approx(40.05, abs=0.01)  # Friis at 1 m, 2.4 GHz
    assert spec.nominal_range_m() == pytest.approx(689, rel=0.01)  # 10^((20 + 91 - 40.05) / 25) m
    n = 20_000
    for d, expect in ((300.0, 0.93), (500.0, 0.72), (700.0, 0.49), (900.0, 0.31)):  # worked example, sigma 6 dB
        mean_rx = 20 - (40.05 + 25 * math.log10(d))
        p = stats.norm.sf((-91 - mean_rx) / 6.0)
        assert spec.p_deliver(d) == pytest.approx(p, rel=1e-3)
        assert p == pytest.approx(expect, abs=0.01)
        assert delivered_fraction_at(shim, link, d, n) == pytest.approx(p, abs=4 * math.sqrt(p * (1 - p) / n))


def test_unknown_positions_are_delivered_and_counted() -> None:
    shim, link = one_link({"distance": {"model": "range", "range_m": 10}})
    assert len(drive(shim, link, 100)) == 100 and link.no_position == 100


def test_partitions_cut_links_between_groups_only() -> None:
    cfg = parse_netem({"preset": "lan", "partitions": {"north": [1, 2], "south": [3, 4]}})
    shim = NetemShim(cfg, 2)
    same, other, free = shim.link(1, Realm.VIRTUAL), shim.link(3, Realm.VIRTUAL), shim.link(9, Realm.VIRTUAL)
    assert len(drive(shim, same, 100)) == 100
    assert len(drive(shim, other, 100)) == 0 and other.dropped["partition"] == 100
    assert len(drive(shim, free, 100)) == 100  # a UAV in no partition hears everyone


def test_outages_drop_exactly_while_a_radio_is_down_at_the_configured_rate() -> None:
    prof = {"outage": {"every_s": 20, "duration_ms": [500, 1500], "mode": "drop"}}
    shim, link = one_link(prof, seed=3)
    t0, n, dt = 10_000.0, 400_000, 0.01  # 4000 s
    out = drive(shim, link, n, interval=dt, t0=t0)
    got = {i for i, _, _ in out}
    radios = link.radios
    assert len(radios) == 2  # v2v: the sender's and the receiver's radio
    down = [any(r.down_until(t0 + i * dt) for r in radios) for i in range(n)]
    assert [i not in got for i in range(n)] == down
    # each radio: Poisson outages every 20 s on average, 1 s long on average
    for r in radios:
        iv = r.intervals(t0, t0 + n * dt)
        assert len(iv) == pytest.approx(4000 / 20, rel=0.2)
        assert np.mean([b - a for a, b in iv]) == pytest.approx(1.0, rel=0.1)
    assert np.mean(down) == pytest.approx(1 - (1 - 1 / 21) ** 2, rel=0.25)


def test_outage_hold_delivers_at_the_end_of_the_outage() -> None:
    shim, link = one_link({"delay": {"ms": 10}, "outage": {"every_s": 5, "duration_ms": 800, "mode": "hold"}})
    out = drive(shim, link, 20_000, interval=0.01)
    assert len(out) == 20_000
    held = 0
    for _, a, b in out:
        end = max(r.down_until(a) for r in link.radios)
        if end:
            held += 1
            assert b == pytest.approx(max(end, a + 0.010))
        else:
            assert b == pytest.approx(a + 0.010)
    assert held > 1000


@pytest.mark.parametrize("every_s, lo_ms, hi_ms", [(60.0, 50.0, 150.0), (5.0, 3000.0, 4900.0), (20.0, 500.0, 19_000.0)])
def test_outage_lookup_is_exact_in_any_query_order(every_s: float, lo_ms: float, hi_ms: float) -> None:
    """The cached O(1) lookup against a brute-force union of every generated outage."""
    from swarmnet.netem.config import OutageSpec

    spec = OutageSpec(every_s=every_s, duration_ms=(lo_ms, hi_ms), mode="drop")
    ref = OutageSchedule(3, 1, spec)
    raw = sorted(iv for w in range(-1, 7) for iv in zip(*ref._window(w), strict=True))
    union: list[list[float]] = []
    for a, b in raw:
        if union and a <= union[-1][1]:
            union[-1][1] = max(union[-1][1], b)
        else:
            union.append([a, b])
    sched = OutageSchedule(3, 1, spec)
    rng = random.Random(0)
    starts = [a for a, _ in union]
    ts = sorted(rng.uniform(0, 20_000) for _ in range(20_000)) + [rng.uniform(0, 20_000) for _ in range(20_000)]
    ts += [x for a, b in union for x in (a, b, math.nextafter(b, -math.inf))]  # the edges
    for t in ts:
        i = bisect.bisect_right(starts, t) - 1
        assert sched.down_until(t) == (union[i][1] if i >= 0 and union[i][1] > t else 0.0)
    assert OutageSchedule(3, 1, spec).intervals(100, 19_000) == [(a, b) for a, b in union if b > 100 and a < 19_000]


def test_every_receiver_computes_the_same_outages_for_a_sender() -> None:
    spec = parse_netem({"v2v": {"outage": {"every_s": 30, "duration_ms": [50, 150]}}}, 9).class_profile("v2v")
    assert spec is not None and spec.outage is not None
    a, b = (NetemShim(parse_netem({"v2v": {"outage": {"every_s": 30, "duration_ms": [50, 150]}}}, 9), me) for me in (2, 3))
    la, lb = a.link(1, Realm.VIRTUAL), b.link(1, Realm.VIRTUAL)
    sender_a = [r for r in la.radios if r.uav == 1][0]
    sender_b = [r for r in lb.radios if r.uav == 1][0]
    assert sender_a.intervals(0, 7200) == sender_b.intervals(0, 7200) == OutageSchedule(9, 1, spec.outage).intervals(0, 7200)
    assert sender_a.intervals(0, 7200) != OutageSchedule(9, 2, spec.outage).intervals(0, 7200)


# ---- link classes -----------------------------------------------------------------------------------
def test_link_classes_and_where_outages_apply() -> None:
    cfg = parse_netem({"preset": "5g-campus"})
    virt = NetemShim(cfg, 2, Realm.VIRTUAL)
    phys = NetemShim(cfg, 5, Realm.PHYSICAL)
    assert virt.link(1, Realm.VIRTUAL).cls == "v2v"
    assert virt.link(6, Realm.PHYSICAL).cls == "v2p"
    assert virt.link("gcs:runner").cls == "ground"
    assert phys.link(1, Realm.VIRTUAL).cls == "v2p"
    p2p = phys.link(6, Realm.PHYSICAL)
    assert p2p.cls is None and p2p.passthrough  # physical <-> physical: never impaired
    assert phys.link("gcs:runner").cls is None
    # only emulated radios go down: the virtual end of a v2p link
    assert [r.uav for r in virt.links[6].radios] == [2]
    assert [r.uav for r in phys.links[1].radios] == [1]
    assert sorted(r.uav for r in virt.links[1].radios) == [1, 2]
    # a UAV first heard through a swarm message (realm unknown) is taken as virtual, then re-classified by its pose
    lk = virt.link(7)
    assert lk.cls == "v2v"
    assert virt.link(7, Realm.PHYSICAL).cls == "v2p"


def test_5g_campus_preset_gives_the_papers_one_way_delay_between_virtual_uavs() -> None:
    shim, link = one_link(None, preset="5g-campus")
    shim.reconfigure(parse_netem({"preset": "5g-campus", "v2v": {"outage": None}}, 1))  # outages off to see the delay alone
    d = delays_ms(drive(shim, link, 20_000))
    assert d.mean() == pytest.approx(9.81, rel=0.05)
    assert link.cls == "v2v"


def test_degraded_preset_is_about_100_ms_30_ms_and_10_percent_bursty_loss() -> None:
    shim, link = one_link(None, preset="degraded")
    n = 100_000
    out = drive(shim, link, n, interval=0.1)  # 10 Hz poses
    d = delays_ms(out)
    assert d.mean() == pytest.approx(100.0, rel=0.05) and d.std() == pytest.approx(30.0, rel=0.05)
    lost = np.ones(n, dtype=bool)
    lost[[i for i, _, _ in out]] = False
    assert lost.mean() == pytest.approx(0.10, rel=0.07)
    assert bursts(lost).mean() == pytest.approx(3.0, rel=0.07)


# ---- reproducibility -------------------------------------------------------------------------------
def trace(seed: int | str, other_traffic: int = 0) -> list[tuple[int, float]]:
    prof = {"delay": {"ms": 40, "jitter_ms": 15, "distribution": "pareto", "correlation": 0.3},
            "loss": {"model": "gilbert_elliott", "rate": 0.1, "burst": 3}, "duplicate": 0.02,
            "reorder": {"p": 0.1, "gap": 3}}
    shim = shim_for(prof, seed)
    link = shim.link(1, Realm.VIRTUAL)
    noise = shim.link(3, Realm.VIRTUAL)
    out = []
    for i in range(3000):
        for k in range(other_traffic):  # interleaved traffic on another link of the same node
            shim.offer(noise, 1000.0 + i * 0.01, 0, ("noise", k))
        if shim.offer(link, 1000.0 + i * 0.01, 0, i):
            out.append((i, 1000.0 + i * 0.01))
        out += [(item, round(1000.0 + i * 0.01, 9)) for _, item, _, _ in shim.release(1000.0 + i * 0.01) if item in range(3000)]
    return out


def test_same_seed_same_sequence_whatever_the_other_traffic() -> None:
    a = trace(42)
    assert a == trace(42)
    assert a == trace(42, other_traffic=3)
    assert a != trace(43)
    assert trace("run-a") == trace("run-a") != trace("run-b")


def test_link_seeds_differ_per_direction() -> None:
    shim = shim_for({"loss": {"model": "bernoulli", "p": 0.5}}, 7, me=2)
    back = shim_for({"loss": {"model": "bernoulli", "p": 0.5}}, 7, me=1)
    a = drive(shim, shim.link(1, Realm.VIRTUAL), 200)
    b = drive(back, back.link(2, Realm.VIRTUAL), 200)
    assert [i for i, _, _ in a] != [i for i, _, _ in b]


# ---- pass-through and the arrival time inside a poll period ---------------------------------------------
def test_no_impairment_is_a_pass_through() -> None:
    for cfg in ({"preset": "none"}, {}, {"v2v": {"delay": {"ms": 0}}}):
        shim = NetemShim(parse_netem(cfg), 2)
        link = shim.link(1, Realm.VIRTUAL)
        assert link.passthrough
        assert all(shim.offer(link, 1000.0 + i, 0, i) for i in range(100))
        assert shim.pending == 0 and link.delivered == link.sent == 100
        assert link.stats()["delay"]["n"] == 100


def test_a_released_message_carries_its_arrival_through_the_link_whenever_it_is_released() -> None:
    """The owner offers each message with its arrival stamp and may release late (its poll
    tick); the time to send it gets back is arrival + the configured delay, exactly."""
    shim = NetemShim(parse_netem({"v2v": {"delay": {"ms": 20.0}}}), 2)
    link = shim.link(1, Realm.VIRTUAL)
    rng = random.Random(5)
    arrivals = sorted(rng.uniform(1000.0, 1010.0) for _ in range(500))
    for k, t in enumerate(arrivals):
        assert not shim.offer(link, t, 0, k)
    released = []
    for j in range(1, 300):  # released by a 40 ms poll loop, well after each time to send
        released += shim.release(1000.0 + j * 0.04)
    assert [item for _, item, _, _ in released] == list(range(500))
    assert all(tts == pytest.approx(arrivals[item] + 0.020, abs=1e-9) for _, item, _, tts in released)


# ---- configuration ---------------------------------------------------------------------------------
@pytest.mark.parametrize("cfg, path", [
    ({"v2v": {"delay": {"ms": -1}}}, "v2v.delay.ms"),
    ({"v2v": {"delay": {"ms": 10, "jitter_ms": 5}}}, "v2v.delay.distribution"),
    ({"v2v": {"delay": {"ms": 10, "jitter_ms": 5, "distribution": "gauss"}}}, "v2v.delay.distribution"),
    ({"v2v": {"delay": {"ms": 10, "correlation": 1.0}}}, "v2v.delay.correlation"),
    ({"v2v": {"loss": {"model": "gilbert_elliott", "p": 0.1}}}, "v2v.loss.r"),
    ({"v2v": {"loss": {"model": "gilbert_elliott", "rate": 0.1}}}, "v2v.loss.burst"),
    ({"v2p": {"loss": {"model": "four_state", "p13": 0.6, "p14": 0.6}}}, "v2p.loss.p14"),
    ({"ground": {"rate": {"kbit": 0}}}, "ground.rate.kbit"),
    ({"v2v": {"outage": {"every_s": 1, "duration_ms": 2000}}}, "v2v.outage.duration_ms"),
    ({"v2v": {"distance": {"model": "log_distance"}}}, "v2v.distance.exponent"),
    ({"v2v": {"delay": {"ms": 10}, "dealy": {}}}, "v2v.dealy"),
    ({"preset": "4g"}, "preset"),
    ({"links": [{"src": 1, "dst": 0, "duplicate": 0.1}]}, "links.0.dst"),
    ({"links": [{"src": "*", "dst": "*"}]}, "links.0"),
    ({"links": [{"src": 1, "dst": 2, "duplicate": 2}]}, "links.0.duplicate"),
    ({"partitions": {"a": [1, 2], "b": [2]}}, "partitions.b.0"),
    ({"exempt_commands": "yes"}, "exempt_commands"),
])
def test_config_errors_name_the_field(cfg: dict[str, Any], path: str) -> None:
    with pytest.raises(NetemConfigError) as err:
        parse_netem(cfg)
    assert err.value.path == path
    assert str(err.value).startswith(f"{path}: ")


def test_class_patch_merges_onto_the_preset_and_links_override() -> None:
    cfg = parse_netem({"preset": "degraded", "v2v": {"delay": {"ms": 200}},
                       "links": [{"src": 1, "dst": 2, "both_ways": True, "loss": None, "delay": {"ms": 5}}]})
    v2v = cfg.class_profile("v2v")
    assert v2v is not None and v2v.delay is not None
    assert (v2v.delay.ms, v2v.delay.jitter_ms, v2v.delay.distribution) == (200.0, 30.0, "normal")  # jitter kept
    assert v2v.loss is not None and v2v.loss.expected_rate == pytest.approx(0.10)
    for src, dst in ((1, 2), (2, 1)):
        lk = cfg.profile_for("v2v", src, dst)
        assert lk is not None and lk.loss is None and lk.delay is not None and lk.delay.ms == 5.0
    assert cfg.profile_for("v2v", 1, 3) == v2v
    # a different loss model replaces the component instead of mixing fields
    c2 = parse_netem({"preset": "degraded", "v2v": {"loss": {"model": "bernoulli", "p": 0.3}}}).class_profile("v2v")
    assert c2 is not None and c2.loss is not None and c2.loss.model == "bernoulli"
    assert parse_netem({"preset": "degraded", "v2v": None}).class_profile("v2v") is None


def test_every_preset_is_valid_and_the_seed_defaults_to_the_scenario_seed() -> None:
    from swarmnet.netem import PRESETS

    for name in PRESETS:
        cfg = parse_netem({"preset": name}, default_seed=11)
        assert cfg.seed == 11 and cfg.data == {"preset": name, "seed": 11}
        assert parse_netem(cfg.data).data == cfg.data  # the normalised form round-trips
    wifi = parse_netem({"preset": "wifi-mesh"}).class_profile("v2v")
    assert wifi is not None and wifi.distance is not None
    assert wifi.distance.nominal_range_m() == pytest.approx(182, rel=0.02)


# ---- bad input: clear errors, never a crash ------------------------------------------------------------
_KEYS = ["preset", "seed", "exempt_commands", "v2v", "v2p", "ground", "links", "partitions", "delay", "loss", "duplicate",
         "reorder", "rate", "limit", "outage", "distance", "ms", "jitter_ms", "distribution", "correlation", "fifo", "model",
         "p", "r", "rate", "burst", "loss_bad", "loss_good", "p13", "p31", "p32", "p23", "p14", "gap", "kbit",
         "overhead_bytes", "every_s", "duration_ms", "mode", "range_m", "full_m", "exponent", "sigma_db", "src", "dst",
         "both_ways", "bogus"]
_VALUES: list[Any] = [None, True, False, 0, 1, -1, 0.5, 2.5, 1e308, float("nan"), float("inf"), "", "*", "normal",
                      "gilbert_elliott", "bernoulli", "four_state", "range", "log_distance", "hold", "degraded", "lan",
                      [], [1, 2], [0.5], [50, 10], {}, 3, 65536]


def random_config(rng: random.Random, depth: int = 0) -> Any:
    if depth > 3 or rng.random() < 0.3:
        return rng.choice(_VALUES)
    if rng.random() < 0.2:
        return [random_config(rng, depth + 1) for _ in range(rng.randint(0, 3))]
    return {rng.choice(_KEYS): random_config(rng, depth + 1) for _ in range(rng.randint(0, 4))}


def test_random_configs_only_ever_raise_netem_config_errors() -> None:
    rng = random.Random(1)
    ok = 0
    for _ in range(20_000):
        cfg = random_config(rng)
        try:
            c = parse_netem(cfg)
        except NetemConfigError as exc:
            assert exc.path is not None and str(exc)
            continue
        ok += 1
        shim = NetemShim(c, 2)  # whatever validates also runs
        link = shim.link(1, Realm.VIRTUAL)
        for i in range(20):
            shim.offer(link, 1000.0 + i * 0.01, 0, i)
        shim.release(2000.0)
    assert ok > 100  # the generator also produces valid configs
