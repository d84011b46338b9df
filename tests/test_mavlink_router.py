"""The agent's MAVLink router over real UDP sockets: raw forwarding, routing rules, no loops, bad input.

The routing rules are those of an open router (``UNSIGNED``, ``gcs.allow_unsigned``: every frame
routed); what a locked one refuses is tests/test_mavlink_security.py."""

from __future__ import annotations

import socket
import time

import pytest

from tests.conftest import free_port, wait_for
from uav_stack.fcu_link import FcuLink
from uav_stack.mav import mavlink
from uav_stack.mavlink_router import PROBE_EVERY_S, UNSIGNED, MavlinkRouter, SigningPolicy, parse_endpoint
from uav_stack.sysid import SHARD_SIZE, allocate_sysid, uav_of

SYSID = 7
COMPANION = (SYSID, mavlink.MAV_COMP_ID_ONBOARD_COMPUTER)


def udp(port: int = 0) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    s.settimeout(0.05)
    return s


def packer(sysid: int, compid: int) -> mavlink.MAVLink:
    return mavlink.MAVLink(None, sysid, compid)


def recv_all(s: socket.socket, wait: float = 0.3) -> list[bytes]:
    out = []
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline:
        try:
            out.append(s.recv(65535))
        except (TimeoutError, BlockingIOError):
            continue
    return out


def parse(datagrams: list[bytes]) -> list:  # noqa: ANN001
    p = mavlink.MAVLink(None)
    p.robust_parsing = True
    msgs = []
    for d in datagrams:
        msgs += [m for m in (p.parse_buffer(d) or []) if m.get_type() != "BAD_DATA"]
    return msgs


class Rig:
    """A fake FCU (a raw UDP socket) <- FcuLink + MavlinkRouter -> ground-station sockets."""

    def __init__(self, endpoints: list[str], signing: SigningPolicy = UNSIGNED):
        self.fcu = udp()
        fcu_port = self.fcu.getsockname()[1]
        self.link = FcuLink(f"udpout:127.0.0.1:{fcu_port}", source_system=SYSID)
        self.router = MavlinkRouter(endpoints, self.link.write, own=COMPANION, signing=signing).open()
        self.link.on_message = self.router.from_fcu
        self.link.open()
        self.fcu_mav = packer(SYSID, 1)
        # the FCU learns the companion's address from its first datagram (its heartbeat)
        self.link.service()
        _, self.companion_addr = self.fcu.recvfrom(65535)

    def fcu_send(self, *frames: bytes) -> None:
        self.fcu.sendto(b"".join(frames), self.companion_addr)

    def pump(self, seconds: float = 0.3) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.link.poll()
            self.router.poll()
            self.router.flush()
            time.sleep(0.01)

    def fcu_received(self, wait: float = 0.3) -> list[bytes]:
        out = []
        end = time.monotonic() + wait
        while time.monotonic() < end:
            self.pump(0.02)
            try:
                out.append(self.fcu.recv(65535))
            except (TimeoutError, BlockingIOError):
                pass
        return out

    def close(self) -> None:
        self.router.close()
        self.link.close()
        self.fcu.close()


@pytest.fixture
def gcs_port() -> int:
    return free_port(socket.SOCK_DGRAM)


def heartbeat(mav: mavlink.MAVLink, gcs: bool = False) -> bytes:
    if gcs:
        return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3).pack(mav)
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 129, 6 << 16, 4, 3).pack(mav)


def test_frames_are_forwarded_byte_for_byte_both_ways(gcs_port: int) -> None:
    gcs = udp(gcs_port)
    rig = Rig([f"udpout:127.0.0.1:{gcs_port}"])
    try:
        hb = heartbeat(rig.fcu_mav)
        pos = mavlink.MAVLink_global_position_int_message(1000, 473977420, 85455940, 500000, 12000, 1, 2, 3,
                                                          9000).pack(rig.fcu_mav)
        # a frame of a message outside our dialect (id 48879, which no dialect defines) is still routed, untouched
        unknown = bytes([0xFD, 3, 0, 0, 42, SYSID, 1, 0xEF, 0xBE, 0x00, 1, 2, 3, 0xAA, 0xBB])
        rig.fcu_send(hb, pos, unknown)
        rig.pump()
        got = b"".join(recv_all(gcs))
        assert hb in got and pos in got and unknown in got
        # and a ground station's command reaches the FCU as it was sent (its own seq and CRC)
        gmav = packer(245, 190)
        gmav.seq = 200
        cmd = mavlink.MAVLink_command_long_message(SYSID, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0).pack(gmav)
        gcs.sendto(heartbeat(gmav, gcs=True) + cmd, ("127.0.0.1", rig.router.addresses()[f"udpout:127.0.0.1:{gcs_port}"][1]))
        at_fcu = b"".join(rig.fcu_received())
        assert cmd in at_fcu
        # the FCU's answer, addressed to the GCS, goes back to it (the GCS is known now)
        ack = mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 0, 0, 245, 190).pack(rig.fcu_mav)
        rig.fcu_send(ack)
        rig.pump()
        assert ack in b"".join(recv_all(gcs))
        assert rig.router.stats.bad_datagrams == 0
        # and the companion's own FcuLink did not take the GCS's ACK for one of its commands
        assert not rig.link.pending
    finally:
        rig.close()
        gcs.close()


def test_routing_rules_addressed_to_us_unknown_targets_and_loops(gcs_port: int) -> None:
    gcs = udp(gcs_port)
    rig = Rig([f"udpout:127.0.0.1:{gcs_port}"])
    st = rig.router.stats
    router_addr = ("127.0.0.1", rig.router.addresses()[f"udpout:127.0.0.1:{gcs_port}"][1])
    try:
        rig.fcu_send(heartbeat(rig.fcu_mav))
        rig.pump()
        recv_all(gcs)
        # addressed to a GCS nobody has heard yet: dropped, not sprayed
        early = mavlink.MAVLink_command_ack_message(400, 0, 0, 0, 255, 190).pack(rig.fcu_mav)
        # addressed to the companion (the agent): stays in the agent
        to_us = mavlink.MAVLink_command_ack_message(400, 0, 0, 0, *COMPANION).pack(rig.fcu_mav)
        rig.fcu_send(early, to_us)
        rig.pump()
        got = b"".join(recv_all(gcs))
        assert early not in got and to_us not in got
        assert st.dropped_unknown_target >= 1 and st.dropped_for_us >= 1
        # a GCS echoing the FCU's own frame back (a loop) never reaches the FCU again
        echo = heartbeat(rig.fcu_mav)
        gcs.sendto(echo, router_addr)
        # a GCS frame for another vehicle (sysid 99, not behind this router) is dropped
        other = mavlink.MAVLink_command_long_message(99, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(packer(255, 190))
        gcs.sendto(other, router_addr)
        at_fcu = b"".join(rig.fcu_received())
        assert echo not in at_fcu and other not in at_fcu
        assert st.spoofed_own_id == 1 and st.dropped_unknown_target >= 2
        # garbage, then a valid frame in its own datagram: counted, never a crash, the frame still routes
        gcs.sendto(b"\xfd\xff\x00garbage" * 20, router_addr)
        good = heartbeat(packer(255, 190), gcs=True)
        gcs.sendto(good, router_addr)
        at_fcu = b"".join(rig.fcu_received())
        assert good in at_fcu and st.bad_datagrams == 1
    finally:
        rig.close()
        gcs.close()


def test_two_ground_stations_no_echo_and_server_endpoint(gcs_port: int) -> None:
    listen = free_port(socket.SOCK_DGRAM)
    gcs1 = udp(gcs_port)
    rig = Rig([f"udpout:127.0.0.1:{gcs_port}", f"udpin:127.0.0.1:{listen}"])
    gcs2 = udp()
    try:
        # the server endpoint stays silent until a ground station speaks to it
        rig.fcu_send(heartbeat(rig.fcu_mav))
        rig.pump()
        assert b"".join(recv_all(gcs1)) and not recv_all(gcs2, 0.1)
        hb2 = heartbeat(packer(200, 190), gcs=True)
        gcs2.sendto(hb2, ("127.0.0.1", listen))
        rig.pump()
        rig.fcu_send(heartbeat(rig.fcu_mav))
        rig.pump()
        got2 = b"".join(recv_all(gcs2))
        assert any(m.get_srcSystem() == SYSID for m in parse([got2]))  # the FCU stream now reaches it
        # GCS 2's broadcast heartbeat went to the FCU and to GCS 1, never back to GCS 2
        got1 = b"".join(recv_all(gcs1))
        assert hb2 in got1 and hb2 not in got2
    finally:
        rig.close()
        gcs1.close()
        gcs2.close()


def test_ground_station_motion_commands_are_noted_as_a_takeover(gcs_port: int) -> None:
    gcs = udp(gcs_port)
    rig = Rig([f"udpout:127.0.0.1:{gcs_port}"])
    addr = ("127.0.0.1", rig.router.addresses()[f"udpout:127.0.0.1:{gcs_port}"][1])
    g = packer(255, 190)
    try:
        rig.fcu_send(heartbeat(rig.fcu_mav))
        rig.pump()
        request = mavlink.MAVLink_command_long_message(SYSID, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0)
        gcs.sendto(request.pack(g), addr)
        rig.pump()
        assert rig.router.takeover is None  # asking for data is not taking over
        gcs.sendto(mavlink.MAVLink_set_mode_message(SYSID, 1, 4 << 16 | 5 << 24).pack(g), addr)
        rig.pump()
        assert rig.router.takeover is not None and rig.router.takeover[1] == "SET_MODE"
        rig.router.takeover = None
        reposition = mavlink.MAVLink_command_int_message(SYSID, 1, 6, mavlink.MAV_CMD_DO_REPOSITION, 0, 0, -1, 1, 0, 0, 473977420,
                                                         85455940, 20).pack(g)
        gcs.sendto(reposition, addr)
        rig.pump()
        assert rig.router.takeover is not None and rig.router.takeover[1] == "DO_REPOSITION"
    finally:
        rig.close()
        gcs.close()


def test_sysid_shards_and_endpoint_specs() -> None:
    assert allocate_sysid(1) == (0, 1)
    assert allocate_sysid(240) == (0, 240)
    assert allocate_sysid(241) == (1, 1)
    assert allocate_sysid(1000) == (4, 40)
    assert allocate_sysid(65535)[1] <= SHARD_SIZE
    sysids = {allocate_sysid(u) for u in range(1, 2001)}
    assert len(sysids) == 2000  # unique per (network, sysid) for any swarm size
    assert all(s <= 240 for _, s in sysids)  # 241..255 stay free for ground stations (MAVSDK 245, QGC 255)
    assert all(uav_of(*allocate_sysid(u)) == u for u in (1, 240, 241, 4242, 65535))
    for bad in (0, 65536, -3):
        with pytest.raises(ValueError):
            allocate_sysid(bad)
    assert parse_endpoint("udpout:127.0.0.1:14550") == ("udpout", "127.0.0.1", 14550)
    for bad_spec in ("udp:1.2.3.4:14550", "udpout:host", "udpout:h:notaport", "udpout:h:0", "tcp:h:5760", "udpin::14550"):
        with pytest.raises(ValueError):
            parse_endpoint(bad_spec)


def test_router_survives_a_flood_of_random_bytes(gcs_port: int) -> None:
    import random

    gcs = udp(gcs_port)
    rig = Rig([f"udpout:127.0.0.1:{gcs_port}"])
    addr = ("127.0.0.1", rig.router.addresses()[f"udpout:127.0.0.1:{gcs_port}"][1])
    rnd = random.Random(5)
    try:
        for _ in range(300):
            data = bytes(rnd.randrange(256) for _ in range(rnd.randrange(1, 300)))
            if rnd.random() < 0.3:
                data = b"\xfd" + data
            gcs.sendto(data, addr)
        rig.pump(0.5)
        good = heartbeat(packer(255, 190), gcs=True)
        gcs.sendto(good, addr)
        assert wait_for(lambda: good in b"".join(rig.fcu_received(0.1)), 3.0)
        assert rig.router.stats.bad_datagrams > 200
    finally:
        rig.close()
        gcs.close()


def test_a_taken_ground_station_port_is_an_error_that_names_the_endpoint_and_opens_nothing() -> None:
    """Another process holds the udpin port: the router opens none of its endpoints (the free one
    is released again) and says which setting and endpoint to change."""
    from uav_stack.fcu_link import LinkOpenError

    holder = udp()
    taken = holder.getsockname()[1]
    free = free_port(socket.SOCK_DGRAM)
    router = MavlinkRouter([f"udpin:127.0.0.1:{free}", f"udpin:127.0.0.1:{taken}"], lambda _b: None, own=COMPANION,
                           signing=UNSIGNED)
    try:
        with pytest.raises(LinkOpenError, match=rf"gcs\.mavlink_endpoints: udpin:127\.0\.0\.1:{taken}: cannot listen on "
                                                rf"127\.0\.0\.1:{taken}: Address already in use"):
            router.open()
        assert router.addresses() == {}
        udp(free).close()  # the endpoint that did open is closed again: its port is free
        # the process that holds the port keeps it, and gets its own traffic
        udp().sendto(b"mine", ("127.0.0.1", taken))
        assert holder.recv(64) == b"mine"
    finally:
        holder.close()
        router.close()


def test_a_ground_station_that_is_not_running_gets_a_datagram_a_second_until_it_listens(gcs_port: int) -> None:
    """Every UAV routes to a ground-station port by default, whether or not one runs there. While
    the port refuses (ICMP port unreachable), the router sends one datagram a second, not one a
    tick; QGroundControl started later sees the UAV within about a second, then gets every frame."""
    rig = Rig([f"udpout:127.0.0.1:{gcs_port}"])
    gcs = None
    try:
        hb = heartbeat(rig.fcu_mav)
        end = time.monotonic() + 3.0
        ticks = 0
        while time.monotonic() < end:  # 3 s of a 20 Hz FCU stream, nobody at the port
            rig.fcu_send(hb)
            rig.pump(0.05)
            ticks += 1
        st = rig.router.stats
        assert ticks >= 40 and st.datagrams_out <= 5, (ticks, st)  # the first, then about one a second
        assert st.unheard >= ticks - 10 and st.bad_datagrams == 0

        gcs = udp(gcs_port)  # the ground station starts
        gcs.setblocking(False)
        t0 = time.monotonic()
        arrivals = []
        while time.monotonic() - t0 < 3.0:
            rig.fcu_send(hb)
            rig.pump(0.05)
            while True:
                try:
                    data = gcs.recv(65535)
                except BlockingIOError:
                    break
                assert hb in data
                arrivals.append(time.monotonic() - t0)
        assert arrivals and arrivals[0] < PROBE_EVERY_S + 0.3, arrivals[:3]
        last_second = [t for t in arrivals if t >= 2.0]
        assert len(last_second) >= 15, len(last_second)  # the whole 20 Hz stream again
    finally:
        rig.close()
        if gcs is not None:
            gcs.close()
