"""The random models behind a link: delay, loss, outage schedules. Pure Python, one RNG per link.

Every model draws from the ``random.Random`` it is given (the link's), never from a global
one, so a link's sequence depends only on its seed and on its own traffic.

Delay: ``delay = max(0, mu + sigma * z_n)`` with the standardised shape ``z``:

* ``uniform``: ``z ~ U[-1, 1)``, so ``jitter_ms`` is the half-width, as in netem (whose
  kernel draws uniform jitter when no table is loaded);
* ``normal``: ``z ~ N(0, 1)``: ``jitter_ms`` is the standard deviation;
* ``pareto``: netem's table shape, Pareto with shape 3 (``U**(-1/3)``, mean 1.5, var 0.75),
  shifted to mean 0 and scaled to sd 1, so ``jitter_ms`` is the standard deviation (netem's
  table is scaled by 4/3 instead, an sd of 1.155 sigma before its +4 sigma clip);
* ``paretonormal``: netem's table shape, the quantile mix ``0.25 * normal + 0.75 * pareto``
  (both from the same uniform), scaled to sd 1.

Correlation ``rho`` is an AR(1) process on the standardised value,
``z_n = rho z_{n-1} + sqrt(1 - rho^2) e_n``, which keeps the mean and the standard deviation
and gives lag-1 autocorrelation ``rho`` (netem's "correlation" mixes uniforms instead, the
kernel's ``get_crandom`` in ``sch_netem.c``, and shrinks the variance). With ``rho > 0`` only the normal
shape is kept exactly; other shapes drift towards normal.
"""

from __future__ import annotations

import bisect
import math
import random
from collections.abc import Callable

from swarmnet.netem.config import BernoulliLoss, DelaySpec, FourStateLoss, GilbertElliottLoss, LossSpec, OutageSpec

_PARETO_MEAN = 1.5  # of U**(-1/3)
_PARETO_SD = math.sqrt(0.75)
# sd of 0.25 * Phi^-1(q) + (1 - q)**(-1/3) - 1.5 over q ~ U(0, 1) (comonotone mix); the
# statistical tests recompute it by numerical integration
PARETONORMAL_SD = 1.0517772455747123


def _shape_uniform(rng: random.Random) -> float:
    return 2.0 * rng.random() - 1.0


def _shape_normal(rng: random.Random) -> float:
    return rng.normalvariate(0.0, 1.0)


def _shape_pareto(rng: random.Random) -> float:
    u = 1.0 - rng.random()  # (0, 1]
    return (u ** (-1.0 / 3.0) - _PARETO_MEAN) / _PARETO_SD


def _make_paretonormal() -> Callable[[random.Random], float]:
    from statistics import NormalDist  # imported only when someone configures paretonormal

    inv_cdf = NormalDist().inv_cdf

    def shape(rng: random.Random) -> float:
        q = rng.random()
        if q <= 0.0:
            q = 5e-324
        return (0.25 * inv_cdf(q) + (1.0 - q) ** (-1.0 / 3.0) - _PARETO_MEAN) / PARETONORMAL_SD

    return shape


def make_shape(distribution: str) -> Callable[[random.Random], float]:
    """The standardised jitter draw of a distribution (see the module docstring)."""
    if distribution == "uniform":
        return _shape_uniform
    if distribution == "normal":
        return _shape_normal
    if distribution == "pareto":
        return _shape_pareto
    if distribution == "paretonormal":
        return _make_paretonormal()
    raise ValueError(f"unknown distribution {distribution!r}")


class DelayGen:
    """Draws one-way delays in seconds."""

    __slots__ = ("mu", "sigma", "rho", "c", "shape", "z")

    def __init__(self, spec: DelaySpec):
        self.mu = spec.ms / 1000.0
        self.sigma = spec.jitter_ms / 1000.0
        self.rho = spec.correlation
        self.c = math.sqrt(1.0 - self.rho * self.rho)
        self.shape = make_shape(spec.distribution or "normal")  # no jitter: unused
        self.z: float | None = None  # AR(1) state

    def draw(self, rng: random.Random) -> float:
        if self.sigma == 0.0:
            return self.mu
        e = self.shape(rng)
        if self.rho:
            z = self.z
            e = e if z is None else self.rho * z + self.c * e
            self.z = e
        d = self.mu + self.sigma * e
        return d if d > 0.0 else 0.0


class LossGen:
    """One loss event per call (True = lost), netem's semantics for each model."""

    __slots__ = ("model", "p", "r", "loss_bad", "loss_good", "bad", "state", "s")

    def __init__(self, spec: LossSpec):
        self.model = spec.model
        self.s = spec if isinstance(spec, FourStateLoss) else None
        self.p, self.r, self.loss_bad, self.loss_good = 0.0, 1.0, 1.0, 0.0
        if isinstance(spec, BernoulliLoss):
            self.p = spec.p
        elif isinstance(spec, GilbertElliottLoss):  # validated: the chain is always filled in
            self.p, self.r = float(spec.p or 0.0), float(spec.r or 0.0)
            self.loss_bad, self.loss_good = float(spec.loss_bad or 0.0), float(spec.loss_good or 0.0)
        self.bad = False  # Gilbert-Elliott state
        self.state = 1  # 4-state chain: 1 gap, 2 burst (delivered), 3 burst (lost), 4 isolated loss

    def lost(self, rng: random.Random) -> bool:
        m = self.model
        if m == "bernoulli":
            return rng.random() < self.p
        if m == "gilbert_elliott":
            # the loss decision uses the state the message arrives in; the transition applies to the next one
            if self.bad:
                if rng.random() < self.r:
                    self.bad = False
                return rng.random() < self.loss_bad
            if rng.random() < self.p:
                self.bad = True
            return rng.random() < self.loss_good
        return self._four_state(rng)

    def _four_state(self, rng: random.Random) -> bool:
        s, u = self.s, rng.random()
        assert s is not None  # the four_state model has its spec
        st = self.state
        if st == 1:
            if u < s.p14:
                self.state = 4
                return True
            if u < s.p13 + s.p14:
                self.state = 3
                return True
            return False
        if st == 2:
            if u < s.p23:
                self.state = 3
                return True
            return False
        if st == 3:
            if u < s.p32:
                self.state = 2
                return False
            if u < s.p31 + s.p32:
                self.state = 1
                return False
            return True
        self.state = 1  # 4: an isolated loss is always followed by a delivery
        return False


class OutageSchedule:
    """When one UAV's radio is down: a Poisson process of outages with uniform durations.

    The schedule is a pure function of ``(seed, uav, spec)`` and absolute wall time, built in
    one-hour windows with an RNG per window, so every node computes the same outages for the
    same UAV (a receiver knows when the *sender's* radio was down without being told), and
    any instant can be looked up without generating the past.
    """

    WINDOW = 3600.0  # s; >= the longest allowed outage, so only the previous window can spill over

    def __init__(self, seed: int | str, uav: int | str, spec: OutageSpec):
        self.seed, self.uav, self.spec = seed, uav, spec
        self._windows: dict[int, tuple[list[float], list[float]]] = {}
        self._merged_windows: dict[int, tuple[list[float], list[float]]] = {}
        self._lo, self._hi, self._ans = 0.0, 0.0, 0.0  # the cached answer and where it holds

    def _window(self, w: int) -> tuple[list[float], list[float]]:
        got = self._windows.get(w)
        if got is not None:
            return got
        if len(self._windows) > 16:
            self._windows.clear()
        s = self.spec
        rng = random.Random(f"netem-outage/{self.seed}/{self.uav}/{w}")
        t = w * self.WINDOW
        end_w = t + self.WINDOW
        starts: list[float] = []
        ends: list[float] = []
        lo, hi = s.duration_min_ms / 1000.0, s.duration_max_ms / 1000.0
        while True:
            t += rng.expovariate(1.0 / s.every_s)
            if t >= end_w:
                break
            e = t + (lo + (hi - lo) * rng.random())
            if starts and t <= ends[-1]:  # overlapping outages merge
                ends[-1] = max(ends[-1], e)
            else:
                starts.append(t)
                ends.append(e)
        self._windows[w] = (starts, ends)
        return starts, ends

    def _merged(self, w: int) -> tuple[list[float], list[float]]:
        """Window ``w``'s outages with the one still running from window ``w - 1``, overlaps merged."""
        got = self._merged_windows.get(w)
        if got is not None:
            return got
        if len(self._merged_windows) > 16:
            self._merged_windows.clear()
        starts, ends = self._window(w)
        ps, pe = self._window(w - 1)
        out_s: list[float] = []
        out_e: list[float] = []
        if pe and pe[-1] > w * self.WINDOW:
            out_s.append(ps[-1])
            out_e.append(pe[-1])
        for a, b in zip(starts, ends, strict=False):
            if out_e and a <= out_e[-1]:
                out_e[-1] = max(out_e[-1], b)
            else:
                out_s.append(a)
                out_e.append(b)
        self._merged_windows[w] = (out_s, out_e)
        return out_s, out_e

    def down_until(self, t: float) -> float:
        """End of the outage covering ``t``, or 0.0 if the radio is up at ``t``.

        The answer holds on a whole interval (up until the next outage starts, down until it
        ends), which is cached, so the per-message query is O(1) for ordinary traffic.
        """
        if self._lo <= t < self._hi:
            return self._ans
        w = int(t // self.WINDOW)
        starts, ends = self._merged(w)
        i = bisect.bisect_right(starts, t) - 1
        if i >= 0 and ends[i] > t:
            lo, end = starts[i], ends[i]
            ww = w
            while end >= (ww + 1) * self.WINDOW:  # the outage runs into the next window: merge with what starts there
                ww += 1
                ns, ne = self._merged(ww)
                for a, b in zip(ns, ne, strict=False):
                    if a <= end:
                        end = max(end, b)
            self._lo, self._hi, self._ans = lo, end, end
            return end
        lo = ends[i] if i >= 0 else w * self.WINDOW
        hi = starts[i + 1] if i + 1 < len(starts) else (w + 1) * self.WINDOW
        self._lo, self._hi, self._ans = lo, hi, 0.0
        return 0.0

    def intervals(self, t0: float, t1: float) -> list[tuple[float, float]]:
        """All outages (overlaps merged) that overlap [t0, t1), for tests and reports."""
        out: list[tuple[float, float]] = []
        t = t0
        while t < t1:
            end = self.down_until(t)
            if end:
                out.append((self._lo, end))
                t = end
            else:
                t = self._hi
        return out
