"""Closed-loop multirotor dynamics for N vehicles at once (numpy, NED).

This is not a rigid-body simulator: it models what a swarm experiment sees of a PX4-tuned
quadrotor flying under its own position/velocity controllers (docs/fcu.md, Dynamics):

* position P-gains with a square-root braking profile, so position targets are reached
  without overshoot at the configured horizontal acceleration;
* velocity limits (horizontal norm, separate climb/descent), acceleration and tilt limits;
* a first-order lag between commanded and achieved acceleration (attitude/thrust response);
* linear drag (compensated by the controller, so it only matters in transients, with wind
  and when the motors are off);
* a yaw-rate limited heading controller;
* ground contact, landed detection, roll/pitch derived from the acceleration for telemetry;
* battery state of charge draining while armed.

All state lives in ``(N,)`` or ``(N, 3)`` float arrays; ``step`` advances every vehicle with a
fixed number of vectorised numpy operations, independent of N. A NaN in ``pos_sp`` on an
axis means "no position control on that axis": that axis follows ``vel_ff`` only.

A few vehicles (a virtual UAV has one) take a scalar path instead: the same equations on
Python floats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

G = 9.80665


# The arrays :meth:`MultirotorArray.get` reads, by index.
FIELDS = ("pos", "vel", "acc", "pos_sp", "vel_ff", "wind", "armed", "landed", "ground_z", "vxy_max", "vz_up", "vz_dn",
          "acc_hor", "tilt_acc", "yaw_rate_max", "yaw_sp", "yaw_rate_sp", "yaw", "yaw_rate", "roll", "pitch",
          "roll_rate", "pitch_rate", "battery", "endurance_s")
POS, VEL, LANDED, YAW, YAW_RATE, ROLL, PITCH, ROLL_RATE, PITCH_RATE, BATTERY = (
    FIELDS.index(f) for f in ("pos", "vel", "landed", "yaw", "yaw_rate", "roll", "pitch", "roll_rate", "pitch_rate", "battery"))


@dataclass
class MultirotorParams:
    """PX4-like limits (defaults: the PX4 parameters named beside each) and the model's time constants."""

    xy_cruise: float = 5.0  # MPC_XY_CRUISE, m/s: auto modes, goto, RTL
    xy_vel_max: float = 12.0  # MPC_XY_VEL_MAX, m/s: offboard
    z_vel_up: float = 3.0  # MPC_Z_VEL_MAX_UP, m/s
    z_vel_dn: float = 1.5  # MPC_Z_VEL_MAX_DN, m/s
    acc_hor: float = 3.0  # MPC_ACC_HOR, m/s^2
    acc_up: float = 4.0  # MPC_ACC_UP_MAX, m/s^2
    acc_dn: float = 3.0  # MPC_ACC_DOWN_MAX, m/s^2
    tilt_max_deg: float = 45.0  # MPC_TILTMAX_AIR
    takeoff_speed: float = 1.5  # MPC_TKO_SPEED, m/s
    land_speed: float = 0.7  # MPC_LAND_SPEED, m/s (below land_alt_slow)
    land_alt_slow: float = 5.0  # MPC_LAND_ALT2, m: above it LAND descends at z_vel_dn
    yaw_rate_max_deg: float = 60.0  # MPC_YAWRAUTO_MAX, deg/s
    kp_xy: float = 0.95  # MPC_XY_P, 1/s
    kp_z: float = 1.0  # MPC_Z_P, 1/s
    kp_yaw: float = 2.0  # 1/s
    tau_vel_xy: float = 0.3  # s, velocity loop time constant
    tau_vel_z: float = 0.25  # s
    tau_att: float = 0.12  # s, commanded -> achieved acceleration lag
    drag: float = 0.25  # 1/s, linear drag per unit mass
    landed_alt: float = 0.05  # m: below this height and slow = landed
    landed_speed: float = 0.3  # m/s
    battery_endurance_s: float = 1200.0  # full -> empty while hovering (SIM_BAT_DRAIN)
    battery_idle_fraction: float = 0.1  # drain while armed on the ground, relative to hover
    battery_capacity_mah: float = 5000.0
    battery_cells: int = 4
    cell_v_full: float = 4.2
    cell_v_empty: float = 3.5

    def hover_current_a(self) -> float:
        return self.battery_capacity_mah / 1000.0 * 3600.0 / self.battery_endurance_s

    def voltage(self, soc: float) -> float:
        """Pack voltage for a state of charge 0..1 (linear per cell)."""
        soc = min(max(soc, 0.0), 1.0)
        return self.battery_cells * (self.cell_v_empty + (self.cell_v_full - self.cell_v_empty) * soc)


def wrap_pi(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % (2.0 * np.pi) - np.pi



class MultirotorArray:
    """State, setpoints and per-vehicle limits of N multirotors; ``step`` advances all."""

    def __init__(self, n: int, params: MultirotorParams | None = None, yaw: np.ndarray | float = 0.0):
        if n < 1:
            raise ValueError("need at least one vehicle")
        p = params or MultirotorParams()
        self.n = n
        self.params = p
        f = np.float64
        # state
        self.pos = np.zeros((n, 3), f)
        self.vel = np.zeros((n, 3), f)
        self.acc = np.zeros((n, 3), f)  # achieved net acceleration (thrust + gravity), NED
        self.yaw = wrap_pi(np.broadcast_to(np.asarray(yaw, f), (n,)).copy())
        self.yaw_rate = np.zeros(n, f)
        self.roll = np.zeros(n, f)
        self.pitch = np.zeros(n, f)
        self.roll_rate = np.zeros(n, f)
        self.pitch_rate = np.zeros(n, f)
        self.battery = np.ones(n, f)  # state of charge 0..1
        self.armed = np.zeros(n, bool)
        self.landed = np.ones(n, bool)
        self.ground_z = np.zeros(n, f)  # NED down of the ground under each vehicle
        self.wind = np.zeros((n, 3), f)
        # setpoints
        self.pos_sp = np.zeros((n, 3), f)  # NaN per axis = velocity only
        self.vel_ff = np.zeros((n, 3), f)
        self.yaw_sp = np.full(n, np.nan, f)  # NaN = hold heading (or follow yaw_rate_sp)
        self.yaw_rate_sp = np.full(n, np.nan, f)
        # per-vehicle limits (parameters can differ per vehicle and per mode)
        self.vxy_max = np.full(n, p.xy_cruise, f)
        self.vz_up = np.full(n, p.z_vel_up, f)
        self.vz_dn = np.full(n, p.z_vel_dn, f)
        self.acc_hor = np.full(n, p.acc_hor, f)
        self.tilt_acc = np.full(n, G * math.tan(math.radians(p.tilt_max_deg)), f)
        self.yaw_rate_max = np.full(n, math.radians(p.yaw_rate_max_deg), f)
        self.endurance_s = np.full(n, p.battery_endurance_s, f)
        # constants
        self._inv_tau_col = np.array([[1.0 / p.tau_vel_xy], [1.0 / p.tau_vel_xy], [1.0 / p.tau_vel_z]], f)
        self._gcol = np.array([[0.0], [0.0], [G]], f)
        self._bz = 0.5 * min(p.acc_up, p.acc_dn)  # vertical braking deceleration of the profile
        self._2bz = 2.0 * self._bz

    # ------------------------------------------------------------------ one vehicle's values
    # The virtual FCU's steady tick reads and writes a dozen of these (telemetry, the setpoint,
    # the failsafes) through these two.
    def get(self, k: int, i: int) -> Any:
        """Vehicle ``i``'s value of field ``FIELDS[k]``: a float, a bool (armed, landed) or an
        (x, y, z) tuple of floats (pos, vel, acc, pos_sp, vel_ff, wind), the units of the field."""
        a = getattr(self, FIELDS[k])
        if a.ndim == 2:
            return tuple(a[i].tolist())
        return bool(a[i]) if a.dtype == np.bool_ else float(a[i])

    def set_targets(self, i: int, pos: Any, vel: Any, yaw: float, yaw_rate: float) -> None:
        """Vehicle ``i``'s position setpoint (m, NED; NaN: that axis free), velocity feed-forward
        (m/s, NED), yaw setpoint (rad) and yaw-rate setpoint (rad/s; NaN: none)."""
        self.pos_sp[i] = pos
        self.vel_ff[i] = vel
        self.yaw_sp[i] = yaw
        self.yaw_rate_sp[i] = yaw_rate

    # ------------------------------------------------------------------ helpers
    def stop_point(self, i: int) -> np.ndarray:
        """Where vehicle i comes to rest if told to hold now (braking at the profile's rate)."""
        p = self.pos[i].copy()
        if self.landed[i]:
            return p
        v = self.vel[i]
        sxy = math.hypot(v[0], v[1])
        if sxy > 1e-3:
            d = sxy * sxy / self.acc_hor[i] + sxy * self.params.tau_vel_xy  # 2*(acc/2) braking + lag
            p[0] += v[0] / sxy * d
            p[1] += v[1] / sxy * d
        p[2] += v[2] * abs(v[2]) / (2.0 * self._bz) + v[2] * self.params.tau_vel_z
        p[2] = min(p[2], self.ground_z[i])
        return p

    def height(self, i: int) -> float:
        return float(self.ground_z[i] - self.pos[i, 2])

    # --------------------------------------------------------------------- step
    scalar_max: int = 8

    def step(self, dt: float, n: int = 1) -> None:
        """Advance all vehicles by ``n`` steps of ``dt`` seconds (semi-implicit Euler;
        stable for dt <= ~0.05).

        numpy's per-call overhead (~0.6 us) dominates for a handful of vehicles, so small
        fleets take an equivalent scalar path (same equations, ``math`` on Python floats, arrays
        converted once per call). One vehicle, two steps a call, warm: 10.8 us; in a UAV among
        50 others, caches cold, several times that. Tests check that both paths agree.
        """
        if n < 1:
            return
        if self.n <= self.scalar_max:
            self._step_scalar(dt, n)
        else:
            for _ in range(n):
                self._step_vector(dt)

    def _step_vector(self, dt: float) -> None:
        prm = self.params
        # (3, N) views of the (N, 3) storage: row k is axis k of every vehicle
        P, V, A = self.pos.T, self.vel.T, self.acc.T
        armed = self.armed
        gz_ = self.ground_z
        # motors off, resting on the ground: nothing changes (the wind's drag would else move it a hair a step)
        rest = ~armed & (P[2] >= gz_) & ~(V.any(axis=0) | A.any(axis=0)) & (self.roll == 0.0) & (self.pitch == 0.0)

        # position loop: P gain, square-root braking profile sqrt(2*(acc/2)*e), NaN axes off
        psp = self.pos_sp.T
        e = np.where(np.isnan(psp), 0.0, psp - P)
        exy = np.hypot(e[0], e[1])
        gxy = np.minimum(np.sqrt(self.acc_hor / np.maximum(exy, 1e-9)), prm.kp_xy)
        gzz = np.minimum(np.sqrt(self._2bz / np.maximum(np.abs(e[2]), 1e-9)), prm.kp_z)
        e[:2] *= gxy
        e[2] *= gzz
        vsp = e + self.vel_ff.T
        s = np.minimum(self.vxy_max / np.maximum(np.hypot(vsp[0], vsp[1]), 1e-9), 1.0)
        vsp[:2] *= s
        vsp[2] = np.minimum(np.maximum(vsp[2], -self.vz_up), self.vz_dn)

        # velocity loop -> acceleration setpoint; acc limit, drag feed-forward, tilt limit
        asp = (vsp - V) * self._inv_tau_col
        asp[:2] *= np.minimum(self.acc_hor / np.maximum(np.hypot(asp[0], asp[1]), 1e-9), 1.0)
        asp[2] = np.minimum(np.maximum(asp[2], -prm.acc_up), prm.acc_dn)
        rel = V - self.wind.T
        asp += prm.drag * rel
        axy = np.hypot(asp[0], asp[1])
        s = np.minimum(self.tilt_acc / np.maximum(axy, 1e-9), 1.0)
        asp[:2] *= s
        axy *= s

        # attitude/thrust lag; motors off when disarmed
        A += (asp - A) * min(1.0, dt / prm.tau_att)
        np.copyto(A, self._gcol, where=~armed)

        # integrate
        V += (A - prm.drag * rel) * dt
        P += np.where(rest, 0.0, V * dt)

        # ground contact
        below = P[2] >= gz_
        P[2] = np.minimum(P[2], gz_)
        V[2] = np.where(below, np.minimum(V[2], 0.0), V[2])
        free = ~(below & (A[2] >= -1e-3))
        V *= free
        A *= free
        self.landed = ~free | ((P[2] > gz_ - prm.landed_alt) & (np.abs(V[2]) < prm.landed_speed) & (A[2] > -0.5))

        # heading
        ysp = self.yaw_sp
        rate = np.where(
            np.isnan(ysp), self.yaw_rate_sp, prm.kp_yaw * (((ysp - self.yaw) + np.pi) % _TWO_PI - np.pi)
        )
        rate = np.minimum(np.maximum(rate, -self.yaw_rate_max), self.yaw_rate_max)
        rate = np.where((rate == rate) & armed & ~self.landed, rate, 0.0)
        self.yaw_rate = rate
        self.yaw = ((self.yaw + rate * dt) + np.pi) % _TWO_PI - np.pi

        # attitude for telemetry: the thrust vector tilts towards the acceleration
        c, sn = np.cos(self.yaw), np.sin(self.yaw)
        fwd = c * A[0] + sn * A[1]
        right = c * A[1] - sn * A[0]
        up = np.maximum(G - A[2], 0.0)
        pitch = -np.arctan2(fwd, up)
        roll = np.arctan2(right, np.hypot(fwd, up))
        self.pitch_rate = (pitch - self.pitch) / dt
        self.roll_rate = (roll - self.roll) / dt
        self.pitch, self.roll = pitch, roll

        # battery: hover endurance, more when accelerating hard, idle on the ground
        load = np.where(self.landed, prm.battery_idle_fraction, 1.0 + 0.3 / G * axy)
        self.battery = np.maximum(self.battery - (armed * dt) * load / self.endurance_s, 0.0)

    def _step_scalar(self, dt: float, n: int) -> None:
        """The same equations as ``_step_vector``, per vehicle on Python floats."""
        prm = self.params
        sqrt, hypot, atan2, cos, sin = math.sqrt, math.hypot, math.atan2, math.cos, math.sin
        pi = math.pi
        kpxy, kpz, bz2, kpyaw = prm.kp_xy, prm.kp_z, self._2bz, prm.kp_yaw
        itxy, itz = 1.0 / prm.tau_vel_xy, 1.0 / prm.tau_vel_z
        drag, acc_up, acc_dn = prm.drag, prm.acc_up, prm.acc_dn
        l_alt, l_spd, idle = prm.landed_alt, prm.landed_speed, prm.battery_idle_fraction
        klag = min(1.0, dt / prm.tau_att)
        P, V, A = self.pos.tolist(), self.vel.tolist(), self.acc.tolist()
        PSP, VFF, W = self.pos_sp.tolist(), self.vel_ff.tolist(), self.wind.tolist()
        armed_l, gz_l = self.armed.tolist(), self.ground_z.tolist()
        vxy_l, vup_l, vdn_l = self.vxy_max.tolist(), self.vz_up.tolist(), self.vz_dn.tolist()
        acc_l, tilt_l, yrm_l = self.acc_hor.tolist(), self.tilt_acc.tolist(), self.yaw_rate_max.tolist()
        ysp_l, yrsp_l, yaw_l = self.yaw_sp.tolist(), self.yaw_rate_sp.tolist(), self.yaw.tolist()
        roll_l, pitch_l, bat_l = self.roll.tolist(), self.pitch.tolist(), self.battery.tolist()
        end_l = self.endurance_s.tolist()
        landed_o, rate_o, rr_o, pr_o = [], [], [], []
        for i in range(self.n):
            p0, p1, p2 = P[i]
            v0_, v1_, v2_ = V[i]
            x0, x1, x2 = A[i]
            s0, s1, s2 = PSP[i]
            f0, f1, f2 = VFF[i]
            w0, w1, w2 = W[i]
            armed, gz = armed_l[i], gz_l[i]
            vxy, vup, vdn, acch, tilt, yrm = vxy_l[i], vup_l[i], vdn_l[i], acc_l[i], tilt_l[i], yrm_l[i]
            ysp, yrsp, yaw, roll, pitch, bat = ysp_l[i], yrsp_l[i], yaw_l[i], roll_l[i], pitch_l[i], bat_l[i]
            drain = dt / end_l[i] if armed else 0.0
            landed = False
            rate = roll_rate = pitch_rate = 0.0
            if not armed and p2 >= gz and not (v0_ or v1_ or v2_ or x0 or x1 or x2 or roll or pitch):
                landed_o.append(True)  # motors off, resting on the ground: nothing changes
                rate_o.append(0.0)
                rr_o.append(0.0)
                pr_o.append(0.0)
                continue
            for _ in range(n):
                e0 = 0.0 if s0 != s0 else s0 - p0
                e1 = 0.0 if s1 != s1 else s1 - p1
                e2 = 0.0 if s2 != s2 else s2 - p2
                gxy = min(sqrt(acch / max(hypot(e0, e1), 1e-9)), kpxy)
                gzz = min(sqrt(bz2 / max(abs(e2), 1e-9)), kpz)
                c0, c1, c2 = e0 * gxy + f0, e1 * gxy + f1, e2 * gzz + f2
                s = min(vxy / max(hypot(c0, c1), 1e-9), 1.0)
                c0 *= s
                c1 *= s
                c2 = min(max(c2, -vup), vdn)
                a0, a1, a2 = (c0 - v0_) * itxy, (c1 - v1_) * itxy, (c2 - v2_) * itz
                s = min(acch / max(hypot(a0, a1), 1e-9), 1.0)
                a0 *= s
                a1 *= s
                a2 = min(max(a2, -acc_up), acc_dn)
                r0, r1, r2 = v0_ - w0, v1_ - w1, v2_ - w2
                a0 += drag * r0
                a1 += drag * r1
                a2 += drag * r2
                axy = hypot(a0, a1)
                s = min(tilt / max(axy, 1e-9), 1.0)
                a0 *= s
                a1 *= s
                axy *= s
                if armed:
                    x0, x1, x2 = x0 + (a0 - x0) * klag, x1 + (a1 - x1) * klag, x2 + (a2 - x2) * klag
                else:
                    x0, x1, x2 = 0.0, 0.0, G
                v0_ += (x0 - drag * r0) * dt
                v1_ += (x1 - drag * r1) * dt
                v2_ += (x2 - drag * r2) * dt
                p0 += v0_ * dt
                p1 += v1_ * dt
                p2 += v2_ * dt
                contact = False
                if p2 >= gz:
                    p2 = gz
                    v2_ = min(v2_, 0.0)
                    if x2 >= -1e-3:
                        v0_ = v1_ = v2_ = x0 = x1 = x2 = 0.0
                        contact = True
                landed = contact or (p2 > gz - l_alt and abs(v2_) < l_spd and x2 > -0.5)
                # heading
                if ysp == ysp:
                    rate = kpyaw * (((ysp - yaw) + pi) % _TWO_PI - pi)
                else:
                    rate = yrsp
                rate = min(max(rate, -yrm), yrm)
                if rate != rate or not armed or landed:
                    rate = 0.0
                yaw = ((yaw + rate * dt) + pi) % _TWO_PI - pi
                # attitude for telemetry
                c, sn = cos(yaw), sin(yaw)
                fwd = c * x0 + sn * x1
                right = c * x1 - sn * x0
                up = max(G - x2, 0.0)
                pt = -atan2(fwd, up)
                rl = atan2(right, hypot(fwd, up))
                pitch_rate, roll_rate = (pt - pitch) / dt, (rl - roll) / dt
                pitch, roll = pt, rl
                bat = max(bat - drain * (idle if landed else 1.0 + 0.3 / G * axy), 0.0)
            P[i], V[i], A[i] = [p0, p1, p2], [v0_, v1_, v2_], [x0, x1, x2]
            yaw_l[i], roll_l[i], pitch_l[i], bat_l[i] = yaw, roll, pitch, bat
            landed_o.append(landed)
            rate_o.append(rate)
            rr_o.append(roll_rate)
            pr_o.append(pitch_rate)
        self.pos[:] = P
        self.vel[:] = V
        self.acc[:] = A
        self.landed = np.array(landed_o, bool)
        self.yaw_rate = np.array(rate_o)
        self.yaw = np.array(yaw_l)
        self.roll, self.pitch = np.array(roll_l), np.array(pitch_l)
        self.roll_rate, self.pitch_rate = np.array(rr_o), np.array(pr_o)
        self.battery = np.array(bat_l)


_TWO_PI = 2.0 * math.pi
