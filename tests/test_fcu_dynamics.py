"""Vectorised multirotor dynamics: limits, no overshoot, ground contact, N=1 vs N=100."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_stack.fcu import dynamics
from uav_stack.fcu.dynamics import G, MultirotorArray, MultirotorParams

DT = 0.02


def fly(d: MultirotorArray, seconds: float, n_per_call: int = 5) -> None:
    for _ in range(int(round(seconds / DT / n_per_call))):
        d.step(DT, n_per_call)


def airborne(n: int = 1, alt: float = 5.0) -> MultirotorArray:
    d = MultirotorArray(n)
    d.armed[:] = True
    d.pos_sp[:] = [0.0, 0.0, -alt]
    fly(d, 8.0)
    assert np.allclose(d.pos[:, 2], -alt, atol=0.05)
    return d


@pytest.mark.parametrize("dist,vmax", [(2.0, 5.0), (20.0, 5.0), (30.0, 12.0), (5.0, 12.0)])
def test_position_target_reached_without_overshoot(dist: float, vmax: float) -> None:
    d = airborne()
    d.vxy_max[:] = vmax
    d.pos_sp[0] = [dist, 0.0, -5.0]
    peak, peak_speed = -1e9, 0.0
    for _ in range(int(15 / DT)):
        d.step(DT)
        peak = max(peak, d.pos[0, 0])
        peak_speed = max(peak_speed, math.hypot(d.vel[0, 0], d.vel[0, 1]))
    assert abs(d.pos[0, 0] - dist) < 0.05
    assert peak - dist < 0.05, "overshoot"
    assert peak_speed <= vmax * 1.01
    if dist >= 20 and vmax == 5.0:
        assert peak_speed > 0.95 * vmax  # actually reaches the speed limit on long legs


def test_velocity_only_axes_and_limits() -> None:
    d = airborne()
    d.vxy_max[:] = 12.0
    d.pos_sp[0] = [np.nan, np.nan, -5.0]  # hold altitude, velocity in xy
    d.vel_ff[0] = [3.0, -4.0, 0.0]
    fly(d, 5.0)
    assert np.allclose(d.vel[0], [3.0, -4.0, 0.0], atol=0.02)
    assert abs(d.pos[0, 2] + 5.0) < 0.05
    # horizontal norm limit and acceleration limit
    d.vel_ff[0] = [30.0, 0.0, 0.0]
    prev = d.vel[0].copy()
    worst = 0.0
    for _ in range(int(6 / DT)):
        d.step(DT)
        worst = max(worst, np.hypot(*(d.vel[0, :2] - prev[:2])) / DT)
        prev = d.vel[0].copy()
    assert math.hypot(d.vel[0, 0], d.vel[0, 1]) == pytest.approx(12.0, abs=0.05)
    assert worst < G * math.tan(math.radians(45)) + 0.1
    # climb/descent limits
    d.pos_sp[0] = [np.nan, np.nan, np.nan]
    d.vel_ff[0] = [0.0, 0.0, -10.0]
    fly(d, 2.0)
    assert d.vel[0, 2] == pytest.approx(-d.vz_up[0], abs=0.02)
    d.vel_ff[0] = [0.0, 0.0, 10.0]
    fly(d, 4.0)
    assert d.vel[0, 2] == pytest.approx(d.vz_dn[0], abs=0.02)


def test_ground_contact_landing_and_takeoff() -> None:
    d = MultirotorArray(1)
    d.armed[:] = True
    assert d.landed[0]
    d.pos_sp[0] = [0.0, 0.0, 0.0]
    fly(d, 1.0)
    assert d.landed[0] and d.pos[0, 2] == 0.0  # armed, idle on the ground
    d.vz_up[:] = 1.5
    d.pos_sp[0] = [0.0, 0.0, -2.0]
    d.step(DT, 10)
    assert not d.landed[0]
    fly(d, 6.0)
    assert d.pos[0, 2] == pytest.approx(-2.0, abs=0.02)
    d.pos_sp[0] = [np.nan, np.nan, np.nan]
    d.vel_ff[0] = [0.0, 0.0, 0.7]
    fly(d, 4.0)
    assert d.landed[0] and d.pos[0, 2] == 0.0 and np.all(d.vel[0] == 0.0)


def test_disarmed_in_air_falls_and_stops_on_ground() -> None:
    d = airborne(alt=3.0)
    d.armed[:] = False
    fly(d, 3.0)
    assert d.pos[0, 2] == 0.0 and d.landed[0]
    assert np.all(d.vel[0] == 0.0)


def test_yaw_rate_limit_and_attitude() -> None:
    d = airborne()
    d.yaw_sp[0] = math.pi / 2
    d.step(DT, 50)  # 1 s at <= 60 deg/s
    assert d.yaw[0] <= math.radians(60) + 1e-6
    fly(d, 4.0)
    assert d.yaw[0] == pytest.approx(math.pi / 2, abs=0.01)
    # accelerating north while facing east: rolls (right wing down is +roll towards east... north is left)
    d.pos_sp[0] = [np.nan, np.nan, -5.0]
    d.vel_ff[0] = [5.0, 0.0, 0.0]
    d.step(DT, 10)
    assert d.roll[0] < -0.05 and abs(d.pitch[0]) < 0.05


def test_battery_drains_only_when_armed() -> None:
    d = MultirotorArray(2, MultirotorParams(battery_endurance_s=100.0))
    d.armed[:] = [True, False]
    d.pos_sp[:] = [0.0, 0.0, -3.0]
    fly(d, 10.0)
    assert d.battery[1] == 1.0
    assert 0.85 < d.battery[0] < 0.95  # ~10 % of a 100 s endurance


def _random_scenario(d: MultirotorArray, rng: np.random.Generator, k: int) -> None:
    n = d.n
    psp = rng.uniform(-20, 20, (n, 3))
    psp[:, 2] = -np.abs(psp[:, 2])
    psp[rng.random((n, 3)) < 0.3] = np.nan
    d.pos_sp[:] = psp
    d.vel_ff[:] = rng.uniform(-3, 3, (n, 3))
    ysp = rng.uniform(-3, 3, n)
    ysp[rng.random(n) < 0.5] = np.nan
    d.yaw_sp[:] = ysp
    d.yaw_rate_sp[:] = rng.uniform(-1, 1, n)
    if k == 2:
        d.armed[: n // 3] = False  # some fall, some rest on the ground


@pytest.mark.parametrize("n", [1, 7, 100])
def test_scalar_and_vector_paths_agree(n: int) -> None:
    rng = np.random.default_rng(n)
    yaw = rng.uniform(-3, 3, n)
    a, b = MultirotorArray(n, yaw=yaw), MultirotorArray(n, yaw=yaw)
    a.scalar_max, b.scalar_max = 0, 10_000  # force vector / scalar
    a.armed[:] = b.armed[:] = True
    for k in range(4):
        state = np.random.default_rng(100 + k)
        _random_scenario(a, state, k)
        _random_scenario(b, np.random.default_rng(100 + k), k)
        for _ in range(30):
            a.step(DT, 5)
            b.step(DT, 5)
    for name in ("pos", "vel", "acc", "yaw", "roll", "pitch", "battery", "landed", "yaw_rate", "roll_rate"):
        x, y = getattr(a, name).astype(float), getattr(b, name).astype(float)
        assert np.allclose(x, y, atol=1e-9), name


def test_hundred_vehicles_step_together() -> None:
    n = 100
    d = MultirotorArray(n, yaw=np.linspace(-3, 3, n))
    assert d.scalar_max < n  # the vectorised path
    d.armed[:] = True
    targets = np.stack([np.arange(n) * 2.0, -np.arange(n) * 1.0, -np.full(n, 4.0)], axis=1)
    d.pos_sp[:] = targets
    d.vxy_max[:] = 12.0
    fly(d, 25.0)
    assert np.allclose(d.pos, targets, atol=0.05)
    assert not d.landed.any()
    assert d.pos.shape == (n, 3) and d.yaw.shape == (n,)


def _mission(d: MultirotorArray, seconds: float, n_per_call: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Take off, fly a square in wind with yaw targets, land, disarm: every branch of the step.
    The track of the flight, then of the rest after the disarm."""
    d.armed[:] = True
    d.wind[:] = (2.0, -1.0, 0.0)
    track, rest = [], []
    legs = [(0.0, 0.0, -10.0), (30.0, 0.0, -10.0), (30.0, 30.0, -12.0), (0.0, 30.0, -8.0), (0.0, 0.0, 0.5)]
    per_leg = seconds / len(legs)
    for k, sp in enumerate(legs):
        d.pos_sp[:] = sp
        d.yaw_sp[:] = np.nan if k % 2 else 0.5 * k
        d.yaw_rate_sp[:] = 0.2
        calls = int(per_leg / (DT * n_per_call))
        for _ in range(calls):
            d.step(DT, n_per_call)
            track.append(np.concatenate([d.pos.ravel(), d.vel.ravel(), d.acc.ravel(), d.yaw, d.roll, d.pitch,
                                         d.battery, d.landed.astype(float), d.yaw_rate, d.pitch_rate]))
    d.armed[:] = False  # motors off on the ground: it must rest, then stay put
    for _ in range(50):
        d.step(DT, 1)
        rest.append(np.concatenate([d.pos.ravel(), d.vel.ravel(), d.landed.astype(float)]))
    return track, rest


@pytest.mark.parametrize("n", [1, 3])
def test_scalar_and_vector_paths_fly_the_same_mission(n: int) -> None:
    """A virtual UAV takes the scalar path: through every branch of a mission it flies as the vectorised
    path does; disarmed on the ground it rests and stays put, in the wind too."""
    yaw = np.linspace(-2.0, 2.0, n)
    s, v = MultirotorArray(n, yaw=yaw), MultirotorArray(n, yaw=yaw)
    v.scalar_max = 0  # force the vectorised path
    (ts, rest), (tv, rest_v) = _mission(s, 80.0, 2), _mission(v, 80.0, 2)
    assert len(ts) == len(tv) > 1000
    worst = max(float(np.max(np.abs(a - b))) for a, b in zip([*ts, *rest], [*tv, *rest_v], strict=True))
    assert worst < 1e-9
    assert s.landed.all() and not s.armed.any() and np.allclose(s.pos[:, 2], 0.0)
    assert s.battery[0] < 1.0
    assert all(np.array_equal(r, rest[0]) for r in rest) and not rest[0][3 * n:6 * n].any()


@pytest.mark.parametrize("n", [1, 3])
def test_one_vehicles_values_read_and_targets_written(n: int) -> None:
    """What the FCU's telemetry, setpoints and failsafes read and write of one vehicle: each field's
    value with its type (an (x, y, z) tuple of floats, a bool or a float), NaN and infinities as
    they are, also after an array was replaced; the targets of that vehicle only."""
    rng = np.random.default_rng(7)
    for _ in range(20):
        d = MultirotorArray(n)
        d.step(0.02, 3)
        for name in dynamics.FIELDS:  # any state, NaN and the limits too
            arr = getattr(d, name)
            vals = rng.random(arr.shape) > 0.5 if arr.dtype == np.bool_ else rng.normal(0.0, 50.0, arr.shape)
            if arr.dtype != np.bool_:
                vals.flat[rng.integers(vals.size)] = rng.choice([math.nan, math.inf, -0.0, 1e308])
            arr[...] = vals
        for k, name in enumerate(dynamics.FIELDS):
            arr = getattr(d, name)
            for i in range(n):
                got = d.get(k, i)
                if arr.ndim == 2:
                    assert type(got) is tuple and len(got) == 3 and all(type(x) is float for x in got), name
                else:
                    assert type(got) is (bool if arr.dtype == np.bool_ else float), name
                assert np.array_equal(np.asarray(got), arr[i], equal_nan=True), name
        i = int(rng.integers(n))
        before = {name: getattr(d, name).copy() for name in ("pos_sp", "vel_ff", "yaw_sp", "yaw_rate_sp")}
        pos, vel = tuple(rng.normal(0.0, 10.0, 3)), (math.nan, float(rng.normal()), 0.5)
        d.set_targets(i, pos, vel, math.nan, 0.25)
        assert np.array_equal(d.pos_sp[i], pos) and np.array_equal(d.vel_ff[i], vel, equal_nan=True)
        assert math.isnan(d.yaw_sp[i]) and d.yaw_rate_sp[i] == 0.25
        for name, was in before.items():
            assert np.array_equal(np.delete(getattr(d, name), i, axis=0), np.delete(was, i, axis=0), equal_nan=True), name
    d.pos = d.pos.copy()  # another array under the same name: read from it
    d.pos[0] = (1.0, 2.0, 3.0)
    assert d.get(dynamics.POS, 0) == (1.0, 2.0, 3.0)
    with pytest.raises(IndexError):
        d.get(dynamics.POS, n)
