"""Two swarms on one discovery server, a ground station in both, and an intruder with a wrong key,
each on its own host of a routed namespace topology (real processes, real Zenoh).

Gossip is off in discovery mode, so the ground station, linked to both swarms, cannot hand
one swarm's addresses to the other; the server relays only within a swarm; a beacon with
the wrong key is dropped before anything in it is read.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.discovery_lab import SwarmLab

KEYS = {"alpha": "isolation-alpha-key-0123456789", "beta": "isolation-beta-key-01234567890",
        "wrong": "isolation-wrong-key-0123456789"}
ALPHA = ["a1", "a2", "a3", "a4"]
BETA = ["b1", "b2", "b3", "b4"]

pytestmark = pytest.mark.netns


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SwarmLab]:
    with SwarmLab(Path(tmp_path_factory.mktemp("isolation")), ALPHA + BETA + ["g", "x"], KEYS, second_octet=67) as lab:
        lab.start_server()
        for i, h in enumerate(ALPHA, 1):
            lab.start_probe(h, h, "alpha", i)
        for i, h in enumerate(BETA, 1):
            lab.start_probe(h, h, "beta", i)  # the same UAV ids as alpha: swarms are separate namespaces
        lab.start_probe("g", "g", "alpha", 1, role="gcs", extra_swarms=("beta",))
        lab.start_probe("x", "x", "alpha", 99, key_file=lab.key_files["wrong"])  # claims alpha, wrong key
        yield lab


def test_two_swarms_stay_isolated_and_the_gcs_sees_both(lab: SwarmLab) -> None:
    names = ALPHA + BETA + ["g", "x"]

    def meshed(st: dict) -> bool:
        z = {n: s["zid"] for n, s in st.items()}
        return (all(set(st[n]["peers"]) == {z[m] for m in ALPHA + ["g"] if m != n} for n in ALPHA)
                and all(set(st[n]["peers"]) == {z[m] for m in BETA + ["g"] if m != n} for n in BETA)
                and set(st["g"]["peers"]) == {z[m] for m in ALPHA + BETA})

    st = lab.wait_status(names, meshed, 30.0)
    assert meshed(st), {n: len(s["peers"]) for n, s in st.items()}
    time.sleep(3.0)  # several beacon rounds and pose exchanges later, nothing has leaked
    st = lab.statuses(names)
    z = {n: s["zid"] for n, s in st.items()}
    assert meshed(st)
    for n in ALPHA:
        assert set(st[n]["per_swarm"]) == {"alpha"}, st[n]["per_swarm"]  # not one sample of beta's traffic
        assert not {z[b] for b in BETA} & (set(st[n]["peers"]) | set(st[n]["lost"]))  # never linked, not even briefly
        assert st[n]["discovery"]["members"] == {"alpha": sorted(["gcs1"] + [f"uav{i}" for i in range(1, 5) if f"a{i}" != n])}
    for n in BETA:
        assert set(st[n]["per_swarm"]) == {"beta"}, st[n]["per_swarm"]
        assert not {z[a] for a in ALPHA} & (set(st[n]["peers"]) | set(st[n]["lost"]))
    rx = st["g"]["rx"]
    assert all(rx.get(f"{s}/{i}", {}).get("n", 0) >= 20 for s in ("alpha", "beta") for i in range(1, 5)), rx


def test_a_node_with_the_wrong_key_is_never_listed_nor_connected(lab: SwarmLab) -> None:
    names = ALPHA + BETA + ["g", "x"]
    st = lab.wait_status(names, lambda st: len(st["g"]["peers"]) == 8, 30.0)
    time.sleep(2.0)
    st = lab.statuses(names)
    x = st["x"]
    assert x["peers"] == {} and x["lost"] == {} and x["per_swarm"] == {}
    assert all(x["zid"] not in s["peers"] and x["zid"] not in s["lost"] for n, s in st.items() if n != "x")
    assert x["discovery"]["server_contact_age"] is None  # the server never answered it
    assert x["discovery"]["stats"]["beacons"] >= 2
    nodes, stats = lab.query("alpha")
    assert ("uav", 99) not in {(n["role"], n["node"]) for n in nodes}
    assert sorted((n["role"], n["node"]) for n in nodes) == [("gcs", 1)] + [("uav", i) for i in range(1, 5)]
    assert stats["drop_bad_mac"] >= x["discovery"]["stats"]["beacons"] - 1
