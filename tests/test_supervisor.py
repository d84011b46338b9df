"""Process supervision with real processes and real signals (mrswarm/run/supervisor.py, deploy/process_runtime.py).

Children are small Python sleepers started the way the process runtime starts every child. The
tests kill them with SIGKILL and check the events, the backoff, the restart policy, and that a
child dies with its runner even when the runner is killed with SIGKILL.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil

from deploy.process_runtime import ProcessRuntime
from mrswarm.run.signals import StopSignals
from mrswarm.run.supervisor import BACKOFF_FIRST_S, Supervisor, last_error
from tests.conftest import wait_for

SLEEPER = [sys.executable, "-c", "import time; time.sleep(120)"]


def gone(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def events_until(sup: Supervisor, pred, timeout: float) -> list:  # noqa: ANN001
    seen: list = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        seen += sup.check()
        if pred(seen):
            break
        time.sleep(0.05)
    return seen


def test_a_killed_service_comes_back_with_backoff_and_a_lost_uav_is_an_event(tmp_path: Path) -> None:
    rt = ProcessRuntime(tmp_path)
    for name in ("router", "uav3"):
        rt._spawn(name, SLEEPER)
    sup = Supervisor(rt, restart_uavs=False, last_pose=lambda uav: [1.0, 2.0, 3.0])
    sup.adopt()
    try:
        first = rt.pids()["router"]
        t_kill = time.time()
        assert rt.signal("router", signal.SIGKILL)
        evs = events_until(sup, lambda e: any(x.event == "restarted" for x in e), 5.0)
        exited, restarted = evs[0], evs[-1]
        assert (exited.name, exited.event, exited.signal, exited.exit_code) == ("router", "exited", "SIGKILL", -9)
        assert restarted.event == "restarted" and rt.pids()["router"] != first and not gone(rt.pids()["router"])
        assert BACKOFF_FIRST_S - 0.05 <= restarted.t - t_kill <= BACKOFF_FIRST_S + 1.0
        # a second crash soon after waits twice as long
        t_kill = time.time()
        rt.signal("router", signal.SIGKILL)
        evs = events_until(sup, lambda e: any(x.event == "restarted" for x in e), 5.0)
        assert 2 * BACKOFF_FIRST_S - 0.05 <= evs[-1].t - t_kill <= 2 * BACKOFF_FIRST_S + 1.0
        # a UAV that dies is lost (no restart policy): one event, with its last pose
        rt.signal("uav3", signal.SIGKILL)
        evs = events_until(sup, lambda e: bool(e), 5.0)
        time.sleep(1.0)
        evs += sup.check()
        assert [(e.name, e.event, e.last_pose) for e in evs] == [("uav3", "exited", [1.0, 2.0, 3.0])]
        assert "uav3" in sup.down and not sup.restarting("uav3")
    finally:
        rt.stop(grace=2.0)


def test_on_failure_restarts_a_crashed_uav_and_a_planned_restart_is_one_event(tmp_path: Path) -> None:
    rt = ProcessRuntime(tmp_path)
    rt._spawn("uav1", SLEEPER)
    rt._spawn("uav2", [sys.executable, "-c", "raise SystemExit(0)"])  # ends by itself, cleanly
    sup = Supervisor(rt, restart_uavs=True)
    sup.adopt()
    try:
        rt.signal("uav1", signal.SIGKILL)
        # (uav2's interpreter may still be starting on a loaded machine: wait for both)
        evs = events_until(sup, lambda e: any(x.event == "restarted" for x in e) and any(x.name == "uav2" for x in e), 15.0)
        assert [(e.name, e.event) for e in evs if e.name == "uav1"] == [("uav1", "exited"), ("uav1", "restarted")]
        assert [(e.name, e.event) for e in evs if e.name == "uav2"] == [("uav2", "exited")]  # exit 0: not a failure
        time.sleep(1.0)
        assert not [e for e in sup.check() if e.name == "uav2"]
        pid = rt.pids()["uav1"]
        ev = sup.restart_now("uav1")
        assert ev is not None and ev.event == "restarted" and ev.detail == "planned restart"
        assert gone(pid) and not gone(rt.pids()["uav1"])
        assert [e.event for e in sup.check()] == ["restarted"]  # reported once, not as a crash
    finally:
        rt.stop(grace=2.0)



def test_a_failed_process_says_why_from_its_log_and_a_killed_one_has_nothing_to_say(tmp_path: Path) -> None:
    """The exit event carries the failed process's last error, from its real log: a logged ERROR
    (the runtime's log format), or a traceback's last line. A SIGKILL leaves no error behind."""
    rt = ProcessRuntime(tmp_path)
    logged = ("import logging, sys; logging.basicConfig(format='%(asctime)s %(levelname)s %(name)s: %(message)s');"
              "logging.getLogger('uav_stack.runtime').info('starting');"
              "logging.getLogger('uav_stack.runtime').error('gcs.mavlink_endpoints: udpin:127.0.0.1:9: taken');"
              "logging.getLogger('x').warning('after the error, not an error'); sys.exit(2)")
    rt._spawn("uav1", [sys.executable, "-c", logged])
    rt._spawn("uav2", [sys.executable, "-c", "print('hello'); {}['missing_key']"])
    rt._spawn("uav3", SLEEPER)
    sup = Supervisor(rt, log_of=lambda name: tmp_path / "logs" / f"{name}.log")
    sup.adopt()
    try:
        rt.signal("uav3", signal.SIGKILL)
        evs = events_until(sup, lambda e: len(e) == 3, 20.0)
        why = {e.name: (e.exit_code, e.error) for e in evs}
        assert why == {"uav1": (2, "gcs.mavlink_endpoints: udpin:127.0.0.1:9: taken"),
                       "uav2": (1, "KeyError: 'missing_key'"), "uav3": (-9, "")}
    finally:
        rt.stop(grace=2.0)
    assert last_error(tmp_path / "no-such.log") == "" and last_error(None) == ""


RUNNER = """
import sys, time
from pathlib import Path
from deploy.process_runtime import ProcessRuntime
rt = ProcessRuntime(Path(sys.argv[1]))
rt._spawn("router", {sleeper!r})
rt._spawn("uav1", {sleeper!r})
print(rt.pids()["router"], rt.pids()["uav1"], flush=True)
time.sleep(120)
"""


def test_children_die_with_their_runner_even_on_sigkill(tmp_path: Path) -> None:
    code = RUNNER.format(sleeper=SLEEPER)
    runner = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], stdout=subprocess.PIPE, text=True,
                              env=dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1])))
    try:
        assert runner.stdout is not None
        pids = [int(p) for p in runner.stdout.readline().split()]
        assert len(pids) == 2 and not any(gone(p) for p in pids)
        runner.kill()
        runner.wait(5)
        assert wait_for(lambda: all(gone(p) for p in pids), 5.0, 0.05), "a child outlived its runner"
    finally:
        if runner.poll() is None:
            runner.kill()


def test_stop_signals_count_and_never_raise_in_the_handler() -> None:
    before = signal.getsignal(signal.SIGINT)  # another test in this worker may have set its own
    s = StopSignals().install()
    try:
        assert s.installed and not s.requested
        os.kill(os.getpid(), signal.SIGTERM)
        assert wait_for(lambda: s.requested, 2.0) and not s.fast and s.exit_code == 143
        os.kill(os.getpid(), signal.SIGINT)
        assert wait_for(lambda: s.fast, 2.0) and s.names == ["SIGTERM", "SIGINT"]
    finally:
        s.restore()
    assert signal.getsignal(signal.SIGINT) is before


def test_a_silent_uav_whose_process_lives_is_a_stall_with_its_duration() -> None:
    from mrswarm.records.summary import RunInfo
    from mrswarm.results.fault_report import stalls
    from mrswarm.run.stalls import StallWatch

    w = StallWatch()
    t0 = 1000.0
    assert w.tick(t0 + 0.5, {1: t0 + 0.4, 2: t0 + 0.4}, {1, 2}) == ([], [])
    assert w.tick(t0 + 1.6, {1: t0 + 1.5, 2: t0 + 0.4}, {1, 2}) == ([2], [])  # UAV 2: nothing for 1.2 s
    assert w.tick(t0 + 3.0, {1: t0 + 2.9, 2: t0 + 0.4}, {1, 2}) == ([], [])  # still silent: no second start
    began, ended = w.tick(t0 + 3.6, {1: t0 + 3.5, 2: t0 + 3.5}, {1, 2})  # a pose again: the stall ends
    assert began == [] and [(e.name, e.event, e.t, e.duration_s) for e in ended] == [("uav2", "stalled", t0 + 0.4, 3.1)]
    assert w.tick(t0 + 5.0, {1: t0 + 3.6, 2: t0 + 4.9}, {2}) == ([], [])  # UAV 1 exited: its exit is the event
    assert w.tick(t0 + 7.0, {2: t0 + 4.9}, {2}) == ([2], [])
    (last,) = w.close(t0 + 8.0)  # still silent at the end: it lasted to the end
    assert last.duration_s == 3.1 and "end of the run" in last.detail
    info = RunInfo(scenario="s", started=t0 - 10, mission_start=t0, events=[*ended, last])
    assert [(s.uav, s.from_s, s.duration_s) for s in stalls(info, t0)] == [(2, 0.4, 3.1), (2, 4.9, 3.1)]


def test_silence_the_runner_cannot_tell_from_its_own_blindness_is_no_stall() -> None:
    from mrswarm.run.stalls import StallWatch

    w = StallWatch()
    t0 = 1000.0
    # the edge router died at t0 + 0.4: the runner's link came back at t0 + 1.0, the UAVs' poses only later
    assert w.tick(t0 + 2.0, {1: t0 + 0.4, 2: t0 + 0.4}, {1, 2}, path_since=t0 + 1.0) == ([], [])
    assert w.tick(t0 + 2.0, {1: t0 + 0.4, 2: t0 + 0.4}, {1, 2}, path_since=float("inf")) == ([], [])  # link down
    # a discovery peer (no router): silent UAV 2 counts only while it hears UAV 1
    assert w.tick(t0 + 2.0, {1: t0 + 0.4, 2: t0 + 0.4}, {1, 2}, path_since=None) == ([], [])
    assert w.tick(t0 + 2.1, {1: t0 + 2.0, 2: t0 + 0.4}, {1, 2}, path_since=None) == ([2], [])
