"""Helpers for the ground-station tests: a virtual UAV process with a MAVLink router, run dirs."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from uav_stack.config import AgentConfig, GcsConfig, MavlinkSigning, MissionConfig, NetworkConfig, VirtualUavConfig
from uav_stack.geo import GeoPoint

ROOT = Path(__file__).resolve().parents[1]
HOME = GeoPoint(47.397742, 8.545594, 488.0)


def start_virtual_uav(tmp: Path, router_endpoint: str, *, uav: int = 1, endpoints: tuple[str, ...] = (),
                      flavour: str = "px4", autostart: bool = False, swarm: str = "gcs",
                      area: tuple[float, float, float, float] = (-40.0, 40.0, -40.0, 40.0),
                      signing: MavlinkSigning | None = None, allow_unsigned: bool = False) -> subprocess.Popen[bytes]:
    """One virtual UAV process (virtual FCU + agent, as the runtimes launch it) whose router sends to ``endpoints``,
    taking commands signed with ``signing``'s key (None: no key, telemetry only) or, with ``allow_unsigned``, any."""
    agent = AgentConfig(
        swarm=swarm, uav=uav, origin=HOME, fcu="", altitude=8.0, autostart=autostart, record_dir=str(tmp),
        mission=MissionConfig(area=area), network=NetworkConfig(endpoints=(router_endpoint,), mode="client"),
        gcs=GcsConfig(mavlink_endpoints=endpoints, signing=signing or MavlinkSigning(), allow_unsigned=allow_unsigned),
    )
    cfg = VirtualUavConfig(agent=agent, home=HOME, flavour=flavour)
    path = tmp / f"uav{uav}.config.json"
    path.write_text(cfg.to_json())
    with open(tmp / f"uav{uav}.log", "ab") as log:  # the child keeps its own copy of the descriptor
        return subprocess.Popen([sys.executable, "-m", "uav_stack.virtual_uav", "--config", str(path), "--log-level", "INFO"],
                                cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def mavproxy_args(mavproxy: str, port: int, passphrase: str | None) -> tuple[list[str], dict[str, str]]:
    """MAVProxy's command line (and environment) as a ground station on the UAV router endpoint at ``port``,
    signing with ``passphrase`` from its first frame (``signing key``: MAVLink 2 only, so MAVLINK20 is set)."""
    cmd = "set requireexit 0" + (f"; signing key {passphrase}" if passphrase is not None else "")
    return ([mavproxy, f"--master=udpout:127.0.0.1:{port}", "--no-state", f"--cmd={cmd}"],
            {**os.environ, "MAVLINK20": "1"})


def mavlink_passphrase(*where: str) -> str:
    """The passphrase ``mrswarm keys mavlink`` prints for ``where`` (``--run DIR`` or ``--dir DIR``)."""
    res = subprocess.run([sys.executable, "-m", "mrswarm", "keys", "mavlink", *where, "--json"], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    return str(json.loads(res.stdout)["passphrase"])


def stop_process(proc: subprocess.Popen[bytes] | subprocess.Popen[str], grace: float = 10.0) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            return
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)


def agent_stats(tmp: Path, uav: int) -> dict:
    return json.loads((tmp / f"uav{uav}.json").read_text())


def start_run(scenario: Path, out: Path, sets: list[str]) -> subprocess.Popen[str]:
    """`mrswarm run` in the background (its own process group); returns once it has started."""
    args = [sys.executable, "-m", "mrswarm", "run", str(scenario), "--out", str(out), "--no-live", "--log-level", "INFO"]
    for s in sets:
        args += ["--set", s]
    with open(out / "run.stdout", "a") as log:  # the child keeps its own copy of the descriptor
        return subprocess.Popen(args, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, text=True, start_new_session=True)


def stop_run(proc: subprocess.Popen[str], timeout: float = 60.0) -> None:
    """Ctrl-C (the runner then stops every UAV process), SIGKILL as a last resort."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
        except ProcessLookupError:
            pass


def run_dir(out: Path, timeout: float = 30.0) -> Path:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        dirs = [d for d in out.iterdir() if d.is_dir() and (d / "network.json").exists()]
        if dirs:
            return dirs[0]
        time.sleep(0.2)
    raise AssertionError(f"no run folder with network.json in {out}")


def gcs(args: list[str], timeout: float = 60.0, input: str | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mrswarm", "gcs", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout, input=input)
