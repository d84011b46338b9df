"""Joining a swarm whose router is not up yet: the session opens once it is (bounded), other errors at once."""

from __future__ import annotations

import socket
import threading
import time

import pytest
import zenoh

from discovery.proxy import BeaconDiscovery
from discovery.rendezvous import serve
from swarmnet.connectivity import Rendezvous, open_retrying, to_zenoh
from tests.conftest import free_port


def test_a_client_joins_a_router_that_starts_late() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = Rendezvous((endpoint,), mode="client").zenoh_config()
    stop = threading.Event()
    late = threading.Timer(1.5, lambda: serve([endpoint], stop))  # the router comes up 1.5 s after the first try
    late.daemon = True
    t0 = time.monotonic()
    late.start()
    try:
        with pytest.raises(zenoh.ZError):  # without retries: refused at once
            zenoh.open(to_zenoh(cfg)).close()
        session = open_retrying(lambda: zenoh.open(to_zenoh(cfg)), 20.0, "test client")
        try:
            assert time.monotonic() - t0 >= 1.5  # it waited for the router, and then got in
            session.put("t/x", b"1")  # a usable session
        finally:
            session.close()
    finally:
        late.cancel()
        stop.set()


def test_it_gives_up_after_its_timeout_with_zenohs_error() -> None:
    cfg = Rendezvous((f"tcp/127.0.0.1:{free_port()}",), mode="client").zenoh_config()  # nobody ever listens
    t0 = time.monotonic()
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        open_retrying(lambda: zenoh.open(to_zenoh(cfg)), 2.0, "test client")
    assert time.monotonic() - t0 < 10.0  # bounded: 2 s of retries plus Zenoh's own connect timeouts


def test_a_discovery_node_whose_scouting_port_is_taken_meanwhile_picks_another() -> None:
    """Another process takes the free loopback port the discovery proxy picked, before Zenoh binds it
    (50 UAVs starting at once did): the open is tried again with a fresh port, and the UAV joins."""
    bd = BeaconDiscovery(server="127.0.0.1:9", key="test-key-0123456789abcdef", swarm="s", node=1, role="uav", lanes=1)
    squatters: list[socket.socket] = []

    def open_once() -> zenoh.Session:
        cfg = bd.zenoh_config()
        if not squatters:  # the first pick is taken between the pick and Zenoh's bind
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", bd.scout_port))
            squatters.append(s)
        return zenoh.open(to_zenoh(cfg))

    try:
        session = open_retrying(open_once, 10.0, "test uav")
        try:
            taken = squatters[0].getsockname()[1]
            assert bd.scout_port != taken  # it scouts on a port of its own
            session.put("t/x", b"1")  # a usable session
        finally:
            session.close()
    finally:
        for s in squatters:
            s.close()
