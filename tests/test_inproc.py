"""The in-process datagram link (``inproc:<name>``, uav_stack/inproc.py): a pooled UAV's agent and
its vehicle of the pool's virtual FCU exchange the same MAVLink datagrams as over UDP, through
bounded queues. Every wait is bounded."""

from __future__ import annotations

import errno
import socket
import time
from collections.abc import Callable

import pytest

from uav_stack import inproc
from uav_stack.config import AgentConfig, GcsConfig
from uav_stack.fcu.config import FcuConfig, VehicleConfig
from uav_stack.fcu.fcu import VirtualFcu
from uav_stack.fcu.link import InprocLink
from uav_stack.fcu_link import FcuLink, LinkOpenError
from uav_stack.geo import GeoPoint
from uav_stack.mav import mavlink
from uav_stack.runtime import open_fcu_link

HOME = GeoPoint(47.397742, 8.545594, 488.0)


# ---- the transport ------------------------------------------------------------------------------
def test_a_queue_is_bounded_drops_the_newest_and_counts_it() -> None:
    q = inproc.DatagramQueue(3)
    for i in range(5):
        q.put(bytes([i]))
    assert len(q) == 3 and (q.datagrams, q.dropped, q.bytes) == (3, 2, 3)
    assert q.take(2) == [b"\x00", b"\x01"]  # oldest first, boundaries kept
    q.put(b"\x05")
    assert q.take(10) == [b"\x02", b"\x05"] and q.take(10) == []
    assert q.as_dict() == {"datagrams": 4, "bytes": 4, "dropped": 2, "queued": 0}
    with pytest.raises(ValueError):
        inproc.DatagramQueue(0)


def test_a_channel_carries_datagrams_both_ways_with_each_senders_address() -> None:
    name = inproc.unique_name("t")
    ch = inproc.listen(name, capacity=4)
    try:
        agent = inproc.connect(name)
        fcu = ch.listener
        assert fcu.address == (f"inproc:{name}", 0) and agent.address == (f"inproc:{name}", 1)
        assert agent.peer == fcu.address and fcu.peer == agent.address
        assert agent.sendto(b"hb", fcu.address) and agent.sendto(b"cmd", fcu.address)
        assert fcu.recvfrom_all() == [(b"hb", agent.address), (b"cmd", agent.address)]
        assert fcu.recvfrom_all() == []
        for i in range(6):  # the agent does not read: the FCU's datagrams beyond the bound are dropped
            assert fcu.sendto(bytes([i]), agent.address)
        assert [d for d, _ in agent.recvfrom_all(3)] == [b"\x00", b"\x01", b"\x02"]  # at most what was asked
        assert [d for d, _ in agent.recvfrom_all()] == [b"\x03"]
        assert ch.as_dict() == {"name": name, "to_fcu": {"datagrams": 2, "bytes": 5, "dropped": 0, "queued": 0},
                                "to_agent": {"datagrams": 4, "bytes": 4, "dropped": 2, "queued": 0}}
        assert not fcu.sendto(b"x", ("inproc:elsewhere", 1)) and not fcu.sendto(b"x", ("127.0.0.1", 14550))
        assert ch.to_connector.datagrams == 4  # nothing queued for an address that is not the peer's
    finally:
        ch.listener.close()


def test_names_are_taken_refused_and_freed_as_ports_are() -> None:
    name = inproc.unique_name("t")
    with pytest.raises(OSError) as refused:
        inproc.connect(name)
    assert refused.value.errno == errno.ECONNREFUSED
    ch = inproc.listen(name)
    with pytest.raises(OSError) as taken:
        inproc.listen(name)
    assert taken.value.errno == errno.EADDRINUSE
    end = inproc.connect(name)
    with pytest.raises(OSError) as second:  # a link has two ends
        inproc.connect(name)
    assert second.value.errno == errno.EISCONN
    assert inproc.is_listening(name)
    ch.listener.close()
    assert not inproc.is_listening(name)
    assert not end.sendto(b"x", end.peer) and ch.to_listener.datagrams == 0  # to a closed end: goes nowhere
    inproc.listen(name).listener.close()  # free again
    with pytest.raises(ValueError):
        inproc.listen("a:b")


def test_a_closed_end_reads_nothing_and_what_was_queued_for_it_is_gone() -> None:
    name = inproc.unique_name("t")
    ch = inproc.listen(name)
    agent = inproc.connect(name)
    assert ch.listener.sendto(b"telemetry", agent.address)
    agent.close()
    agent.close()  # twice is fine
    assert agent.recvfrom_all() == [] and len(ch.to_connector) == 0
    assert not ch.listener.sendto(b"more", agent.address) and not agent.sendto(b"late", agent.peer)
    ch.listener.close()


def test_inproc_urls_are_parsed_and_a_configured_agent_cannot_ask_for_one() -> None:
    from uav_stack.config import fcu_url_problem

    assert inproc.parse_inproc_url("inproc:fcu.3") == "fcu.3"
    assert inproc.parse_inproc_url("udpout:127.0.0.1:14540") is None
    with pytest.raises(ValueError):
        inproc.parse_inproc_url("inproc:")
    # only a pool wires one (its FCU is in the agent's process); an agent's configuration cannot name one
    assert "unknown scheme" in fcu_url_problem("inproc:fcu.3")


# ---- the FCU link over it -----------------------------------------------------------------------
def _fcu(n: int = 1) -> VirtualFcu:
    fcu = VirtualFcu(FcuConfig(vehicles=[VehicleConfig(sysid=i + 1, home=HOME, inproc=True) for i in range(n)]))
    fcu.open()
    return fcu


def _pump(fcu: VirtualFcu, links: list[FcuLink], until: Callable[[], bool], timeout: float = 8.0,
          between: Callable[[], None] | None = None) -> bool:
    """The pool's loop in small: the FCU's datagrams and physics, every link's, until ``until`` or ``timeout``."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        fcu.poll_io()
        fcu.service()
        for link in links:
            link.poll()
            link.service()
        if between is not None:
            between()
        fcu.poll_io()
        if until():
            return True
        time.sleep(0.01)
    return False


def test_an_agents_fcu_link_flies_its_vehicle_over_the_in_process_link() -> None:
    fcu = _fcu()
    v = fcu.vehicles[0]
    assert isinstance(v.link, InprocLink) and v.link.fileno() == -1 and fcu.fds() == []
    assert v.link.url.startswith("inproc:")
    link = FcuLink(v.link.url, source_system=1, target_system=1).open()
    try:
        assert link.local_address is not None
        v.link.set_owner(link.local_address, owner_only=True)  # as open_virtual_uav does
        assert _pump(fcu, [link], lambda: link.connected and v.gps_ok and link.state.has_position)
        assert link.fcu_ids == (1, 1) and link.counts["foreign_source"] == 0 and link.counts["bad"] == 0
        h = link.arm()
        assert _pump(fcu, [link], lambda: h.done) and h.accepted and v.armed
        st = fcu.stats
        assert st.datagrams_in > 0 and st.datagrams_out > 0 and st.send_errors == 0 and st.foreign_datagrams == 0
        ch = v.link.channel
        assert ch is not None
        assert ch.to_connector.dropped == 0 and ch.to_listener.dropped == 0 and ch.to_listener.datagrams == st.datagrams_in
    finally:
        link.close()
        fcu.close()
    assert not inproc.is_listening(ch.name)  # the FCU's close frees the name


def test_an_agent_that_does_not_read_loses_the_fcus_datagrams_beyond_the_bound_counted() -> None:
    fcu = VirtualFcu(FcuConfig(vehicles=[VehicleConfig(sysid=1, home=HOME, inproc=True)], coalesce_datagrams=False))
    fcu.open()
    v = fcu.vehicles[0]
    link = FcuLink(v.link.url, source_system=1, target_system=1).open()
    try:
        ch = v.link.channel
        assert ch is not None
        link.service()  # its heartbeat: the vehicle learns its peer and streams to it
        end = time.monotonic() + 8.0
        while ch.to_connector.dropped == 0 and time.monotonic() < end:  # nobody reads the agent's end
            fcu.poll_io()
            fcu.service()
            time.sleep(0.01)
        assert ch.to_connector.dropped > 0 and len(ch.to_connector) == ch.to_connector.capacity
        assert link.poll() > 0 and link.counts["bad"] == 0  # what was queued is whole
    finally:
        link.close()
        fcu.close()


def test_a_link_to_no_in_process_fcu_is_refused_with_the_setting_named() -> None:
    with pytest.raises(LinkOpenError, match=r"fcu: inproc:nobody\.1: cannot connect to the in-process FCU"):
        FcuLink("inproc:nobody.1").open()


def test_a_cut_link_in_a_pool_loses_that_vehicles_datagrams_only() -> None:
    from uav_stack.pool import PooledFcu
    from uav_stack.sim_faults import SimFaults

    fcu = _fcu(2)
    links = [FcuLink(v.link.url, source_system=v.sysid, target_system=v.sysid).open() for v in fcu.vehicles]
    try:
        faults = [SimFaults(fcu, 0, i) for i in range(2)]
        pooled = PooledFcu(fcu, faults)
        faults[0].link_cut_until = time.time() + 60.0
        pooled.service(time.time())
        assert faults[0].cut and not faults[1].cut
        for link in links:
            link.service()  # a heartbeat each
        pooled.poll_io()
        assert faults[0].dropped_datagrams == 1 and fcu.stats.datagrams_in == 1
        assert fcu.vehicles[1].link.peers and not fcu.vehicles[0].link.peers
    finally:
        for link in links:
            link.close()
        fcu.close()


def test_a_pooled_uavs_ground_station_endpoint_reaches_its_vehicle_through_the_in_process_link() -> None:
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.setblocking(False)
    port = gcs.getsockname()[1]
    fcu = _fcu()
    v = fcu.vehicles[0]
    agent = AgentConfig(swarm="t", uav=1, origin=HOME, fcu="udpout:127.0.0.1:9",
                        gcs=GcsConfig(mavlink_endpoints=(f"udpout:127.0.0.1:{port}",), allow_unsigned=True, sysid=1))
    link, router = open_fcu_link(agent, v.link.url, target_system=1)
    assert router is not None and link.local_address is not None
    v.link.set_owner(link.local_address, owner_only=True)
    got: dict[str, list[mavlink.MAVLink_message]] = {}
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    mav = mavlink.MAVLink(None, 255, 190)

    def gcs_side() -> None:
        router.poll()
        router.flush()
        while True:
            try:
                data = gcs.recv(65535)
            except BlockingIOError:
                return
            for m in parser.parse_buffer(data) or []:
                got.setdefault(m.get_type(), []).append(m)

    try:
        # the vehicle's telemetry reaches the ground station through the agent's router
        assert _pump(fcu, [link], lambda: "HEARTBEAT" in got and "GLOBAL_POSITION_INT" in got and v.gps_ok,
                     between=gcs_side)
        assert all(m.get_srcSystem() == 1 for m in got["HEARTBEAT"] if m.get_srcComponent() == 1)
        # and its command reaches the vehicle, whose answer comes back to it
        gcs.sendto(mav.command_long_encode(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav),
                   router.endpoints[0].address)
        assert _pump(fcu, [link], lambda: any(a.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM
                                              for a in got.get("COMMAND_ACK", [])), between=gcs_side)
        assert v.armed
    finally:
        router.close()
        link.close()
        fcu.close()
        gcs.close()
