"""`mrswarm gcs web`'s server on a real router and a real UAV node: who may connect, and bad commands.

The page itself, in headless Chromium during a live 10-UAV run, is tested in tests/test_recording_e2e.py.
"""

from __future__ import annotations

import asyncio
import http.client
import json
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from mrswarm.gcs.web.server import WebMap
from swarmnet.connectivity import Rendezvous
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.observer import SwarmObserver
from tests.conftest import free_port, router, wait_for  # noqa: F401 (router is a fixture)
from uav_stack.recorder import TrajectoryRecorder

ROOT = Path(__file__).resolve().parents[1]


def run_folder(run_dir: Path) -> Path:
    """A run folder as `mrswarm run` leaves it mid-flight: the wildfire scenario, and UAV 1's first 20 s flown
    east along y = 50 at 5 m/s (the trail a page opened now must still show)."""
    run_dir.mkdir()
    shutil.copy(ROOT / "scenarios" / "wildfire.yaml", run_dir / "scenario.yaml")
    rec = TrajectoryRecorder(run_dir / "uav1.csv")
    for k in range(200):
        t = 1000.0 + 0.1 * k
        rec.write(t, (t, t, -25.0 + 0.5 * k, 50.0, 15.0, 5.0, 0.0, 0.0, 0.0, "mission", "OFFBOARD", 1, 1.0))
    rec.close()
    return run_dir


@pytest.fixture
def web(router: str, tmp_path: Path) -> Iterator[tuple[int, SwarmNode]]:  # noqa: F811
    uav = SwarmNode(NodeIdentity("webt", 1), Rendezvous((router,), mode="client")).open()
    obs = SwarmObserver("webt", Rendezvous((router,), mode="client"), role="gcs", name="web").open()
    port = free_port()
    wm = WebMap(obs, "127.0.0.1", port, run_folder(tmp_path / "run"))
    stop = threading.Event()

    def pump() -> None:  # the UAV publishes and acks while the test runs
        while not stop.is_set():
            if uav.pose_due(time.time()):
                uav.publish_pose(t_sim=0.0, x=3.0, y=4.0, z=5.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0)
                uav.publish_state("hover", "coverage")
            for c in uav.poll().commands:
                uav.ack(c.cmd_id, True, f"{c.verb} ok")
            time.sleep(0.02)

    th = threading.Thread(target=lambda: asyncio.run(wm.run(duration=25.0)), daemon=True)
    pu = threading.Thread(target=pump, daemon=True)
    th.start()
    pu.start()
    assert wait_for(lambda: 1 in obs.alive_uavs() and 1 in obs.uavs, 10.0)
    yield port, uav
    stop.set()
    wm.stopping = True
    pu.join(5)
    th.join(10)
    obs.close()
    uav.close()


def _get(port: int, path: str, host: str) -> tuple[int, bytes, dict[str, str]]:
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    c.request("GET", path, headers={"Host": host})
    r = c.getresponse()
    return r.status, r.read(), dict(r.getheaders())


def test_the_page_is_served_to_loopback_names_only_and_its_socket_to_its_own_page_only(web: tuple[int, SwarmNode]) -> None:
    port, _ = web
    status, body, headers = _get(port, "/", f"127.0.0.1:{port}")
    assert status == 200 and b"map.js" in body and headers["Content-Type"].startswith("text/html")
    assert b"http://" not in body and b"https://" not in body  # no external asset
    assert _get(port, "/map.js", f"localhost:{port}")[0] == 200
    assert _get(port, "/", f"evil.example:{port}")[0] == 403  # DNS rebinding
    assert _get(port, "/../pyproject.toml", f"127.0.0.1:{port}")[0] == 404

    async def talk() -> list[dict]:
        with pytest.raises(InvalidStatus):  # another site's page in the same browser
            async with connect(f"ws://127.0.0.1:{port}/ws", origin="http://evil.example"):
                pass
        out = []
        async with connect(f"ws://127.0.0.1:{port}/ws", origin=f"http://127.0.0.1:{port}") as ws:
            out.append(json.loads(await ws.recv()))
            out.append(json.loads(await ws.recv()))
            for cmd in ({"op": "command", "verb": "kill", "uavs": [1]},
                        {"op": "command", "verb": "goto", "uavs": [1], "args": {"x": "ten", "y": 0, "z": 10}},
                        {"op": "command", "verb": "hold", "uavs": [7]},
                        {"op": "command", "verb": "hold", "uavs": "1"},
                        "not json at all",
                        {"op": "command", "verb": "hold", "uavs": [1]}):
                await ws.send(cmd if isinstance(cmd, str) else json.dumps(cmd))
                while (m := json.loads(await ws.recv()))["type"] == "state":
                    pass
                out.append(m)
            deadline = time.monotonic() + 8
            while time.monotonic() < deadline:  # the hold's acknowledgement reaches the page
                m = json.loads(await ws.recv())
                if m["type"] == "state" and m["commands"] and m["commands"][0]["targets"][0]["status"] == "ok":
                    out.append(m)
                    break
        return out

    hello, state, kill, goto, unknown, notalist, junk, hold, acked = asyncio.run(talk())
    assert hello["swarm"] == "webt" and "kill" not in hello["verbs"]
    # the run's fixed layer and the trails from its start, for a page opened mid-run
    scene = hello["scene"]
    assert scene["area"] == [0, 100, 0, 100] and scene["area_label"] == "forest" and scene["hub"] == [-25, 50, 15]
    assert scene["zones"] == [{"name": "village", "kind": "no_fly", "polygon": [[5, 35], [15, 35], [15, 65], [5, 65]]}]
    trail = hello["trails"]["1"]
    recorded = [pt for pt in trail if pt[1] == 50.0]
    assert recorded[0] == [-25.0, 50.0] and recorded[-1][0] >= 73.0 and len(recorded) >= 95  # 99.5 m, a point a metre
    assert trail[-1] == [3.0, 4.0]  # then the live poses
    assert state["uavs"][0]["id"] == 1 and (state["uavs"][0]["x"], state["uavs"][0]["y"]) == (3.0, 4.0)
    assert kill["type"] == "error" and kill["message"].startswith("verb:")
    assert goto["type"] == "error" and goto["message"].startswith("args.x:")
    assert unknown["type"] == "error" and "[7] not alive" in unknown["message"]
    assert notalist["type"] == "error" and notalist["message"].startswith("uavs:")
    assert junk["type"] == "error"
    assert hold["type"] == "sent" and hold["targets"] == [{"uav": 1, "status": "pending", "message": "", "latency_ms": None}]
    assert acked["commands"][0]["targets"][0]["message"] == "hold ok"
