"""`mrswarm preflight` against the virtual FCU in both flavours: a failing check shown, then fixed.

Real processes over real UDP: ``mrswarm fcu`` and ``mrswarm preflight --json``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONUNBUFFERED="1")
GCS_FAILSAFE = {"px4": "NAV_DLL_ACT=2", "ardupilot": "FS_GCS_ENABLE=1"}


@contextmanager
def fcu(*args: str) -> Iterator[str]:
    p = subprocess.Popen([sys.executable, "-m", "mrswarm", "fcu", "--listen", "127.0.0.1:0", "--duration", "60", *args],
                         cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ENV)
    try:
        line = p.stdout.readline()  # type: ignore[union-attr]
        assert line.startswith("LISTEN"), line
        yield line.split()[2]
    finally:
        p.terminate()
        p.wait(10)


def preflight(addr: str, *args: str, timeout: float = 5.0) -> tuple[int, dict[str, dict[str, Any]]]:
    out = subprocess.run([sys.executable, "-m", "mrswarm", "preflight", "--fcu", f"udpout:{addr}", "--listen", "7",
                          "--timeout", str(timeout), "--json", *args],
                         cwd=ROOT, capture_output=True, text=True, env=ENV, timeout=60)
    data = json.loads(out.stdout)
    assert data["ok"] == (out.returncode == 0), out.stdout
    return out.returncode, {c["name"]: c for c in data["checks"]}


@pytest.mark.parametrize("flavour", ["px4", "ardupilot"])
def test_the_gcs_link_loss_failsafe_fails_at_factory_defaults_and_passes_once_set(flavour: str) -> None:
    streams = ["--set-streams"] if flavour == "ardupilot" else []  # a factory ArduPilot streams nothing unasked
    with fcu("--flavour", flavour) as addr:
        rc, checks = preflight(addr, *streams)
        assert rc == 1
        gcs = checks["GCS link loss"]
        assert gcs["result"] == "fail" and GCS_FAILSAFE[flavour].split("=")[0] in gcs["fix"]
        assert checks["heartbeat"]["result"] == "pass" and checks["commands answered"]["result"] == "pass"
        assert checks["autopilot"]["found"].startswith("PX4 1." if flavour == "px4" else "ArduCopter 4.")
        for name in ("GLOBAL_POSITION_INT", "GPS", "position", "pre-arm checks", "companion link loss"):
            assert checks[name]["result"] == "pass", checks[name]
    with fcu("--flavour", flavour, "--param", GCS_FAILSAFE[flavour]) as addr:
        rc, checks = preflight(addr, *streams)
        assert checks["GCS link loss"]["result"] == "pass", checks["GCS link loss"]
        assert rc == 0, [c for c in checks.values() if c["result"] == "fail"]


def test_a_stream_the_autopilot_does_not_send_fails_unless_asked_for() -> None:
    """ArduCopter at its factory defaults streams nothing unasked (its MAV1_* rates are 0)."""
    with fcu("--flavour", "ardupilot", "--param", "FS_GCS_ENABLE=1") as addr:
        rc, checks = preflight(addr)
        assert rc == 1
        gpi = checks["GLOBAL_POSITION_INT"]
        assert gpi["result"] == "fail" and "--set-streams" in gpi["fix"] and "MAV1_POSITION=10" in gpi["fix"]
        assert checks["position"]["result"] == "fail"
        rc, checks = preflight(addr, "--set-streams")
        assert checks["GLOBAL_POSITION_INT"]["result"] == "pass" and checks["position"]["result"] == "pass"
        assert rc == 0, [c for c in checks.values() if c["result"] == "fail"]


def test_no_autopilot_fails_the_heartbeat_naming_the_link_to_check() -> None:
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))  # a port nobody answers on
    try:
        rc, checks = preflight(f"127.0.0.1:{s.getsockname()[1]}", timeout=1.0)
    finally:
        s.close()
    assert rc == 1 and list(checks) == ["heartbeat"]
    assert checks["heartbeat"]["result"] == "fail" and "SERIALn_PROTOCOL" in checks["heartbeat"]["fix"]


def test_a_bad_url_is_a_usage_error() -> None:
    out = subprocess.run([sys.executable, "-m", "mrswarm", "preflight", "--fcu", "udpout:nowhere"],
                         cwd=ROOT, capture_output=True, text=True, env=ENV, timeout=30)
    assert out.returncode == 2 and "--fcu" in out.stderr and "Traceback" not in out.stderr
