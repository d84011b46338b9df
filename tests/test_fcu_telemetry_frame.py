"""The virtual FCU's GLOBAL_POSITION_INT framed by compiled code (uav_stack/fcu/_telemetry.c)
is the frame the Python encoder and pymavlink make, byte for byte, whatever the state; and the
FCU's stream of it parses on a real MAVLink-over-UDP link as the position flown."""

from __future__ import annotations

import math
import random
import socket
import time

import pytest

from uav_stack.fcu import FcuConfig, VehicleConfig, VirtualFcu
from uav_stack.fcu import telemetry as T
from uav_stack.geo import GeoPoint, LocalFrame
from uav_stack.mav import mavlink
from uav_stack.mavcodec import pack

pytestmark = pytest.mark.skipif(T.TELEMETRY != "compiled", reason="the compiled framer was not built (no C compiler at install)")

HOMES = [GeoPoint(47.397742, 8.545594, 488.0), GeoPoint(-33.9, 151.2, 5.0), GeoPoint(89.9999, -179.9, 3000.0),
         GeoPoint(0.0, 0.0, 0.0), GeoPoint(-89.99999, 179.99999, -50.0)]


def _fcu(home: GeoPoint) -> VirtualFcu:
    fcu = VirtualFcu(FcuConfig(vehicles=[VehicleConfig(sysid=7, home=home, listen=("127.0.0.1", 0))]))
    fcu.open()
    fcu.vehicles[0].finish_boot()  # booted: the position is valid from the start
    return fcu


def _value(rng: random.Random, scale: float) -> float:
    r = rng.random()
    if r < 0.03:
        return rng.choice([math.nan, math.inf, -math.inf, 0.0, -0.0])
    if r < 0.08:
        return rng.choice([1.0, -1.0]) * rng.choice([1e12, 3.3e5, 327.675, 327.665, 21474.8365])  # bounds and halves
    return rng.uniform(-scale, scale)


@pytest.mark.parametrize("home", HOMES, ids=lambda h: f"{h.lat:g},{h.lon:g}")
def test_compiled_frame_is_the_python_frame(home: GeoPoint) -> None:
    fcu = _fcu(home)
    try:
        v, d = fcu.vehicles[0], fcu.dyn
        rng = random.Random(hash((home.lat, home.lon)) & 0xFFFF)
        for k in range(1500):
            d.pos[0] = [_value(rng, 5000.0), _value(rng, 5000.0), _value(rng, 300.0)]
            d.vel[0] = [_value(rng, 40.0), _value(rng, 40.0), _value(rng, 10.0)]
            d.yaw[0] = _value(rng, 20.0)
            v.position_error = (0.0, 0.0, 0.0) if k % 3 else (_value(rng, 50.0), _value(rng, 50.0), _value(rng, 5.0))
            v.home = GeoPoint(home.lat, home.lon, home.alt + _value(rng, 100.0))
            fcu.clock.steps += 1  # a new step: the geodetic cache is computed anew
            fcu.clock.sim_time = rng.choice([0.0, 0.0005, 12.3456, 4294967.2955, 1e7 * rng.random()])
            v.mav.seq = k & 0xFF
            frame = T.global_position_int_frame(v)
            msg = T.global_position_int(v)
            assert msg is not None and frame is not None
            assert frame == pack(msg, v.mav), (k, d.pos[0], d.vel[0], d.yaw[0], v.position_error)
    finally:
        fcu.close()


def test_no_frame_before_the_fix_nor_on_a_signing_link() -> None:
    fcu = VirtualFcu(FcuConfig(vehicles=[VehicleConfig(sysid=7, home=HOMES[0], listen=("127.0.0.1", 0))]))
    fcu.open()
    try:
        v = fcu.vehicles[0]  # booting: PX4 has no position estimate yet
        assert T.global_position_int_frame(v) is None and T.global_position_int(v) is None
        v.finish_boot()
        assert T.global_position_int_frame(v) is not None
        v.mav.signing.sign_outgoing = True  # a signed link: the Python path signs
        assert T.global_position_int_frame(v) is None
    finally:
        fcu.close()


def test_the_stream_flies_to_a_ground_station_as_the_position_flown() -> None:
    """Over real UDP: the FCU's GLOBAL_POSITION_INT stream, now framed by compiled code, parses in
    pymavlink as the vehicle's position, at PX4's rate, with consecutive sequence numbers."""
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.2)
    home = HOMES[0]
    fcu = VirtualFcu(FcuConfig(vehicles=[VehicleConfig(sysid=7, home=home, listen=("127.0.0.1", 0),
                                                       remotes=(gcs.getsockname(),))]))
    fcu.open()
    try:
        v, d = fcu.vehicles[0], fcu.dyn
        v.finish_boot()
        d.pos[0] = [30.0, -40.0, 0.0]  # 30 m north, 40 m west, on the ground (disarmed: it stays)
        parser = mavlink.MAVLink(None)
        got = []
        end = time.monotonic() + 1.5
        while time.monotonic() < end and len(got) < 12:
            fcu.service()
            try:
                data = gcs.recv(65535)
            except TimeoutError:
                continue
            got += [m for m in (parser.parse_buffer(data) or []) if m.get_type() == "GLOBAL_POSITION_INT"]
        assert len(got) >= 10
        lat, lon, alt = LocalFrame(home).to_geodetic(-40.0, 30.0, 0.0)
        for m in got:
            assert m.get_srcSystem() == 7
            assert abs(m.lat - lat * 1e7) <= 1 and abs(m.lon - lon * 1e7) <= 1 and abs(m.alt - alt * 1000) <= 1
        seqs = [m.get_seq() for m in got]
        assert all((b - a) % 256 >= 1 for a, b in zip(seqs, seqs[1:], strict=False))  # in order (others between)
        assert fcu.stats.as_dict()["telemetry"] == "compiled"
    finally:
        fcu.close()
        gcs.close()
