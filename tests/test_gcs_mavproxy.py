"""MAVProxy, a real ground station, signing with the key `mrswarm keys mavlink` prints: takes one UAV of a running
swarm mission to RTL through its agent's router, while a process on the ground-station port watches every UAV and
its unsigned commands are refused; flies a QGC WPL mission file in AUTO and climbs a UAV with `rc 3 1700` in LOITER
(ArduPilot flavour)."""

from __future__ import annotations

import math
import os
import shutil
import signal
import socket
import subprocess
import sysconfig
import threading
import time
from pathlib import Path

import pytest

from mrswarm.gcs.session import open_observer, resolve_target
from swarmnet.connectivity import Rendezvous
from swarmnet.observer import SwarmObserver
from tests.conftest import free_port, wait_for
from tests.fcu_helpers import DatagramParser
from tests.gcs_helpers import (
    HOME,
    ROOT,
    gcs,
    mavlink_passphrase,
    mavproxy_args,
    run_dir,
    start_run,
    start_virtual_uav,
    stop_process,
    stop_run,
)
from uav_stack.config import MavlinkSigning
from uav_stack.mav import mavlink as M
from uav_stack.mavlink_signing import write_key_file

pytestmark = pytest.mark.e2e
SCENARIO = ROOT / "tests" / "scenarios" / "gcs_mavproxy.yaml"
# beside the interpreter (the checkout's .venv/bin, also when that venv is not activated), else on PATH
MAVPROXY = shutil.which("mavproxy.py", path=os.pathsep.join([sysconfig.get_path("scripts"), os.environ.get("PATH", "")]))


def _free_udp_block(n: int) -> int:
    """A base port with base+1..base+n free for UDP (the routers' listen ports)."""
    for _ in range(50):
        base = free_port(socket.SOCK_DGRAM)
        if base + n > 65535:
            continue
        socks = []
        try:
            for i in range(1, n + 1):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(s)
                s.bind(("127.0.0.1", base + i))
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise RuntimeError("no free UDP port block")


def test_mavproxy_switches_one_uav_to_rtl_it_yields_and_the_swarm_carries_on(tmp_path: Path) -> None:
    assert MAVPROXY is not None, "mavproxy.py not found: MAVProxy is in the test extra (pip install -e '.[test]')"
    base = _free_udp_block(3)
    # a local process on the ground-station port (QGroundControl's 14550 in a default run): the UAVs send it telemetry
    qgc_port = free_port(socket.SOCK_DGRAM)
    rogue = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rogue.bind(("127.0.0.1", qgc_port))
    rogue.settimeout(0.2)
    run = start_run(SCENARIO, tmp_path, [f"gcs.listen_base={base}", f"gcs.port={qgc_port}"])
    mp: subprocess.Popen[str] | None = None
    obs = None
    try:
        rdir = run_dir(tmp_path)
        obs = open_observer(resolve_target(str(rdir), [], None))

        def phases() -> dict[int, str]:
            obs.poll()
            return obs.phases()

        assert wait_for(lambda: [phases().get(u) for u in (1, 2, 3)] == ["mission"] * 3, 120, 0.2), \
            f"swarm never reached the mission: {phases()}"
        # it sees every UAV, and its unsigned force-disarm and LAND to each are refused: they all fly on
        routers: dict[tuple[str, int], int] = {}  # each UAV's router (its udpout socket) -> its FCU's sysid
        gcs_mav = M.MAVLink(None, 255, 190)
        parser = DatagramParser()
        end = time.monotonic() + 4.0
        while time.monotonic() < end:
            try:
                data, addr = rogue.recvfrom(65535)
            except OSError:
                continue
            for m in parser.parse(data)[0]:
                if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1:
                    sysid = routers[addr] = m.get_srcSystem()
                    rogue.sendto(M.MAVLink_command_long_message(sysid, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 21196,
                                                                0, 0, 0, 0, 0).pack(gcs_mav)
                                 + M.MAVLink_set_mode_message(sysid, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 9).pack(gcs_mav),
                                 addr)
        assert sorted(routers.values()) == [1, 2, 3], routers
        time.sleep(1.5)  # the stats files are rewritten every second
        for u in (1, 2, 3):
            rt = __import__("json").loads((rdir / f"uav{u}.json").read_text())["mavlink_router"]
            assert rt["unsigned_commands_refused"] >= 2 and rt["to_fcu"] == 0 and rt["signing"] == "signed", (u, rt)
        assert [phases().get(u) for u in (1, 2, 3)] == ["mission"] * 3
        # MAVProxy connects to UAV 2's router (udpout to the agent's listening endpoint), signing with the run's
        # key as `mrswarm keys mavlink --run` prints it, and is fed commands on stdin once it has detected the
        # vehicle (its --cmd runs before any heartbeat).
        args, env = mavproxy_args(MAVPROXY, base + 2, mavlink_passphrase("--run", str(rdir)))
        mp = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              cwd=tmp_path, start_new_session=True, env=env)
        out: list[str] = []
        threading.Thread(target=lambda: out.extend(iter(mp.stdout.readline, "")), daemon=True).start()  # type: ignore[union-attr]
        assert wait_for(lambda: any("Detected vehicle 2:1" in line for line in out), 60, 0.2), "".join(out)[-2000:]
        assert wait_for(lambda: any("Received" in line and "parameters" in line for line in out), 30, 0.2), "".join(out)[-2000:]
        assert mp.stdin is not None
        mp.stdin.write("mode RTL\n")
        mp.stdin.flush()
        assert wait_for(lambda: any("DO_SET_MODE: ACCEPTED" in line for line in out), 20, 0.2), "".join(out)[-2000:]

        def yielded() -> bool:
            obs.poll()
            v = obs.uavs.get(2)
            return v is not None and v.state is not None and v.state.phase == "yielded"

        assert wait_for(yielded, 15, 0.1), phases()
        st = obs.uavs[2].state
        assert st is not None and st.override in ("fcu:RTL", "gcs:DO_SET_MODE") and "setpoints stopped" in st.detail
        # the others carry on with the mission: still in it and still moving
        before = {u: (obs.uavs[u].pose.x, obs.uavs[u].pose.y) for u in (1, 3)}  # type: ignore[union-attr]
        time.sleep(3.0)
        obs.poll()
        assert phases()[1] == phases()[3] == "mission"
        for u in (1, 3):
            p = obs.uavs[u].pose
            assert p is not None and ((p.x - before[u][0]) ** 2 + (p.y - before[u][1]) ** 2) ** 0.5 > 3.0
        # UAV 2 is really in RTL (ArduPilot climbs to RTL_ALT 15 m first) and the CLI reports it
        res = gcs(["telemetry", "--run", str(rdir), "--uav", "2", "--json"])
        assert res.returncode == 0, res.stderr
        assert '"mode": "RTL"' in res.stdout and '"phase": "yielded"' in res.stdout
        res = gcs(["nodes", "--run", str(rdir), "--json"])
        assert res.returncode == 0, res.stderr
        nodes = [__import__("json").loads(line) for line in res.stdout.splitlines()]
        assert sorted(n["id"] for n in nodes if n["role"] == "uav") == [1, 2, 3]
        assert all(n["realm"] == "virtual" and n["alive"] and n["last_seen"] for n in nodes if n["role"] == "uav")
        # a discovery run: the server's registry adds each node's software version and Zenoh locators
        assert all(n["version"].startswith("mrswarm") and "tls/127.0.0.1:" in n["address"]  # secured run: TLS locators
                   for n in nodes if n["role"] == "uav"), nodes
        res = gcs(["watch", "--run", str(rdir), "--once", "--filter", "override"])
        assert res.returncode == 0, res.stderr
        table = [line.split() for line in res.stdout.splitlines() if line.split() and line.split()[0].isdigit()]
        assert [row[:3] for row in table] == [["2", "V", "yielded"]], res.stdout
        stats_file = rdir / "uav2.json"
        tx = __import__("json").loads(stats_file.read_text())["fcu_link"]["tx_setpoints"]
        time.sleep(2.5)
        assert __import__("json").loads(stats_file.read_text())["fcu_link"]["tx_setpoints"] == tx  # no more setpoints
        rt2 = __import__("json").loads(stats_file.read_text())["mavlink_router"]
        assert rt2["signed"] > 0 and rt2["to_fcu"] > 0 and rt2["bad_signature"] == 0, rt2
        stop_run(run)
        summary = __import__("json").loads((rdir / "summary.json").read_text())
        assert summary["mavlink"]["mode"] == "signed" and summary["mavlink"]["refused"]["unsigned_commands_refused"] >= 2
    finally:
        rogue.close()
        if obs is not None:
            obs.close()
        if mp is not None and mp.poll() is None:
            try:
                os.killpg(mp.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            mp.wait(10)
        stop_run(run)


def _wpl(path: Path, home: tuple[float, float, float], legs: list[tuple[float, float]], alt: float) -> list[tuple[float, float]]:
    """A QGC WPL 110 file as MAVProxy and Mission Planner write it: home, takeoff, waypoints (north/east m).
    Returns the waypoints' lat/lon."""
    lat0, lon0, alt0 = home
    lines = ["QGC WPL 110", f"0\t1\t0\t16\t0\t0\t0\t0\t{lat0:.8f}\t{lon0:.8f}\t{alt0:.6f}\t1",
             f"1\t0\t3\t22\t0\t0\t0\t0\t0\t0\t{alt:.6f}\t1"]
    points = []
    for k, (n, e) in enumerate(legs, start=2):
        lat, lon = lat0 + n / 111_320.0, lon0 + e / (111_320.0 * math.cos(math.radians(lat0)))
        points.append((lat, lon))
        lines.append(f"{k}\t0\t3\t16\t0\t0\t0\t0\t{lat:.8f}\t{lon:.8f}\t{alt:.6f}\t1")
    path.write_text("\n".join(lines) + "\n")
    return points


class _Listener:
    """A ground station that only listens (the router's udpout endpoint): every message, in order."""

    def __init__(self, port: int):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.2)
        self.parser = DatagramParser()
        self.msgs: list = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                data, _ = self.sock.recvfrom(65535)
            except OSError:
                continue
            self.msgs.extend(self.parser.parse(data)[0])

    def latest(self, mtype: str):  # noqa: ANN201
        """The vehicle's latest message of a type (MAVProxy's own heartbeat comes through the router too)."""
        return next((m for m in reversed(self.msgs) if m.get_type() == mtype and m.get_srcComponent() == 1), None)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(2)
        self.sock.close()


def test_mavproxy_flies_a_wpl_file_in_auto_and_climbs_with_rc_override_in_loiter(tmp_path: Path, router: str) -> None:
    assert MAVPROXY is not None, "mavproxy.py not found: MAVProxy is in the test extra (pip install -e '.[test]')"
    port, watch_port = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)
    legs = [(15.0, 0.0), (15.0, 15.0), (0.0, 15.0), (0.0, 0.0)]
    points = _wpl(tmp_path / "survey.waypoints", (HOME.lat, HOME.lon, HOME.alt), legs, 8.0)
    watch = _Listener(watch_port)
    obs = SwarmObserver("gcs", Rendezvous((router,), mode="client"), role="gcs", name="test").open()
    key = write_key_file(tmp_path / "mavlink.key")
    proc = start_virtual_uav(tmp_path, router, uav=3, flavour="ardupilot", signing=MavlinkSigning(key_file=str(key)),
                             endpoints=(f"udpin:127.0.0.1:{port}", f"udpout:127.0.0.1:{watch_port}"))
    mp: subprocess.Popen[str] | None = None
    try:
        args, env = mavproxy_args(MAVPROXY, port, key.read_text().strip())
        mp = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              cwd=tmp_path, start_new_session=True, env=env)
        out: list[str] = []
        threading.Thread(target=lambda: out.extend(iter(mp.stdout.readline, "")), daemon=True).start()  # type: ignore[union-attr]

        def say(line: str) -> None:
            assert mp is not None and mp.stdin is not None
            mp.stdin.write(line + "\n")
            mp.stdin.flush()

        assert wait_for(lambda: any("Detected vehicle 3:1" in line for line in out), 60, 0.2), "".join(out)[-2000:]
        assert wait_for(lambda: any("Received" in line and "parameters" in line for line in out), 30, 0.2), "".join(out)[-2000:]
        # the FCU is ready (its first fix) and the agent reports ready
        assert wait_for(lambda: _phase_is(obs, 3, "ready"), 30, 0.2)
        say(f"wp load {tmp_path / 'survey.waypoints'}")
        assert wait_for(lambda: any("Loaded 6 waypoints in" in line for line in out), 20, 0.2), "".join(out)[-2000:]
        say("mode GUIDED")
        assert wait_for(lambda: any("GUIDED" in line for line in out[-20:]), 10, 0.2)
        say("arm throttle")
        assert wait_for(lambda: (hb := watch.latest("HEARTBEAT")) is not None and hb.base_mode & 128, 15, 0.2), "not armed"
        since = len(watch.msgs)
        say("mode AUTO")
        reached = lambda: [m.seq for m in watch.msgs[since:] if m.get_type() == "MISSION_ITEM_REACHED"]  # noqa: E731
        assert wait_for(lambda: reached() == [1, 2, 3, 4, 5], 90, 0.2), (reached(), "".join(out)[-1500:])
        # every waypoint flown to within WPNAV_RADIUS (2 m), the home slot (item 0) never
        for k, (lat, lon) in enumerate(points, start=2):
            k_lon = 111_320.0 * math.cos(math.radians(lat))
            near = min(math.hypot((m.lat * 1e-7 - lat) * 111_320.0, (m.lon * 1e-7 - lon) * k_lon)
                       for m in watch.msgs[since:] if m.get_type() == "GLOBAL_POSITION_INT")
            assert near < 2.0, (k, near)
        st = _state(obs, 3)  # the agent saw someone else fly its UAV, and says so
        assert st is not None and st.phase == "yielded" and st.override in ("fcu:AUTO", "gcs:DO_SET_MODE"), st
        # LOITER, then "rc 3 1700": above the throttle dead zone, it climbs
        say("mode LOITER")
        assert wait_for(lambda: (hb := watch.latest("HEARTBEAT")) is not None and hb.custom_mode == 5, 10, 0.2)
        time.sleep(1.0)
        alt0 = watch.latest("GLOBAL_POSITION_INT").relative_alt / 1000.0
        say("rc 3 1700")
        assert wait_for(lambda: watch.latest("GLOBAL_POSITION_INT").relative_alt / 1000.0 > alt0 + 2.0, 8, 0.1), \
            (alt0, watch.latest("GLOBAL_POSITION_INT").relative_alt)
        say("rc 3 1500")
        time.sleep(1.5)
        held = watch.latest("GLOBAL_POSITION_INT").relative_alt / 1000.0
        time.sleep(1.0)
        assert abs(watch.latest("GLOBAL_POSITION_INT").relative_alt / 1000.0 - held) < 0.3  # mid stick holds
        assert watch.latest("HEARTBEAT").custom_mode == 5
    finally:
        if mp is not None and mp.poll() is None:
            try:
                os.killpg(mp.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            mp.wait(10)
        watch.close()
        obs.close()
        stop_process(proc)


def _state(obs: SwarmObserver, uav: int):  # noqa: ANN202
    obs.poll()
    v = obs.uavs.get(uav)
    return v.state if v is not None else None


def _phase_is(obs: SwarmObserver, uav: int, phase: str) -> bool:
    st = _state(obs, uav)
    return st is not None and st.phase == phase
