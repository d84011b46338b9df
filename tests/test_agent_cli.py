"""``mrswarm agent``'s command line as a field user types it: southern and western sites, one-line usage
errors naming the flag (exit 2, no traceback), folders made, and ``--config`` as ``mrswarm run`` writes it
for a companion computer."""

from __future__ import annotations

import logging
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from groundfloor.process import setup_logging
from mrswarm.gcs.cli import build_parser
from mrswarm.scenario import load_scenario
from uav_stack.cli_args import ArgumentParser, join_dash_values
from uav_stack.config import NetworkConfig, fcu_url_problem
from uav_stack.runtime import parse_agent

ROOT = Path(__file__).resolve().parents[1]
BASE = ["--fcu", "udpin:127.0.0.1:14540", "--swarm", "alpha", "--uav", "3", "--connect", "tcp/127.0.0.1:7447", "--insecure"]


def usage_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one line ``mrswarm agent`` prints for a usage error (exit code 2)."""
    with pytest.raises(SystemExit) as ex:
        parse_agent(argv)
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err


def test_a_southern_and_western_origin_is_typed_as_the_docs_write_it() -> None:
    cfg, _ = parse_agent([*BASE, "--origin", "-35.36,149.16,584"])
    assert (cfg.origin.lat, cfg.origin.lon, cfg.origin.alt) == (-35.36, 149.16, 584.0)
    cfg, _ = parse_agent([*BASE, "--origin", "-22.9,-43.2,10"])  # Rio: both negative
    assert (cfg.origin.lat, cfg.origin.lon) == (-22.9, -43.2)
    cfg, _ = parse_agent([*BASE, "--origin=-35.36,149.16,584"])  # the = form still works
    assert cfg.origin.lat == -35.36


def test_only_values_are_joined_to_their_option_never_flags_or_positionals() -> None:
    ap = ArgumentParser(prog="x")
    ap.add_argument("--geo")
    ap.add_argument("--all", action="store_true")
    ap.add_argument("xyz", nargs="*", type=float)
    assert join_dash_values(ap, ["--geo", "-33.9,151.2,50"]) == ["--geo=-33.9,151.2,50"]
    assert join_dash_values(ap, ["--all", "-20", "5", "10"]) == ["--all", "-20", "5", "10"]  # a flag, then numbers
    assert join_dash_values(ap, ["--geo", "--all"]) == ["--geo", "--all"]  # a missing value stays missing
    assert join_dash_values(ap, ["--", "--geo", "-1"]) == ["--", "--geo", "-1"]
    a = ap.parse_args(["--all", "-20", "-5", "10"])
    assert a.all and a.xyz == [-20.0, -5.0, 10.0]
    g = build_parser().parse_args(["goto", "--uav", "3", "--geo", "-33.86,151.21,40"])  # the ground station's too
    assert g.geo == "-33.86,151.21,40"


@pytest.mark.parametrize("argv,flag", [
    (["--swarm", "alpha", "--uav", "3", "--origin", "47,8,500", "--insecure", "--connect", "tcp/127.0.0.1:1"],
     "--fcu is required"),
    ([*BASE[:6], "--insecure", "--origin", "-35.36,149.16,584"], "no way to the swarm: give --connect"),
    ([*BASE, "--origin", "-95,149.16,584"], "--origin -95,149.16,584: latitude -95 is outside -90..90"),
    ([*BASE, "--origin", "47,8"], "--origin 47,8: expected LAT,LON,ALT"),
    ([*BASE, "--origin"], "argument --origin: expected one argument"),
    ([*BASE, "--origin", "47,8,500", "--uav", "0"], "--uav: must be an integer in [1, 65535]"),
    ([*BASE, "--origin", "47,8,500", "--swarm", "no spaces"], "--swarm: must be a string matching"),
    ([*BASE, "--origin", "47,8,500", "--fcu", "com9:57600"], "--fcu com9:57600: unknown scheme 'com9:'"),
    ([*BASE, "--origin", "47,8,500", "--fcu", "udpin:127.0.0.1:x"], "--fcu udpin:127.0.0.1:x: port 'x' is not a port number"),
    ([*BASE, "--origin", "47,8,500", "--connect", "edge-server:7447"], "--connect edge-server:7447: not a Zenoh endpoint"),
    ([*BASE, "--origin", "47,8,500", "--listen", "0.0.0.0"], "--listen 0.0.0.0: not a Zenoh endpoint"),
    ([*BASE[:-1], "--origin", "47,8,500"], "no credentials: give --keys DIR"),
    ([*BASE[:-1], "--origin", "47,8,500", "--keys", "/nonexistent/uav-3"], "--keys: /nonexistent/uav-3/ca.pem missing"),
    ([*BASE, "--origin", "47,8,500", "--discovery", "127.0.0.1:7450"], "--discovery needs --discovery-key-file"),
    ([*BASE, "--origin", "47,8,500", "--mavlink-endpoint", "tcp:1.2.3.4:5"], "--mavlink-endpoint"),
    (["--config", "/nonexistent/uav3.json"], "--config /nonexistent/uav3.json: cannot read it: No such file or directory"),
    (["--config", "/nonexistent/uav3.json", "--uav", "4"], "--uav: the --config file sets it"),
])
def test_every_mistake_is_one_usage_line_naming_the_flag(argv: list[str], flag: str, capsys: pytest.CaptureFixture[str]) -> None:
    err = usage_error(argv, capsys)
    assert err.startswith("mrswarm agent: error: ") and flag in err, err


def test_mrswarm_agent_without_a_way_to_the_swarm_exits_2_with_one_line_not_a_traceback() -> None:
    res = subprocess.run([sys.executable, "-m", "mrswarm", "agent", "--fcu", "udpin:127.0.0.1:14540", "--swarm", "alpha",
                          "--uav", "1", "--origin", "-35.36,149.16,584", "--insecure"],
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines() == [res.stderr.strip()] and "Traceback" not in res.stderr
    assert "--connect" in res.stderr and "--discovery" in res.stderr


def test_the_record_dir_is_made_and_one_that_cannot_be_is_a_usage_error(tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    rec = tmp_path / "flights" / "2026" / "uav3"
    cfg, _ = parse_agent([*BASE, "--origin", "47,8,500", "--record-dir", str(rec)])
    assert rec.is_dir() and cfg.record_dir == str(rec)
    (tmp_path / "file").write_text("in the way")
    err = usage_error([*BASE, "--origin", "47,8,500", "--record-dir", str(tmp_path / "file" / "uav3")], capsys)
    assert f"--record-dir {tmp_path / 'file' / 'uav3'}: cannot make it: Not a directory" in err


def test_a_companions_config_file_runs_with_its_own_fcu_keys_and_record_dir(tmp_path: Path,
                                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """What ``mrswarm run`` writes for a companion's agent (``agent: companion``) is what ``--config`` reads; the
    companion's own flight controller and record folder go beside it."""
    scn = load_scenario(ROOT / "scenarios" / "head_on_external.yaml", ["uavs.0.agent=companion"])
    net = NetworkConfig(endpoints=("tcp/127.0.0.1:7447",), mode="client")
    cfg = scn.external_agent_configs(net, "/runs/x")[0]
    assert cfg.uav == 1 and cfg.realm == "physical" and cfg.fcu == "udpin:127.0.0.1:14540"
    assert cfg.record_dir is None  # a companion records on its own computer, where its --record-dir says
    path = tmp_path / "uav1.json"
    path.write_text(cfg.to_json())
    got, _ = parse_agent(["--config", str(path), "--insecure"])
    assert got == cfg
    rec = tmp_path / "rec"
    got, _ = parse_agent(["--config", str(path), "--insecure", "--fcu", "serial:/dev/ttyACM0:921600", "--record-dir", str(rec)])
    assert got.fcu == "serial:/dev/ttyACM0:921600" and got.record_dir == str(rec) and rec.is_dir()
    assert got.mission == cfg.mission and got.network == cfg.network
    err = usage_error(["--config", str(path)], capsys)  # its run was secured: it needs --keys, or the run's --insecure
    assert "no credentials: give --keys DIR" in err


def test_fcu_connection_strings() -> None:
    for ok in ("udpin:127.0.0.1:14540", "udpout:192.0.2.7:14580", "tcp:127.0.0.1:5760", "serial:/dev/ttyACM0:921600",
               "serial:/dev/ttyUSB0", "/dev/ttyAMA0"):
        assert fcu_url_problem(ok) == "", ok
    for bad, what in (("", "empty"), ("127.0.0.1:14540", "unknown scheme"), ("udpin:14540", "HOST:PORT"),
                      ("tcp:127.0.0.1:99999", "not a port number"), ("serial:", "no serial device")):
        assert what in fcu_url_problem(bad), bad


def test_the_folders_a_field_user_names_are_made(tmp_path: Path) -> None:
    """The key directory and a UAV's bundle (``mrswarm keys``), and the agent's log file, each in folders that do
    not exist yet."""
    from mrswarm.cli.keys import main as keys_main

    kd = tmp_path / "lab" / "keys" / "alpha"
    assert keys_main(["init", "--swarm", "alpha", "--dir", str(kd)]) == 0
    assert keys_main(["issue", "--dir", str(kd), "uav-3"]) == 0
    usb = tmp_path / "media" / "usb" / "uav-3"
    assert keys_main(["bundle", "--dir", str(kd), "uav-3", "--out", str(usb)]) == 0
    assert {p.name for p in usb.iterdir()} == {"ca.pem", "roster.json", "uav-3.alpha.pem", "uav-3.alpha.key",
                                               "uav-3.alpha.beacon", "mavlink.key"}
    cfg, _ = parse_agent([*BASE[:-1], "--origin", "47,8,500", "--keys", str(usb)])  # the bundle is what the agent takes
    assert cfg.network.security is not None and cfg.network.security.keys == str(usb)
    log = tmp_path / "var" / "log" / "mrswarm" / "uav3.log"
    root = logging.getLogger()
    saved = root.handlers[:]
    root.handlers = []
    try:
        setup_logging("INFO", str(log))
        logging.getLogger("uav_stack.test").info("hello")
        for h in root.handlers:
            h.flush()
    finally:
        for h in root.handlers:
            h.close()
        root.handlers = saved
    assert "hello" in log.read_text()


def test_a_swarm_the_agent_cannot_join_is_one_error_line_not_a_traceback() -> None:
    """Past the usage checks: a listen address that is not this machine's (TEST-NET-1, nothing is sent) fails the node."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    res = subprocess.run([sys.executable, "-m", "mrswarm", "agent", "--fcu", f"udpin:127.0.0.1:{port}", "--swarm", "alpha",
                          "--uav", "1", "--origin", "-35.36,149.16,584", "--insecure", "--connect", "tcp/127.0.0.1:9",
                          "--listen", "tcp/192.0.2.1:7447"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 1, res.stderr
    assert "ERROR uav_stack.runtime: network: cannot join swarm 'alpha' through tcp/127.0.0.1:9" in res.stderr, res.stderr
    assert "Traceback" not in res.stderr
