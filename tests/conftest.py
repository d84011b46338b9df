"""Shared fixtures: everything on 127.0.0.1, ephemeral ports, cleaned up afterwards."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator

import pytest

from discovery.netutil import free_port  # the tests import it from here
from discovery.rendezvous import serve
from swarmnet.connectivity import Rendezvous


def wait_for(pred: Callable[[], bool], timeout: float, period: float = 0.02) -> bool:
    """Poll ``pred`` until it is true or ``timeout`` passes (bounded, never forever)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(period)
    return pred()


@pytest.fixture
def router() -> Iterator[str]:
    """A Zenoh rendezvous router on 127.0.0.1 running in this process; yields its endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    stop = threading.Event()
    th = threading.Thread(target=serve, args=([endpoint], stop), daemon=True)
    th.start()
    time.sleep(0.6)  # a router's open() always waits scouting.delay (0.5 s)
    yield endpoint
    stop.set()
    th.join(5)


@pytest.fixture
def rendezvous(router: str) -> Rendezvous:
    return Rendezvous((router,))
