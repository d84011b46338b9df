"""``python -m uav_stack.fcu`` as a subprocess, and several vehicles in one FCU process."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time

import pytest

from tests.fcu_helpers import FcuThread, MavClient
from uav_stack.fcu import FcuConfig, VehicleConfig
from uav_stack.fcu.__main__ import main
from uav_stack.geo import GeoPoint
from uav_stack.mav import mavlink as M


def _read_lines(p: subprocess.Popen, n: int, timeout: float) -> list[str]:
    """The first n stdout lines (raw fd reads, so select() sees every byte), bounded in time."""
    buf = b""
    fd = p.stdout.fileno()
    deadline = time.monotonic() + timeout
    while buf.count(b"\n") < n and time.monotonic() < deadline:
        r, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
        if r:
            chunk = os.read(fd, 4096)
            if not chunk:
                break
            buf += chunk
    return [line.strip() for line in buf.decode().splitlines()[:n]]


def test_cli_subprocess_two_vehicles_params_and_clean_exit() -> None:
    cmd = [sys.executable, "-m", "uav_stack.fcu", "--sysid", "7", "--listen", "127.0.0.1:0", "--count", "2",
           "--home", "47.3977,8.5456,500", "--flavour", "px4", "--rtf", "1.0", "--duration", "30",
           "--param", "MIS_TAKEOFF_ALT=3.5"]  # fmt: skip
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    try:
        lines = _read_lines(p, 2, 10.0)
        assert len(lines) == 2 and lines[0].startswith("LISTEN 7 ") and lines[1].startswith("LISTEN 8 "), lines
        for line in lines:
            sysid = int(line.split()[1])
            host, port = line.split()[2].rsplit(":", 1)
            with MavClient((host, int(port)), target_sysid=sysid) as c:
                c.heartbeat()
                hb = c.recv_match("HEARTBEAT", 3.0)
                assert hb is not None and hb.get_srcSystem() == sysid
                assert c.param_read("MIS_TAKEOFF_ALT").param_value == pytest.approx(3.5)
                gp = c.recv_match("GLOBAL_POSITION_INT", 2.0)
                assert gp is not None and gp.alt == 500_000
        p.send_signal(signal.SIGTERM)
        assert p.wait(5.0) == 0
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(5.0)
        p.stdout.close()


def test_cli_rejects_bad_arguments(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["--listen", "nonsense"])
    with pytest.raises(SystemExit):
        main(["--home", "1,2"])
    assert main(["--listen", "127.0.0.1:0", "--param", "NO_SUCH_PARAM=1", "--duration", "0.1"]) == 2
    assert "NO_SUCH_PARAM" in capsys.readouterr().err
    # the old ArduPilot names are not 4.7's: a clear error, as for any unknown parameter
    assert main(["--listen", "127.0.0.1:0", "--flavour", "ardupilot", "--param", "SYSID_THISMAV=3", "--duration", "0.1"]) == 2
    assert "SYSID_THISMAV" in capsys.readouterr().err
    assert main(["--listen", "127.0.0.1:0", "--rate", "AHRS2=4", "--duration", "0.1"]) == 2  # an ArduPilot message, not PX4's
    assert "AHRS2" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--boot", "slow"])
    with pytest.raises(ValueError, match="boot: expected one of 'short', 'firmware', got 'slow'"):
        VehicleConfig(boot="slow")
    with pytest.raises(ValueError, match="stream_rates: unknown message names"):
        FcuConfig([VehicleConfig()], stream_rates={"NOPE": 1.0})


def test_cli_duration_runs_and_returns() -> None:
    t0 = time.monotonic()
    assert main(["--listen", "127.0.0.1:0", "--duration", "0.5", "--flavour", "ardupilot", "--boot", "firmware"]) == 0
    assert 0.4 < time.monotonic() - t0 < 5.0


def test_cli_boot_firmware_runs_the_firmwares_timeline() -> None:
    """``--boot firmware``: ArduCopter's own boot (its first heartbeat about 1 s after launch, BOOT, then
    STANDBY about 3 s after, not armable until its EKF uses GPS about 42 s after)."""
    cmd = [sys.executable, "-m", "uav_stack.fcu", "--listen", "127.0.0.1:0", "--flavour", "ardupilot", "--boot", "firmware",
           "--duration", "30"]  # fmt: skip
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    try:
        (line,) = _read_lines(p, 1, 10.0)
        host, port = line.split()[2].rsplit(":", 1)
        with MavClient((host, int(port))) as c:
            c.heartbeat()
            hb = c.recv_match("HEARTBEAT", 3.0)
            assert hb is not None and hb.system_status == M.MAV_STATE_BOOT
            assert c.recv_match("HEARTBEAT", 4.0, lambda m: m.system_status == M.MAV_STATE_STANDBY) is not None
            assert c.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_FAILED
            assert c.wait(lambda: any(t.startswith("Arm: ") for t in c.statustexts), 1.0)
        p.send_signal(signal.SIGTERM)
        assert p.wait(5.0) == 0
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(5.0)
        p.stdout.close()


def test_fleet_of_vehicles_in_one_fcu_are_independent() -> None:
    home = GeoPoint(47.3977, 8.5456, 500.0)
    cfg = FcuConfig(
        [VehicleConfig(sysid=10 + i, home=home, flavour="px4" if i % 2 == 0 else "ardupilot") for i in range(4)]
    )
    with FcuThread(cfg) as ft:
        clients = [MavClient(a, target_sysid=10 + i) for i, a in enumerate(ft.addrs)]
        try:
            for i, c in enumerate(clients):
                c.heartbeat()
                hb = c.recv_match("HEARTBEAT", 3.0)
                assert hb is not None and hb.get_srcSystem() == 10 + i
                want = M.MAV_AUTOPILOT_PX4 if i % 2 == 0 else M.MAV_AUTOPILOT_ARDUPILOTMEGA
                assert hb.autopilot == want
            assert clients[2].command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
            assert [ft.fcu.truth(i).armed for i in range(4)] == [False, False, True, False]
            assert len({ft.fcu.truth(i).sysid for i in range(4)}) == 4
        finally:
            for c in clients:
                c.close()
