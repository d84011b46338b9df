"""One live 10-UAV run checks the whole recorder: Foxglove live, the web map in Chromium, run.mcap, results, replay.

During the mission: `mrswarm gcs foxglove` serves the run and a WebSocket client speaking the
Foxglove protocol receives every UAV's poses; `mrswarm gcs web` serves the map, headless Chromium
(the system's, through Playwright) shows every UAV where the swarm says it is, a click on one UAV
and on "Hold" holds it and the page shows its acknowledgement. After the run: the `mcap` reader
finds every UAV's poses in order and as many as the UAVs counted sending (1 %), every command
paired with its ack; `mrswarm results run.mcap` rebuilds the summary; `mrswarm replay` into a
router of its own shows `gcs watch` the same UAVs and phases as the recording.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import shutil
import struct
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from mrswarm.gcs.session import open_observer, resolve_target
from swarmnet.observer import SwarmObserver
from tests.conftest import free_port, wait_for
from tests.gcs_helpers import ROOT, gcs, run_dir, start_run, stop_run

pytestmark = pytest.mark.e2e
SCENARIO = ROOT / "scenarios" / "coverage.yaml"
IDS = list(range(1, 11))
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def _spawn(args: list[str]) -> subprocess.Popen[bytes]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen([sys.executable, "-m", "mrswarm", *args], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def _wait_port(port: int, timeout: float = 30.0) -> bool:
    import socket

    def up() -> bool:
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", port)) == 0
    return wait_for(up, timeout, 0.1)


def foxglove_poses(port: int, seconds: float) -> tuple[str | None, dict[str, dict[str, Any]], dict[int, int]]:
    """Subscribe to every /uav/N/pose channel over the Foxglove WebSocket protocol; count the poses per UAV."""
    from websockets.asyncio.client import connect

    async def run() -> tuple[str | None, dict[str, dict[str, Any]], dict[int, int]]:
        channels: dict[str, dict[str, Any]] = {}
        subs: dict[int, str] = {}
        got: dict[int, int] = defaultdict(int)
        # foxglove-sdk 0.30 names the v1 protocol foxglove.sdk.v1; older servers foxglove.websocket.v1
        async with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],  # type: ignore[list-item]
                           max_size=None) as ws:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                try:
                    m = await asyncio.wait_for(ws.recv(), 0.5)
                except TimeoutError:
                    continue
                if isinstance(m, str):
                    d = json.loads(m)
                    if d["op"] == "advertise":
                        new = []
                        for c in d["channels"]:
                            channels[c["topic"]] = c
                            if c["topic"].endswith("/pose"):
                                sid = len(subs) + 1
                                subs[sid] = c["topic"]
                                new.append({"id": sid, "channelId": c["id"]})
                        if new:
                            await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                elif m[0] == 0x01:  # message data: opcode, subscription id, log time, payload
                    _, sid, _ts = struct.unpack_from("<BIQ", m)
                    pose = json.loads(m[13:])
                    assert subs[sid] == f"/uav/{pose['uav']}/pose"
                    got[pose["uav"]] += 1
            return ws.subprotocol, channels, got

    return asyncio.run(run())


def page_waits_for(page: Any, expression: str, timeout_s: float) -> None:
    """Poll a JS expression with ``page.evaluate`` until it is true (bounded). Not Playwright's
    ``wait_for_function``: its polling evaluates strings with ``eval``, which the page's
    Content-Security-Policy (rightly) forbids, so it fails whenever the first check is false."""
    assert wait_for(lambda: bool(page.evaluate(expression)), timeout_s, 0.1), f"never true: {expression}"


def web_map_check(page: Any, obs: SwarmObserver, shot: Path) -> dict[str, Any]:
    """The page (loaded before take-off): every UAV where the swarm says, a click holds one, its ack shown."""
    out: dict[str, Any] = {}
    page_waits_for(page, "Object.keys(window.mrswarm.uavs).length >= 10", 20.0)
    page.evaluate("window.mrswarm.fit()")  # the view was fitted to the UAVs on the ground
    page.wait_for_timeout(1500)  # a few pushes: trails
    # the JS state and the table, read together (the page redraws both on every push)
    shown, rows = page.evaluate("""() => [window.mrswarm.uavs, [...document.querySelectorAll('#uavs tbody tr')]
                                   .map(r => [+r.dataset.uav, +r.dataset.x, +r.dataset.y])]""")
    obs.poll()
    truth = {u: (v.pose.x, v.pose.y) for u, v in obs.uavs.items() if v.pose is not None}
    out["offsets"] = {int(k): math.dist((u["x"], u["y"]), truth[int(k)]) for k, u in shown.items()}
    out["rows"] = rows
    out["shown"] = {int(k): (u["x"], u["y"]) for k, u in shown.items()}
    out["scene"] = page.evaluate("window.mrswarm.scene")  # the run's mission area, from its scenario.yaml
    out["trails"] = page.evaluate("Object.fromEntries(Object.entries(window.mrswarm.trails).map(([k, t]) => [k, t.length]))")
    at = page.evaluate("window.mrswarm.screenOf(3)")
    page.mouse.click(at["x"], at["y"])
    out["selected"] = page.evaluate("window.mrswarm.selected")
    page.click("button[data-verb=hold]")
    page.wait_for_selector("#commands li[data-uav='3'][data-verb='hold'][data-status='ok']", timeout=15_000)
    out["ack"] = page.inner_text("#commands li[data-uav='3'][data-verb='hold']")
    page_waits_for(page, "!!window.mrswarm.uavs[3] && window.mrswarm.uavs[3].phase === 'hold'", 10.0)
    page.wait_for_timeout(500)
    page.screenshot(path=str(shot))
    page.click("button[data-verb=resume]")
    page.wait_for_selector("#commands li[data-uav='3'][data-verb='resume'][data-status='ok']", timeout=15_000)
    return out


def _in_thread(fn: Any, *args: Any) -> Any:
    """Run ``fn`` in a thread of its own (an asyncio client beside Playwright's sync API)."""
    import concurrent.futures

    with concurrent.futures.ThreadPoolExecutor(1) as ex:
        return ex.submit(fn, *args).result(timeout=60)


def phases_in_recording(path: Path, t_from: float, t_to: float) -> dict[int, set[str]]:
    """Each UAV's phases in [t_from, t_to] s of the recording (the last one before t_from included)."""
    out: dict[int, set[str]] = defaultdict(set)
    last: dict[int, str] = {}
    t0 = None
    with open(path, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages():
            t0 = m.log_time if t0 is None else t0
            if not ch.topic.endswith("/state"):
                continue
            d = json.loads(m.data)
            t = (m.log_time - t0) / 1e9
            if t < t_from:
                last[d["uav"]] = d["phase"]
            elif t <= t_to:
                out[d["uav"]].add(d["phase"])
    for u, ph in last.items():
        out[u].add(ph)
    return out


def watch_rows(text: str) -> dict[int, list[str]]:
    rows = {}
    for line in text.splitlines():
        cells = line.split()
        if len(cells) > 5 and cells[0].isdigit() and cells[1] in ("V", "P"):
            rows[int(cells[0])] = cells
    return rows


def test_a_recorded_run_live_in_foxglove_and_the_web_map_then_read_rebuilt_and_replayed(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    proc = start_run(SCENARIO, out, ["duration=45"])
    helpers: list[subprocess.Popen[bytes]] = []
    try:
        rd = run_dir(out, 60)
        # Every helper starts now, while the UAVs start: a process start is a CPU burst, and on a loaded
        # 2-core machine a burst in flight can make Zenoh drop a pose on its way to the recorder.
        fport, wport = free_port(), free_port()
        helpers.append(_spawn(["gcs", "foxglove", "--run", str(rd), "--port", str(fport), "--duration", "120"]))
        helpers.append(_spawn(["gcs", "web", "--run", str(rd), "--port", str(wport), "--duration", "120"]))
        assert _wait_port(fport) and _wait_port(wport), "gcs foxglove or gcs web never listened"
        from playwright.sync_api import sync_playwright

        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1400, "height": 800})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(f"http://127.0.0.1:{wport}/")
            obs = open_observer(resolve_target(str(rd), [], None), name="e2e")
            try:
                assert wait_for(lambda: (obs.poll(), obs.phases())[1] == {u: "mission" for u in IDS}, 120.0, 0.1), obs.phases()
                # ---- Foxglove, live
                proto, channels, got = _in_thread(foxglove_poses, fport, 4.0)
                _stop(helpers[0])  # each client costs the edge router a copy of every message: only while needed
                assert proto in ("foxglove.sdk.v1", "foxglove.websocket.v1")
                assert set(got) == set(IDS) and min(got.values()) >= 15, got  # 10 Hz for 4 s, less the subscription's start
                assert channels["/swarm/scene"]["schemaName"] == "foxglove.SceneUpdate"
                assert channels["/uav/1/location"]["schemaName"] == "foxglove.LocationFix"
                assert channels["/uav/1/pose"]["encoding"] == "json"
                # ---- the web map in Chromium, live
                shot = tmp_path / "web-map.png"
                web = web_map_check(page, obs, shot)
                _stop(helpers[1])
                if os.environ.get("MRSWARM_DOC_SCREENSHOT"):  # how docs/images/web-map.png was made
                    shutil.copy(shot, os.environ["MRSWARM_DOC_SCREENSHOT"])
            finally:
                obs.close()
                browser.close()
        assert errors == []
        assert sorted(web["shown"]) == IDS
        assert max(web["offsets"].values()) < 3.0, web["offsets"]  # m: 5 m/s between two 5 Hz pushes
        assert sorted(r[0] for r in web["rows"]) == IDS
        assert all(web["shown"][u] == (x, y) for u, x, y in web["rows"])  # the table shows the state the map draws
        assert web["selected"] == [3]
        assert web["scene"]["area"] == [-100, 100, -80, 80]  # coverage.yaml's field, drawn
        assert sorted(int(k) for k in web["trails"]) == IDS and min(web["trails"].values()) >= 5, web["trails"]
        assert web["ack"].startswith("#1 hold → UAV 3: ok") and "holding at" in web["ack"]
        assert shot.stat().st_size > 20_000
        assert proc.wait(180) == 0
    finally:
        for h in helpers:
            _stop(h)
        stop_run(proc)

    # ---- the recording, read back with the mcap package
    mcap = rd / "run.mcap"
    with open(mcap, "rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None  # the recorder finished its file
        poses: dict[int, list[tuple[int, float]]] = defaultdict(list)
        cmds: dict[tuple[int, int], tuple[str, int]] = {}
        acks: dict[tuple[int, int], int] = {}
        for i, (_, ch, m) in enumerate(reader.iter_messages(log_time_order=False)):  # file order: arrival order
            if ch.topic.endswith("/pose"):
                d = json.loads(m.data)
                poses[d["uav"]].append((m.sequence, d["t_wall"]))
            elif ch.topic.endswith("/cmd"):
                d = json.loads(m.data)
                cmds[(d["target"], d["cmd_id"])] = (d["verb"], i)
            elif ch.topic.endswith("/ack"):
                d = json.loads(m.data)
                acks[(d["uav"], d["cmd_id"])] = i
    for u in IDS:
        seqs = [s for s, _ in poses[u]]
        # in order (the sequence number only grows; a pose Zenoh dropped under congestion, by design, leaves a gap)
        assert all(0 < (b - a) % 65536 < 100 for a, b in zip(seqs, seqs[1:], strict=False)), f"UAV {u}: poses out of order"
        assert all(b >= a for (_, a), (_, b) in zip(poses[u], poses[u][1:], strict=False))
        sent = json.loads((rd / f"uav{u}.json").read_text())["net"]["sent"]["pose"]
        assert abs(len(poses[u]) - sent) <= 0.01 * sent, f"UAV {u}: recorded {len(poses[u])} poses, sent {sent}"
    verbs = {v for v, _ in cmds.values()}
    assert {"takeoff", "start", "hold", "resume"} <= verbs
    assert set(cmds) == set(acks), (set(cmds) ^ set(acks))  # every command acknowledged, every ack answers one
    assert all(acks[k] > cmds[k][1] for k in cmds)  # each ack arrived after its command

    # ---- results rebuilt from the recording alone
    res = subprocess.run([sys.executable, "-m", "mrswarm", "results", str(mcap), "--out", str(tmp_path / "from-mcap")], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    original = json.loads((rd / "summary.json").read_text())
    rebuilt = json.loads((tmp_path / "from-mcap" / "summary.json").read_text())
    assert rebuilt["uavs_recorded"] == 10
    assert rebuilt["separation"]["collisions"] == original["separation"]["collisions"]
    assert rebuilt["coverage"]["final"] == pytest.approx(original["coverage"]["final"], abs=0.03)

    # ---- replay into a router of its own, watched by `gcs watch`
    rport = free_port()
    endpoint = f"tcp/127.0.0.1:{rport}"
    rp = _spawn(["replay", str(mcap), "--speed", "4", "--from", "30s", "--swarm", "rp", "--listen", endpoint, "--quiet"])
    try:
        assert _wait_port(rport), "the replay's router never listened"
        t_start = time.monotonic()
        time.sleep(2.0)
        watch = gcs(["watch", "--once", "--connect", endpoint, "--swarm", "rp"], timeout=60)
        elapsed = time.monotonic() - t_start
        assert rp.wait(120) == 0
    finally:
        _stop(rp)
    assert watch.returncode == 0, watch.stderr
    rows = watch_rows(watch.stdout)
    assert sorted(rows) == IDS, watch.stdout
    expected = phases_in_recording(mcap, 30.0, 30.0 + (elapsed + 1.0) * 4)
    assert all(rows[u][2] in expected[u] for u in IDS), (watch.stdout, dict(expected))
    assert all(rows[u][1] == "V" for u in IDS)
