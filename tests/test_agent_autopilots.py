"""`mrswarm agent` against flight controllers that behave like factory-default autopilots.

Real processes over real UDP MAVLink: the agent (``mrswarm agent``) against a virtual FCU
(``mrswarm fcu``) set up the way a real autopilot is at its factory defaults, or against the
frames a real ArduCopter 4.7 sent (tests/captures.py) replayed at their pace. Each test reads
what the user reads: the UAV's status file (``uav<N>.json``: phase, detail, counters).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from groundfloor.schema import convert
from tests import captures
from tests.conftest import free_port, wait_for
from uav_stack.config import AgentConfig

pytestmark = pytest.mark.e2e  # flights of several processes, tens of seconds each

ROOT = Path(__file__).resolve().parents[1]
HOME = (47.397742, 8.545594, 488.0)
ARDUPILOT_HOME = (-35.363261, 149.165230, 584.0)  # where the recorded ArduCopter SITL was
ENV = dict(os.environ, PYTHONUNBUFFERED="1")


def _stop(*procs: subprocess.Popen[Any] | None) -> None:
    for p in procs:
        if p is not None and p.poll() is None:
            p.terminate()
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)


@contextmanager
def virtual_fcu(*args: str) -> Iterator[str]:
    """`mrswarm fcu` with these flags; yields its address (HOST:PORT)."""
    fcu = subprocess.Popen([sys.executable, "-m", "mrswarm", "fcu", "--listen", "127.0.0.1:0", "--home",
                            ",".join(map(str, HOME)), "--duration", "120", *args],
                           cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ENV)
    try:
        line = fcu.stdout.readline()  # type: ignore[union-attr]
        assert line.startswith("LISTEN"), line
        yield line.split()[2]
    finally:
        _stop(fcu)


@contextmanager
def agent(tmp_path: Path, fcu_url: str, router: str, *, autostart: bool = True, origin: tuple[float, ...] = HOME,
          arm_timeout_s: float = 60.0, name: str = "rec", **more: Any) -> Iterator[tuple[subprocess.Popen[str], Path]]:
    """`mrswarm agent --config` for UAV 3 (``more``: further AgentConfig fields); yields the process
    and its status file (``<name>/uav3.json``)."""
    rec = tmp_path / name
    cfg = convert({"swarm": "solo", "uav": 3, "origin": {"lat": origin[0], "lon": origin[1], "alt": origin[2]},
                   "fcu": fcu_url, "realm": "physical", "autostart": autostart, "record_dir": str(rec),
                   "network": {"endpoints": [router], "listen": ["tcp/127.0.0.1:0"]},
                   "failsafe": {"arm_timeout_s": arm_timeout_s}, **more}, AgentConfig)
    path = tmp_path / f"{name}.json"
    path.write_text(cfg.to_json())
    p = subprocess.Popen([sys.executable, "-m", "mrswarm", "agent", "--fcu", fcu_url, "--config", str(path), "--insecure",
                          "--duration", "90"],  # (the config sets the swarm, UAV and origin: beside it only these flags)
                         cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ENV)
    try:
        yield p, rec / "uav3.json"
    finally:
        _stop(p)


def status(path: Path) -> dict[str, Any]:
    try:
        data: dict[str, Any] = json.loads(path.read_text())
        return data
    except (OSError, ValueError):
        return {}


def test_an_fcu_silent_until_asked_is_asked_and_flown(tmp_path: Path, router: str) -> None:
    """ArduCopter's factory defaults stream nothing but HEARTBEAT: the agent asks for its streams
    (SET_MESSAGE_INTERVAL) and flies. The virtual ArduCopter, like the firmware, sends nothing it is not asked for."""
    with virtual_fcu("--flavour", "ardupilot") as addr, agent(tmp_path, f"udpout:{addr}", router) as (p, st):
        assert wait_for(lambda: status(st).get("phase") in ("hover", "mission", "done"), 60.0), (status(st), p.poll())
        s = status(st)
        streams = s["fcu"]["streams"]
        assert streams["GLOBAL_POSITION_INT"]["status"] == "ok" and streams["GLOBAL_POSITION_INT"]["ack"] == "accepted"
        assert s["fcu"]["autopilot"] == "ArduCopter" and s["fcu"]["requests"] >= 5
        assert s["fcu_link"]["foreign_id"] == 0 and s["fcu_link"]["unknown_id"] == 0
        assert p.poll() is None


@contextmanager
def replaying(autopilot: str, capture: str, port: int, speed: float) -> Iterator[threading.Event]:
    """Send a capture's vehicle frames to 127.0.0.1:``port`` at ``speed`` times their pace; the event is set at the end."""
    frames = [f for f in captures.frames(autopilot, capture) if f.msg.get_srcSystem() == 1]
    done, stop = threading.Event(), threading.Event()

    def run() -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        t0, w0 = frames[0].t, time.monotonic()
        for f in frames:
            if stop.is_set():
                break
            delay = (f.t - t0) / speed - (time.monotonic() - w0)
            if delay > 0:
                stop.wait(delay)
            sock.sendto(f.raw, ("127.0.0.1", port))
        sock.close()
        done.set()

    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        yield done
    finally:
        stop.set()
        th.join(5)


def test_zeros_before_the_gps_fix_are_no_position_and_never_a_crash(tmp_path: Path, router: str) -> None:
    """A real ArduCopter's first 50 s (replayed at 4x): GLOBAL_POSITION_INT all zeros until its GPS
    is detected, then a position its EKF does not use until 41.8 s. The agent waits in init saying
    why, publishes no pose, then is ready once the EKF uses GPS."""
    port = free_port(socket.SOCK_DGRAM)
    with agent(tmp_path, f"udpin:127.0.0.1:{port}", router, autostart=False, origin=ARDUPILOT_HOME) as (p, st), \
            replaying(captures.ARDUPILOT, "arm_too_early", port, 4.0):
        assert wait_for(lambda: "latitude and longitude 0" in status(st).get("detail", ""), 20.0), status(st)
        s = status(st)
        assert s["phase"] == "init" and s["net"]["sent"].get("pose", 0) == 0
        assert wait_for(lambda: "does not use GPS" in status(st).get("detail", ""), 20.0), status(st)
        assert status(st)["phase"] == "init" and status(st)["net"]["sent"].get("pose", 0) == 0
        assert wait_for(lambda: status(st).get("phase") == "ready", 20.0), status(st)
        assert wait_for(lambda: status(st)["net"]["sent"].get("pose", 0) > 0, 5.0)
        s = status(st)
        assert s["fcu_link"]["no_position"] > 20 and s["fcu_link"]["foreign_id"] == 0
        assert p.poll() is None


def test_an_own_pose_the_wire_cannot_hold_is_counted_and_skipped(tmp_path: Path, router: str) -> None:
    """A swarm origin far from the UAV (0, 0 against 47 N, 8 E): its altitude in the swarm frame is out
    of the pose's range. Counted, skipped, the agent keeps running."""
    with virtual_fcu() as addr, agent(tmp_path, f"udpout:{addr}", router, autostart=False, origin=(0.0, 0.0, 0.0)) as (p, st):
        assert wait_for(lambda: status(st).get("agent", {}).get("pose_unencodable", 0) > 10, 30.0), status(st)
        assert status(st)["phase"] == "ready" and p.poll() is None


def test_an_arm_the_autopilot_keeps_refusing_is_reported_with_its_reason(tmp_path: Path, router: str) -> None:
    """Pre-arm checks that never pass (the virtual PX4's battery threshold above any charge): the agent
    waits for them, tries, says the autopilot's own reason (PX4 sends no text: its refusal event), and gives
    up after failsafe.arm_timeout_s."""
    with virtual_fcu("--param", "BAT_EMERGEN_THR=1.0") as addr, \
            agent(tmp_path, f"udpout:{addr}", router, arm_timeout_s=15.0) as (p, st):
        assert wait_for(lambda: "pre-arm checks" in status(st).get("detail", ""), 20.0), status(st)
        assert status(st)["phase"] == "arming"
        reason = "commander_arm_denied_resolve_failures"  # PX4's own refusal, as its event names it
        assert wait_for(lambda: reason in status(st).get("detail", ""), 20.0), status(st)
        watch = subprocess.run([sys.executable, "-m", "mrswarm", "gcs", "watch", "--connect", router, "--swarm", "solo",
                                "--once"], cwd=ROOT, capture_output=True, text=True, env=dict(ENV, COLUMNS="100"), timeout=60)
        assert "UAV 3 arming: " in watch.stdout and "commander_arm_denied" in watch.stdout, watch.stdout  # a GCS sees it
        assert wait_for(lambda: status(st).get("phase") == "error", 20.0), status(st)
        s = status(st)
        assert s["detail"].startswith("not armed after 15 s (takeoff or start tries again)") and reason in s["detail"]
        assert s["agent"]["arm_refused"] >= 1 and s["agent"]["arm_gave_up"] == 1
        out = subprocess.run([sys.executable, "-m", "mrswarm", "gcs", "start", "--connect", router, "--swarm", "solo",
                              "--uav", "3", "--json"], cwd=ROOT, capture_output=True, text=True, env=ENV, timeout=60)
        assert out.returncode == 0 and json.loads(out.stdout.splitlines()[-1])["status"] == "ok", (out.stdout, out.stderr)
        assert wait_for(lambda: status(st).get("phase") == "arming", 5.0), status(st)  # an operator's start tries again
        assert p.poll() is None


# PX4 streams all of it from boot; an ArduPilot whose MAV1_* rates are set streams its groups' messages
# (EXTENDED_SYS_STATE and HOME_POSITION are in none: asked for)
STREAMING = {"px4": ((), ("GLOBAL_POSITION_INT", "SYS_STATUS", "EXTENDED_SYS_STATE", "HOME_POSITION", "GPS_RAW_INT")),
             "ardupilot": (("--param", "MAV1_POSITION=10", "--param", "MAV1_EXT_STAT=2", "--param", "MAV1_EXTRA3=2"),
                           ("GLOBAL_POSITION_INT", "SYS_STATUS", "GPS_RAW_INT"))}  # fmt: skip


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_the_contract_asks_nothing_of_an_fcu_that_streams_what_the_agent_needs(tmp_path: Path, router: str,
                                                                               flavour: str) -> None:
    args, unasked = STREAMING[flavour]
    with virtual_fcu("--flavour", flavour, *args) as addr, \
            agent(tmp_path, f"udpout:{addr}", router, autostart=False) as (p, st):  # fmt: skip
        assert wait_for(lambda: status(st).get("fcu", {}).get("streams", {}).get("HOME_POSITION", {}).get("status") == "ok",
                        20.0), status(st)
        streams = status(st)["fcu"]["streams"]
        for name in unasked:
            assert streams[name]["status"] == "ok" and streams[name]["ack"] == "", (name, streams[name])  # never asked
        assert status(st)["phase"] == "ready"


def test_px4_back_in_offboard_after_a_landing_is_armed_and_flown_again(tmp_path: Path, router: str) -> None:
    """A first agent flies and lands; PX4, disarmed, returns to OFFBOARD (its intended mode), where it
    refuses to arm without a setpoint stream. A second agent, on the same FCU, leaves OFFBOARD for
    HOLD, arms and flies."""
    hop = {"altitude": 4.0, "mission": {"type": "goto", "goal": [4.0, 0.0], "land_when_done": True}}
    with virtual_fcu("--flavour", "px4") as addr:
        with agent(tmp_path, f"udpout:{addr}", router, name="first", **hop) as (p1, st1):
            assert wait_for(lambda: status(st1).get("phase") == "landed" and status(st1)["fcu"]["mode"] != "LAND", 40.0), \
                status(st1)
            assert status(st1)["fcu"]["mode"] == "OFFBOARD"
            assert wait_for(lambda: status(st1)["fcu"]["prearm_ok"] is False, 5.0)  # PX4 would refuse to arm there
        with agent(tmp_path, f"udpout:{addr}", router, name="second") as (p2, st2):
            assert wait_for(lambda: status(st2).get("phase") in ("hover", "mission", "done"), 40.0), status(st2)
            assert status(st2)["agent"]["arm_refused"] == 0  # it left OFFBOARD first: no refusal to learn from
        out = p2.stdout.read() if p2.stdout else ""  # type: ignore[union-attr]
        assert "switching from OFFBOARD to HOLD to arm" in out, out[-3000:]


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_started_with_the_autopilot_it_arms_on_its_signals_not_its_refusals(tmp_path: Path, router: str,
                                                                             flavour: str) -> None:
    """The agent starts with the autopilot, through its boot (the firmware's own timeline, run 4x: ArduCopter
    has its position after about 42 s): it waits for the position and the pre-arm checks the autopilot
    reports, then arms once, accepted."""
    with virtual_fcu("--flavour", flavour, "--boot", "firmware", "--rtf", "4") as addr, \
            agent(tmp_path, f"udpout:{addr}", router) as (p, st):
        assert wait_for(lambda: status(st).get("phase") in ("hover", "mission", "done"), 60.0), status(st)
        s = status(st)
        assert s["agent"]["arm_refused"] == 0, s["detail"]
        assert s["fcu_link"]["no_position"] > 0 or flavour == "px4"  # ArduCopter's zeros, then its EKF without GPS
