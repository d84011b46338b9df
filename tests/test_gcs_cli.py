"""`mrswarm gcs` pieces that need no running swarm: ids, filters, sorting, layout, recordings, usage errors."""

from __future__ import annotations

import io
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from mrswarm.gcs.commands import confirm_kill, goto_args
from mrswarm.gcs.record import Recorder, plot_recording, read_recording
from mrswarm.gcs.session import GcsError, parse_ids, resolve_target
from mrswarm.gcs.watch import Filter, Row, fit_columns, sort_rows, split_keys
from mrswarm.results.wording import format_ids
from mrswarm.scenario import ScenarioError, load_scenario
from swarmnet.messages import AgentState, Pose, Realm, Telemetry

ROOT = Path(__file__).resolve().parents[1]


def test_id_lists() -> None:
    assert parse_ids("3") == [3]
    assert parse_ids("1,2,5-7, 7") == [1, 2, 5, 6, 7]
    assert format_ids([1, 2, 3, 7, 9, 10]) == "1-3,7,9-10"
    for bad in ("x", "5-2", "0", "70000", "", "1-"):
        with pytest.raises(GcsError):
            parse_ids(bad)


def test_filters_sorting_and_narrow_terminals() -> None:
    rows = [Row(1, phase="mission", mode="OFFBOARD", battery=0.5, seen=0.1),
            Row(2, phase="hold", override="hold", battery=0.9, seen=0.2),
            Row(3, phase="yielded", override="fcu:RTL", mode="RTL", seen=5.0),
            Row(10, realm="physical", phase="mission", seen=0.1)]
    f = Filter.parse(["phase=mission"])
    assert [r.id for r in rows if f.match(r)] == [1, 10]
    assert [r.id for r in rows if Filter.parse(["override"]).match(r)] == [2, 3]
    assert [r.id for r in rows if Filter.parse(["stale"]).match(r)] == [3]
    assert [r.id for r in rows if Filter.parse(["id=2-10", "realm=physical"]).match(r)] == [10]
    assert [r.id for r in rows if Filter.parse(["mode=rtl"]).match(r)] == [3]
    for bad in (["colour=red"], ["phase="], ["id=abc"]):
        with pytest.raises(GcsError):
            Filter.parse(bad)
    assert [r.id for r in sort_rows(rows, "battery")] == [1, 2, 3, 10]  # unknown values last
    assert [r.id for r in sort_rows(rows, "battery", reverse=True)] == [2, 1, 3, 10]
    assert [r.id for r in sort_rows(rows, "phase")] == [2, 1, 10, 3]
    with pytest.raises(GcsError):
        sort_rows(rows, "colour")
    assert fit_columns(200)[:3] == ["id", "R", "phase"]
    narrow = fit_columns(80)
    assert {"id", "phase", "override", "mode", "x", "y", "alt", "bat%", "age ms"} <= set(narrow)
    assert split_keys("q\x1b[6~s") == ["q", "PGDN", "s"]


def test_goto_args_and_kill_confirmation() -> None:
    assert goto_args([1.0, -2.0, 10.0]) == {"x": 1.0, "y": -2.0, "z": 10.0}
    with pytest.raises(GcsError):
        goto_args([1.0, math.nan, 10.0])
    assert goto_args([], "47.3977,8.5456,503") == {"lat": 47.3977, "lon": 8.5456, "alt": 503.0}  # degrees, m AMSL
    assert goto_args([], "-33.86,151.21,20")["lat"] == -33.86
    for bad in ("47.3,8.5", "47.3,8.5,x", "95,8.5,500", "47.3,200,500", "nan,8.5,500"):
        with pytest.raises(GcsError, match="--geo"):
            goto_args([], bad)
    with pytest.raises(GcsError, match="X Y Z"):
        goto_args([1.0, 2.0])
    assert confirm_kill([1], yes=True)
    with pytest.raises(GcsError, match="--yes"):
        confirm_kill([1], yes=False, stdin=io.StringIO("kill\n"))  # not a terminal


def test_recording_survives_a_torn_last_line_and_plots(tmp_path: Path) -> None:
    path = tmp_path / "rec.jsonl"
    t = [1000.0]
    rec = Recorder(path, clock=lambda: t[0])
    for i in range(50):
        t[0] += 0.1
        for u in (1, 2):
            rec("pose", Pose(u, Realm.VIRTUAL, i, i * 0.1, t[0], float(i), float(u * 5), 10.0, 1.0, 0.0, 0.0, 0.0))
        if i % 10 == 0:
            rec("telemetry", Telemetry(1, Realm.VIRTUAL, i, t[0], "OFFBOARD", True, 0.9 - i / 1000, 16.0, 47.0, 8.0, 500.0, 1.0))
            rec("state", AgentState(1, Realm.VIRTUAL, i, t[0], "hold" if i > 20 else "mission", "coverage",
                                    "hold" if i > 20 else ""))
        rec.maybe_flush()
    rec.close()
    with open(path, "a") as f:
        f.write('{"t": 1, "kind": "pose", "uav": 1, "x": 1')  # a crash mid-write
    lines = list(read_recording(path))
    assert len(lines) == 100 + 5 + 5
    assert lines[0]["kind"] == "pose" and lines[0]["realm"] == "virtual"
    out, info = plot_recording(path)
    assert out.exists() and out.stat().st_size > 10_000 and info["uavs"] == 2
    (tmp_path / "junk.jsonl").write_text("junk\n")
    with pytest.raises(ValueError, match="no recorded messages"):
        plot_recording(tmp_path / "junk.jsonl")


def test_recorder_flushes_within_a_second(tmp_path: Path) -> None:
    path = tmp_path / "r.jsonl"
    t = [0.0]
    rec = Recorder(path, clock=lambda: t[0])
    rec("joined", "mrs/a/alive/uav/1")
    rec.maybe_flush()
    assert path.read_text() == ""  # buffered...
    t[0] = 1.0
    rec.maybe_flush()
    assert json.loads(path.read_text())["kind"] == "joined"  # ...on disk a second later, without close()
    rec.close()


def test_where_is_the_swarm(tmp_path: Path) -> None:
    with pytest.raises(GcsError, match="--run RUN_DIR"):
        resolve_target(None, [], None)
    with pytest.raises(GcsError, match="network.json"):
        resolve_target(str(tmp_path), [], None)
    (tmp_path / "network.json").write_text(json.dumps({"swarm": "alpha", "endpoints": ["tcp/127.0.0.1:7447"]}))
    t = resolve_target(str(tmp_path), [], None)
    assert t.swarm == "alpha" and t.endpoints == ("tcp/127.0.0.1:7447",)
    with pytest.raises(GcsError, match="--swarm"):
        resolve_target(None, ["tcp/127.0.0.1:7447"], None)
    with pytest.raises(GcsError):
        resolve_target(None, ["127.0.0.1:7447"], "alpha")
    with pytest.raises(GcsError):
        resolve_target(None, ["tcp/127.0.0.1:7447"], "bad swarm!")


@pytest.mark.parametrize("args,needle", [
    (["hold", "--uav", "3"], "where is the swarm"),
    (["goto", "1", "nan", "3", "--uav", "1", "--connect", "tcp/127.0.0.1:1", "--swarm", "a"], "not a finite number"),
    (["watch", "--filter", "colour=red", "--connect", "tcp/127.0.0.1:1", "--swarm", "a"], "--filter"),
    (["watch", "--refresh", "1", "--connect", "tcp/127.0.0.1:1", "--swarm", "a"], "at least 2"),
    (["watch", "--filter", "phase=nosuch", "--connect", "tcp/127.0.0.1:1", "--swarm", "a"], "unknown phase"),
    (["goto", "--geo", "47.1,8.5", "--uav", "1", "--connect", "tcp/127.0.0.1:1", "--swarm", "a"], "LAT,LON,ALT"),
    (["goto", "1", "2", "3", "--geo", "47.1,8.5,500", "--uav", "1", "--connect", "tcp/127.0.0.1:1", "--swarm", "a"],
     "not both"),
    (["hold", "--uav", "1", "--connect", "tcp/127.0.0.1:1", "--swarm", "a"], "cannot reach the swarm"),
    (["plot", "/nonexistent/rec.jsonl"], "No such file"),
    (["nodes", "--connect", "tcp/127.0.0.1:1", "--swarm", "a", "--discovery", "127.0.0.1:7450"], "go together"),
    (["nodes", "--connect", "tcp/127.0.0.1:1", "--swarm", "a", "--discovery", "127.0.0.1:7450",
      "--discovery-key-file", "/nonexistent/keys"], "--discovery-key-file"),
])
def test_cli_usage_errors_exit_2_with_one_line(args: list[str], needle: str) -> None:
    res = subprocess.run([sys.executable, "-m", "mrswarm", "gcs", *args], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2, res.stdout + res.stderr
    assert needle in res.stderr and "Traceback" not in res.stderr


def test_scenario_gcs_section(tmp_path: Path) -> None:
    mini = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"
    s = load_scenario(mini, ["gcs.mavlink=true", "gcs.listen_base=20000", "fleet.first_id=239", "fleet.flavour=ardupilot"])
    from uav_stack.config import NetworkConfig

    cfgs = s.virtual_uav_configs(NetworkConfig(), None)
    eps = {c.agent.uav: c.agent.gcs.mavlink_endpoints for c in cfgs}
    assert eps[239] == ("udpout:127.0.0.1:14550", "udpin:127.0.0.1:20239")
    assert eps[241] == ("udpout:127.0.0.1:14551", "udpin:127.0.0.1:20241")  # the second 240-UAV network
    assert {c.agent.mavlink_sysid for c in cfgs} == {239, 240, 1, 2}
    assert all(c.flavour == "ardupilot" for c in cfgs)
    assert cfgs[0].agent.gcs.geofence == (-30.0, 30.0, -20.0, 20.0)  # the mission area
    # on by default, to a ground station on this machine (QGroundControl's UDP 14550); off on request
    default = load_scenario(mini)
    assert default.virtual_uav_configs(NetworkConfig(), None)[0].agent.gcs.mavlink_endpoints == ("udpout:127.0.0.1:14550",)
    assert not default.gcs.landing_ends_run  # a ground station landing everyone does not end the run
    off = load_scenario(mini, ["gcs.mavlink=false"])
    assert off.virtual_uav_configs(NetworkConfig(), None)[0].agent.gcs.mavlink_endpoints == ()
    with pytest.raises(ScenarioError, match="listen_base"):
        load_scenario(mini, ["gcs.mavlink=true", "gcs.listen_base=65534"])
    with pytest.raises(ScenarioError, match="flavour"):
        load_scenario(mini, ["fleet.flavour=betaflight"])


def test_node_list_merges_liveliness_with_the_discovery_registry(tmp_path: Path) -> None:
    from mrswarm.gcs.directory import NodeInfo, merge

    live = [NodeInfo(1, "uav", "virtual", last_seen=100.0), NodeInfo(2, "uav", alive=True), NodeInfo(9, "gcs")]
    reg = [NodeInfo(1, "uav", "virtual", "mrswarm/0.1.0", "tcp/127.0.0.1:4001", last_seen=50.0),
           NodeInfo(2, "uav", "physical", "mrswarm/0.1.0", "tcp/10.0.0.2:7447", last_seen=60.0),
           NodeInfo(3, "uav", "virtual", "mrswarm/0.1.0", "tcp/127.0.0.1:4003", last_seen=70.0)]
    got = {(n.role, n.id): n for n in merge(live, reg)}
    assert [k for k in got] == [("uav", 1), ("uav", 2), ("uav", 3), ("gcs", 9)]
    assert got[("uav", 1)].version == "mrswarm/0.1.0" and got[("uav", 1)].address == "tcp/127.0.0.1:4001"
    assert got[("uav", 1)].last_seen == 100.0  # this machine's clock wins over the server's
    assert got[("uav", 2)].realm == "physical" and got[("uav", 2)].last_seen == 60.0
    assert got[("uav", 3)].alive and got[("gcs", 9)].version == "-"
    # a discovery run's folder names its server and key file; the ground station picks them up
    (tmp_path / "discovery.keys").write_text("alpha k3y\n")
    (tmp_path / "network.json").write_text(json.dumps({"swarm": "alpha", "endpoints": ["tcp/127.0.0.1:7447"],
                                                       "discovery": {"server": "127.0.0.1:7450", "key_file": "discovery.keys"}}))
    t = resolve_target(str(tmp_path), [], None)
    assert t.discovery == ("127.0.0.1:7450", "k3y") and t.endpoints == ("tcp/127.0.0.1:7447",)


def test_a_phase_filter_takes_the_agents_phase_names_only() -> None:
    assert Filter.parse(["phase=Landed"]).phase == "landed"
    with pytest.raises(GcsError, match=r"unknown phase .*mission"):  # a typo gets the list of names
        Filter.parse(["phase=misson"])


def test_telemetry_lines_do_not_wrap_in_a_pipe() -> None:
    from rich.console import Console

    from mrswarm.gcs.cli import _print_telemetry

    buf = io.StringIO()
    console = Console(file=buf)  # not a terminal: rich would wrap at 80 columns
    rec = {"uav": 12, "phase": "yielded", "override": "gcs:DO_REPOSITION", "mode": "OFFBOARD", "armed": True, "x": -123.4,
           "y": 456.7, "z": 15.0, "speed": 4.9, "battery": 0.87, "rtf": 0.98, "pose_age_ms": 12.0}
    for _ in range(3):
        _print_telemetry(rec, False, console)
    lines = buf.getvalue().splitlines()
    assert len(lines) == 3 and all(len(line) > 80 for line in lines), lines
    assert lines[0].startswith("uav 12 phase=yielded") and lines[0].endswith("pose_age_ms=12")


def test_nodes_are_listed_in_full_without_a_terminal() -> None:
    from rich.console import Console

    from mrswarm.gcs.cli import nodes_table, print_table
    from mrswarm.gcs.directory import NodeInfo

    address = "tcp/127.0.0.1:41234,tcp/10.0.0.5:41234,tcp/[fe80::1]:41234,tcp/192.168.100.200:41234"
    nodes = [NodeInfo(1, "uav", "virtual", "mrswarm/0.1.0", address, last_seen=100.0),
             NodeInfo(2, "uav", "physical", "mrswarm/0.1.0", "tcp/10.0.0.2:7447", last_seen=99.0)]
    buf = io.StringIO()
    console = Console(file=buf)  # a pipe: rich assumes 80 columns
    print_table(console, nodes_table("alpha", nodes, 101.0))
    out = buf.getvalue()
    assert address in out and "…" not in out, out  # the IPv6 [..] is text, not markup
    assert "mrswarm/0.1.0" in out and "1.0 s ago" in out
    assert console.width == 80  # the console is left as it was


def test_recording_plot_says_which_colour_is_which_uav(tmp_path: Path) -> None:
    from mrswarm.gcs.record import draw_recording

    path = tmp_path / "rec.jsonl"
    rec = Recorder(path, clock=lambda: 1000.0)
    for i in range(10):
        for u in (3, 1, 2):
            rec("pose", Pose(u, Realm.VIRTUAL, i, i * 0.1, 1000.0 + i, float(i), float(u * 5), 10.0, 1.0, 0.0, 0.0, 0.0))
    rec.close()
    fig, info = draw_recording(path)
    ax = fig.axes[0]
    legend = ax.get_legend()
    assert legend is not None and [t.get_text() for t in legend.get_texts()] == ["UAV 1", "UAV 2", "UAV 3"]
    colours = {line.get_label(): line.get_color() for line in ax.get_lines() if line.get_label().startswith("UAV")}
    assert len(set(colours.values())) == 3  # one colour each
    assert sorted(t.get_text() for t in ax.texts) == ["1", "2", "3"]  # and each track ends in its id


def test_record_exits_130_on_ctrl_c_with_everything_written(tmp_path: Path, router: str) -> None:
    import signal
    import time

    out = tmp_path / "rec.jsonl"
    proc = subprocess.Popen([sys.executable, "-m", "mrswarm", "gcs", "record", str(out), "--connect", router, "--swarm", "ctrlc"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        while not out.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.1)
        assert out.exists(), proc.stderr.read() if proc.poll() is not None else "no recording file"  # type: ignore[union-attr]
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)  # what Ctrl-C sends
        stdout, stderr = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    assert proc.returncode == 130, stdout + stderr
    assert "recorded" in stdout and "Traceback" not in stderr


def test_watch_says_when_the_run_it_watches_has_ended(tmp_path: Path) -> None:
    """`gcs watch --run DIR` reads the run's run.json: once the runner has stopped, the view says so, and where
    its summary is."""
    import time

    from rich.console import Console

    from mrswarm.gcs.watch import WatchView
    from mrswarm.records.summary import RunInfo
    from swarmnet.connectivity import Rendezvous
    from swarmnet.observer import SwarmObserver

    obs = SwarmObserver("alpha", Rendezvous(("tcp/127.0.0.1:1",), mode="client"))  # never opened: nothing heard
    view = WatchView("alpha", run_dir=tmp_path)

    def shown(now: float) -> str:
        console = Console(width=200, record=True, file=io.StringIO())
        console.print(view.render(obs, now, 40, 200))
        return console.export_text()

    now = time.time()
    RunInfo(scenario="coverage", started=now - 60).write(tmp_path / "run.json")
    assert "has ended" not in shown(now)
    RunInfo(scenario="coverage", started=now - 60, stopped=now + 1.0).write(tmp_path / "run.json")
    text = shown(now + 6.0)
    assert "the run has ended (5 s ago" in text and "summary is being written" in text
    (tmp_path / "summary.json").write_text("{}")
    assert f"summary: {tmp_path / 'summary.json'}" in shown(now + 8.0)
