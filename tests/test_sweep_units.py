"""``mrswarm sweep`` without flying: the statistics against scipy, the campaign file's validation (the bad field
named, exit 2), the slots' states on disk, the schedule's capacity rules, and the tables from a campaign folder."""

from __future__ import annotations

import json
import math
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats as sps

from mrswarm.cli import main
from mrswarm.scenario import load_scenario, parse_override
from mrswarm.sweep.campaign import Cell, override_text, parse_campaign, plan_campaign, value_label
from mrswarm.sweep.capacity import SETTLE_S, Capacity, Need
from mrswarm.sweep.slots import SlotRecord, SlotState, status, write_record
from mrswarm.sweep.stats import summarise, t_quantile, t_two_sided
from mrswarm.sweep.table import collect, metric_problem, runs_csv
from tests.conftest import wait_for

ROOT = Path(__file__).resolve().parents[1]
MINI = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"


# ---- statistics ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("df", [*range(1, 41), 57, 100, 999, 1000, 1001, 5000, 100_000])
def test_t_quantile_matches_scipy(df: int) -> None:
    for p in (0.6, 0.9, 0.95, 0.975, 0.995, 0.9995, 0.025):
        assert t_quantile(p, df) == pytest.approx(sps.t.ppf(p, df), rel=1e-10, abs=1e-12)


def test_t_distribution_function_matches_scipy() -> None:
    for df in (1, 2, 3, 4, 7, 30, 200):
        for t in (0.0, 0.3, 1.0, 2.2, 9.0):
            assert t_two_sided(t, df) == pytest.approx(sps.t.cdf(t, df) - sps.t.cdf(-t, df), abs=1e-13)


def test_summary_of_a_cell_matches_numpy_and_scipy() -> None:
    rng = np.random.default_rng(45)
    for n in (2, 3, 5, 10, 31):
        xs = rng.normal(40.0, 6.0, n)
        s = summarise(list(xs))
        lo, hi = sps.t.interval(0.95, n - 1, loc=xs.mean(), scale=sps.sem(xs))
        assert (s.runs, s.n) == (n, n)
        assert s.mean == pytest.approx(xs.mean(), rel=1e-12)
        assert s.median == pytest.approx(np.median(xs), rel=1e-12)
        assert s.std == pytest.approx(xs.std(ddof=1), rel=1e-12)
        assert (s.ci_low, s.ci_high) == (pytest.approx(lo, rel=1e-10), pytest.approx(hi, rel=1e-10))
    s = summarise([1.0, 2.0, 4.0], level=0.9)
    assert (s.ci_low, s.ci_high) == tuple(pytest.approx(v) for v in sps.t.interval(0.9, 2, loc=7 / 3, scale=sps.sem([1, 2, 4])))


def test_missing_values_are_counted_but_left_out_of_the_statistics() -> None:
    s = summarise([30.0, None, 34.0, float("nan")])
    assert (s.runs, s.n, s.mean, s.median) == (4, 2, 32.0, 32.0)
    one = summarise([5.0, None])
    assert (one.n, one.mean, one.ci_low, one.ci_high, one.half_width) == (1, 5.0, None, None, None)
    none = summarise([None, None])
    assert (none.runs, none.n, none.mean) == (2, 0, None)


# ---- the campaign file ---------------------------------------------------------------------------------------
def _campaign(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "campaign.yaml"
    path.write_text(f"scenario: {MINI}\n" + body)
    return path


@pytest.mark.parametrize(("body", "said"), [
    ("gird: {fleet.count: [2, 3]}\n", "campaign.yaml: gird: unknown field (expected one of:"),
    ("grid: {fleet.count: []}\n", "grid.fleet.count: must be a list of length >= 1"),
    ("grid: {fleet.count: [2, 2]}\n", "grid.fleet.count: the value 2 is listed twice"),
    ("seeds: 0\n", "seeds: must be an integer in [1, 1000], got 0"),
    ("grid: {seed: [1, 2]}\n", "grid.seed: the seeds come from `seeds`"),
    ("set: {fleet.count: 2}\ngrid: {fleet.count: [2, 3]}\n", "grid.fleet.count: also in `set`"),
    ("grid: {fleet.count: [2, 0]}\n", f"grid.fleet.count = 0: {MINI}: fleet.count: must be an integer in [1, 1000], got 0"),
    ("grid: {flight.sped: [1, 2]}\n", "grid.flight.sped = 1: " + str(MINI) + ": flight.sped: unknown field"),
    ("set: {flight.speed: 99}\n", "set.flight.speed = 99: " + str(MINI) + ": flight.speed: must be a number in (0, 15]"),
    ("grid: {'fleet count': [1]}\n", "grid: 'fleet count' is not a scenario field's key"),
    ("metrics: [coverage.time_to_91_s]\n", "metrics.0: coverage.time_to_91_s: coverage has no 'time_to_91_s'"),
    ("grid: {fleet.count: [2, 3]}\nx: flight.speed\n", "x: flight.speed is not a grid key"),
    ("parallel: lots\n", "parallel:"),
])
def test_a_bad_campaign_names_the_field_and_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], body: str,
                                                    said: str) -> None:
    path = _campaign(tmp_path, body)
    assert main(["sweep", str(path), "--out", str(tmp_path / "out"), "--no-live"]) == 2
    err = capsys.readouterr().err.replace("\n", "")
    assert said in err
    assert "Traceback" not in err
    assert not (tmp_path / "out" / "runs").exists()  # nothing flown


def test_flags_make_a_campaign_and_bad_flags_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main(["sweep", str(MINI), "--grid", "fleet.count=2,3", "--seeds", "7,11", "--set", "duration=5", "--out", str(out),
                 "--plan"]) == 0
    shown = capsys.readouterr().out
    for label in ("fleet.count=2 seed=7", "fleet.count=3 seed=7", "fleet.count=2 seed=11", "fleet.count=3 seed=11"):
        assert label in shown
    assert main(["sweep", str(MINI), "--out", str(out)]) == 2
    assert "give --grid" in capsys.readouterr().err
    assert main(["sweep", str(MINI), "--grid", "fleet.count", "--out", str(out)]) == 2
    assert "expected key.path=value1,value2" in capsys.readouterr().err
    assert main(["sweep", str(MINI), "--seeds", "many", "--out", str(out)]) == 2
    assert "--seeds 'many'" in capsys.readouterr().err
    assert main(["sweep", "--report", str(tmp_path / "nowhere")]) == 2
    assert "not a campaign folder" in capsys.readouterr().err


def test_an_external_autopilot_is_refused_for_parallel_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scenario = ROOT / "scenarios" / "head_on_external.yaml"
    assert main(["sweep", str(scenario), "--seeds", "2", "--parallel", "2", "--out", str(tmp_path / "out"), "--no-live"]) == 2
    err = capsys.readouterr().err.replace("\n", " ")
    assert "uavs.0.fcu: UAV 1's flight controller is external" in err
    assert "--parallel 1" in err


def test_the_plan_flies_every_cell_at_a_seed_before_the_next_seed_with_the_overrides_as_run_would_read_them() -> None:
    c = parse_campaign({"scenario": str(MINI), "set": {"duration": 5},
                        "grid": {"fleet.count": [2, 3], "network.netem.preset": [None, "lte"]}, "seeds": [4, 9]}, "t")
    plan = plan_campaign(c, None)
    assert [(s.cell.values["fleet.count"], s.cell.values["network.netem.preset"], s.seed) for s in plan.slots] == [
        (2, None, 4), (2, "lte", 4), (3, None, 4), (3, "lte", 4), (2, None, 9), (2, "lte", 9), (3, None, 9), (3, "lte", 9)]
    s = plan.slots[1]
    assert s.overrides == ("duration=5", "fleet.count=2", 'network.netem.preset="lte"', "seed=4")
    scn = load_scenario(MINI, list(s.overrides))  # what the child `mrswarm run` is given
    assert (scn.duration, len(scn.uav_list()), scn.seed) == (5, 2, 4)
    assert scn.network.netem is not None and scn.network.netem.preset == "lte"
    assert s.scenario == scn
    assert len({x.digest for x in plan.slots}) == 8
    assert len({x.name for x in plan.slots}) == 8
    assert plan.slots[0].name == "count-2_preset-null_seed-4"


@pytest.mark.parametrize("value", [5, 2.5, "lte", "5g-campus", None, True, "yes", "1e3", [1, 2], {"preset": "lte", "seed": 3}])
def test_override_texts_read_back_as_the_same_value(value: object) -> None:
    assert parse_override(override_text("a.b", value)) == ("a.b", value)


def test_cell_folders_are_readable_and_distinct() -> None:
    assert Cell(0, {"fleet.count": 5, "network.netem.preset": "lte"}).slug == "count-5_preset-lte"
    assert Cell(0, {"fleet.rtf": 0.5, "uavs.0.rtf": 0.4}).slug == "fleet.rtf-0.5_uavs.0.rtf-0.4"
    a, b = Cell(0, {"mission.area": {"x_min": 0}}), Cell(1, {"mission.area": {"x_min": 1}})
    assert a.slug != b.slug and "/" not in a.slug and " " not in a.slug
    assert value_label(None) == "null" and value_label({"b": 1, "a": 2}) == '{"a":2,"b":1}'


def test_metric_paths_are_checked_against_summary_json() -> None:
    for ok in ("coverage.time_to_90_s", "rtf.mean", "rtf.per_uav.3", "network.netem.total.delay_ms.p99", "incidents",
               "separation.collisions", "cpu_cores", "network.messages_sent.pose"):
        assert metric_problem(ok) == "", ok
    assert "summary.json has no 'coverge'" in metric_problem("coverge.final")
    assert "not a number" in metric_problem("network.transport_age_ms")
    assert "is a float, not a section" in metric_problem("rtf.mean.x")


# ---- slots on disk ------------------------------------------------------------------------------------------
def _run_folder(slot: Path, name: str, summary: dict[str, object] | None, started: float) -> Path:
    d = slot / name
    d.mkdir(parents=True)
    (d / "run.json").write_text(json.dumps({"scenario": "mini", "started": started}))
    (d / "scenario.yaml").write_text(yaml.safe_dump({"mission": {"type": "coverage"}}))
    if summary is not None:
        (d / "summary.json").write_text(json.dumps(summary))
    return d


def test_a_slot_is_complete_only_with_a_summary_of_a_run_that_was_not_interrupted(tmp_path: Path) -> None:
    slot = tmp_path / "runs" / "count-2_seed-0"
    slot.mkdir(parents=True)
    assert status(slot).state == SlotState.PENDING
    _run_folder(slot, "mini-1", None, 100.0)  # runner killed outright: no summary
    _run_folder(slot, "mini-2", {"interrupted": True, "aborted": None}, 200.0)
    st = status(slot)
    assert (st.state, st.attempts, st.interrupted) == (SlotState.PENDING, 2, 2)
    _run_folder(slot, "mini-3", {"interrupted": False, "aborted": "no acknowledgement of 'takeoff'"}, 300.0)
    st = status(slot)
    assert (st.state, st.why, st.run_dir and st.run_dir.name) == (SlotState.FAILED, "no acknowledgement of 'takeoff'", "mini-3")
    _run_folder(slot, "mini-4", {"interrupted": False, "aborted": None, "coverage": {"final": 0.5}}, 400.0)
    st = status(slot)
    assert (st.state, st.run_dir and st.run_dir.name, st.attempts) == (SlotState.OK, "mini-4", 4)


def test_a_folder_of_another_campaign_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    path = _campaign(tmp_path, "set: {duration: 5}\ngrid: {fleet.count: [2]}\n")
    slot = out / "runs" / "count-2_seed-0"
    slot.mkdir(parents=True)
    write_record(slot, SlotRecord(cell={"fleet.count": 2}, seed=0, overrides=["duration=9", "fleet.count=2", "seed=0"],
                                  digest="0123456789abcdef"))
    assert main(["sweep", str(path), "--out", str(out), "--no-live"]) == 2
    err = capsys.readouterr().err.replace("\n", " ")
    assert "flown with another scenario than this campaign gives it" in err and "another --out" in err


def test_the_tables_hold_every_complete_run_and_the_cells_statistics(tmp_path: Path) -> None:
    out = tmp_path / "camp"
    (out / "runs").mkdir(parents=True)
    (out / "campaign.yaml").write_text(yaml.safe_dump({"name": "t", "grid": {"fleet.count": [2, 10]}, "confidence": 0.95}))
    t90 = {(2, 0): 40.0, (2, 1): 44.0, (2, 2): None, (10, 0): 12.0, (10, 1): 13.5, (10, 2): 12.9}
    for (n, seed), v in t90.items():
        slot = out / "runs" / f"count-{n}_seed-{seed}"
        slot.mkdir()
        write_record(slot, SlotRecord(cell={"fleet.count": n}, seed=seed, overrides=[], digest="d"))
        _run_folder(slot, "mini-1", {"interrupted": False, "aborted": None,
                                     "coverage": {"final": 0.8 if v is None else 0.95, "time_to_90_s": v},
                                     "incidents": [{"kind": "x"}] * seed}, 1.0)
    pending = out / "runs" / "count-10_seed-3"
    pending.mkdir()
    write_record(pending, SlotRecord(cell={"fleet.count": 10}, seed=3, overrides=[], digest="d"))
    t = collect(out)
    assert [c.values["fleet.count"] for c in t.cells] == [2, 10]  # grid order, not the folders' alphabetical one
    two, ten = t.cells
    assert (two.ok, two.pending, ten.ok, ten.pending) == (3, 0, 3, 1)
    s = two.stats["coverage.time_to_90_s"]
    assert (s.runs, s.n, s.mean) == (3, 2, 42.0)
    lo, hi = sps.t.interval(0.95, 1, loc=42.0, scale=sps.sem([40.0, 44.0]))
    assert (s.ci_low, s.ci_high) == (pytest.approx(lo), pytest.approx(hi))
    assert ten.stats["incidents"].mean == pytest.approx(1.0)
    text = runs_csv(t).splitlines()
    head = text[0].split(",")
    assert head[:4] == ["slot", "fleet.count", "seed", "status"] and "coverage.time_to_90_s" in head
    assert len(text) == 7 and text[1].startswith("count-2_seed-0,2,0,ok,")
    assert "wall_s" not in t.columns  # not flown by a sweep: no measures of its own


# ---- capacity -----------------------------------------------------------------------------------------------
def test_a_second_run_waits_for_room_on_the_machine() -> None:
    cap = Capacity(limit=3, cores=4)
    small, big = Need(cores=0.5, memory_mb=400), Need(cores=2.0, memory_mb=400)
    assert cap.admits(big, []) == ""  # the first run always flies (mrswarm run checks the fleet itself)
    assert "would need about 4.5 cores" in cap.admits(big, [big, small])
    assert "3 running (--parallel 3)" in cap.admits(small, [small, small, small])
    cap.started()
    assert "the last run started" in cap.admits(small, [small])
    cap.last_start = time.monotonic() - SETTLE_S - 1
    assert cap.admits(small, [small]) == "watching the machine's load"
    now = time.monotonic()
    cap._load.extend([(now - 10.0, 0.95), (now, 0.95)])  # the machine is busy with something else
    assert "the machine uses 3.8 of 4 cores" in cap.admits(small, [small])
    cap._load.clear()
    cap._load.extend([(now - 10.0, 0.1), (now, 0.1)])
    assert cap.admits(small, [small]) == ""
    scn = load_scenario(MINI)
    first = cap.need(scn, "c")
    cap.measured("c", 3.0)  # a run of that cell used 3 cores: its next one is planned with that (and a margin)
    assert first.cores < 1.0 and cap.need(scn, "c").cores == pytest.approx(3.0 * 1.25)
    assert math.isclose(cap.need(scn, "other").cores, first.cores)
    # a lock-step run goes as fast as the CPU allows: it needs the whole machine, none flies beside it
    lockstep = load_scenario(MINI, ["time=lockstep"])
    assert cap.need(lockstep, "l").cores >= 4.0
    assert "would need" in cap.admits(cap.need(lockstep, "l"), [small])


# ---- a swarm job's wrapper and service ---------------------------------------------------------------------------
def test_the_job_wrapper_records_exit_code_cpu_and_forwards_sigterm(tmp_path: Path) -> None:
    from mrswarm.sweep.job import ask_stop, read_result

    result, log = tmp_path / "job.json", tmp_path / "run.log"
    burn = ("import time; t = time.process_time(); print('flying', flush=True)\n"
            "while time.process_time() - t < 0.3: pass\nraise SystemExit(3)")
    done = subprocess.run([sys.executable, "-m", "mrswarm.sweep.job", "--result", str(result), "--log", str(log), "--",
                           sys.executable, "-c", burn], cwd=ROOT, timeout=60)
    r = read_result(result)
    assert done.returncode == 0 and r is not None and log.read_text() == "flying\n"
    assert (r.exit_code, r.node) == (3, socket.gethostname())
    assert r.cpu_s is not None and r.cpu_s >= 0.3 and r.wall_s is not None and r.wall_s >= r.cpu_s * 0.5
    # a stop signal the sweep writes into the stop file (in the shared campaign folder) reaches the run, as does one
    # sent to the wrapper itself (the container stopped by hand); the run stops as it likes
    wait = ("import signal, sys, time\nsignal.signal(signal.SIGTERM, lambda *a: sys.exit(143))\n"
            "signal.signal(signal.SIGINT, lambda *a: sys.exit(130))\nprint('up', flush=True)\ntime.sleep(60)")
    for how, code in (("file", 130), ("signal", 143)):
        log.write_text("")
        stop = tmp_path / f"stop-{how}"
        proc = subprocess.Popen([sys.executable, "-m", "mrswarm.sweep.job", "--result", str(result), "--log", str(log),
                                 "--stop", str(stop), "--", sys.executable, "-c", wait], cwd=ROOT)
        assert wait_for(lambda: log.read_text().endswith("up\n"), timeout=30)
        if how == "file":
            ask_stop(stop, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
        r = read_result(result)
        assert r is not None and r.exit_code == code and r.wall_s is not None and r.wall_s < 30, how


def test_a_job_reserves_the_runs_need_and_mounts_only_the_campaign_folder(tmp_path: Path) -> None:
    from mrswarm.sweep.swarm_jobs import scenario_files_problem, service_kwargs

    kw = service_kwargs(image="mrswarm:0.1.0", argv=["python3", "-m", "mrswarm.sweep.job"], out=tmp_path, name="mrs-x-1",
                        run_label="sweep-x", need=Need(cores=0.62, memory_mb=480.0), uid=1000, gid=1000)
    assert dict(kw["mode"]) == {"ReplicatedJob": {}}  # one task, run once (Swarm's defaults: one completion)
    assert kw["restart_policy"]["Condition"] == "none"
    assert kw["resources"]["Reservations"] == {"NanoCPUs": 620_000_000, "MemoryBytes": 480 * 2**20}
    (m,) = kw["mounts"]
    assert (m["Source"], m["Target"], m["Type"]) == (str(tmp_path.resolve()), str(tmp_path.resolve()), "bind")
    assert kw["user"] == "1000:1000" and "networks" not in kw and kw["hostname"] == "{{.Node.Hostname}}"
    assert scenario_files_problem(load_scenario(MINI)) == ""
    keyed = load_scenario(MINI, ["network.security.keys=/etc/mrswarm/keys"])
    assert scenario_files_problem(keyed).startswith("network.security.keys: /etc/mrswarm/keys: a key directory on this machine")
