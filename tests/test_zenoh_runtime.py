"""A UAV process runs all of Zenoh's runtimes on one worker thread, a user's choice wins, and an
idle session leaves that thread asleep.

Each case is a real child process (Zenoh reads ``ZENOH_RUNTIME`` once, when its first runtime
starts, so it cannot be changed inside this test process): two sessions with mrswarm's
configuration linked over TCP on 127.0.0.1, one sample delivered across the link, the Zenoh
thread's wake-ups (its context switches in ``/proc``) over a time without traffic, then the
process's threads by name.

Zenoh 1.x turns its shared-memory transport on by default, and a session with it on runs a task
(the SHM "handoff" reactor) that wakes the process every 100 ms whatever the traffic; a lone UAV
spent 5-11 % of its CPU on it (docs/scale.md). mrswarm's sessions turn it off
(``TransportTuning.shared_memory``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from discovery.netutil import free_port
from swarmnet.connectivity import LEAN_ZENOH_RUNTIME

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, os, sys, time
import zenoh
from swarmnet.connectivity import TransportTuning, base_config, lean_zenoh_runtime, to_zenoh
if sys.argv[1] == "lean":
    lean_zenoh_runtime()
port, shm, idle_s = int(sys.argv[2]), sys.argv[3] == "shm", float(sys.argv[4])
# a lease of 12 s: a keep-alive every 3 s per link, so that the idle time shows what else wakes
tuning = TransportTuning(lease_ms=12000, shared_memory=shm)
a = zenoh.open(to_zenoh(base_config("peer", (), (f"tcp/127.0.0.1:{port}",), tuning)))
b = zenoh.open(to_zenoh(base_config("peer", (f"tcp/127.0.0.1:{port}",), ("tcp/127.0.0.1:0",), tuning)))
sub = b.declare_subscriber("t/pose", zenoh.handlers.FifoChannel(8))
got = None
deadline = time.monotonic() + 10.0
while got is None and time.monotonic() < deadline:
    a.put("t/pose", b"p")
    got = sub.try_recv()
    time.sleep(0.05)

def zenoh_switches():
    total = 0
    for t in os.listdir("/proc/self/task"):
        if open(f"/proc/self/task/{t}/comm").read().strip().startswith("app-"):
            for line in open(f"/proc/self/task/{t}/status"):
                if line.startswith(("voluntary_ctxt_switches", "nonvoluntary_ctxt_switches")):
                    total += int(line.split()[1])
    return total

wakes = None
if idle_s > 0:
    time.sleep(1.0)  # the link's opening settled
    before, t0 = zenoh_switches(), time.monotonic()
    time.sleep(idle_s)
    wakes = (zenoh_switches() - before) / (time.monotonic() - t0)
names = sorted(open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task"))
print(json.dumps({"received": got is not None and got.payload.to_bytes() == b"p",
                  "env": os.environ.get("ZENOH_RUNTIME"), "threads": names, "wakes_per_s": wakes}))
a.close(); b.close()
"""


def _child(mode: str, env_value: str | None, shm: bool = False, idle_s: float = 0.0) -> dict:
    """``mode`` "lean" applies :func:`lean_zenoh_runtime`; ``shm``: Zenoh's shared memory on;
    ``idle_s`` > 0: the Zenoh thread's wake-ups per second over that long without traffic."""
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}
    env["PYTHONPATH"] = str(ROOT)
    if env_value is not None:
        env["ZENOH_RUNTIME"] = env_value
    args = [mode, str(free_port()), "shm" if shm else "no-shm", str(idle_s)]
    res = subprocess.run([sys.executable, "-c", CHILD, *args], env=env, capture_output=True, text=True,
                         timeout=60, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def _rx_threads(out: dict) -> int:
    return sum(1 for name in out["threads"] if name.startswith("rx-"))


def _zenoh_threads(out: dict) -> list[str]:
    """Zenoh's worker threads by name (``app-0``, ``rx-1``, ...): those of its five runtimes."""
    return [name for name in out["threads"] if name.split("-")[0] in ("app", "acc", "tx", "rx", "net")]


def test_lean_runtime_sends_and_receives_on_one_zenoh_thread() -> None:
    out = _child("lean", None)
    assert out["received"], "the sample did not cross the link"
    assert out["env"] == LEAN_ZENOH_RUNTIME
    # two sessions, a listener, a link, a sample: all on the application runtime. Its one worker
    # is app-0; any app-N beyond it is tokio's blocking pool (opening a session waits in one),
    # whose threads end after 10 s idle. None of the receive, transmit, network or accept runtimes.
    names = _zenoh_threads(out)
    assert "app-0" in names and all(name.startswith("app-") for name in names), out["threads"]


def test_zenoh_defaults_have_two_rx_threads_and_a_users_choice_is_kept() -> None:
    default = _child("plain", None)
    assert default["received"] and _rx_threads(default) == 2, default["threads"]
    assert {name.split("-")[0] for name in _zenoh_threads(default)} >= {"app", "tx", "rx", "net"}, default["threads"]
    kept = _child("lean", "()")  # '()': Zenoh's own defaults, asked for by the user
    assert kept["received"] and kept["env"] == "()" and _rx_threads(kept) == 2, kept["threads"]
    three = _child("lean", "(rx: (worker_threads: 3))")
    assert three["received"] and _rx_threads(three) == 3, three["threads"]


def test_an_idle_session_does_not_wake_its_process_ten_times_a_second() -> None:
    off = _child("lean", None, shm=False, idle_s=4.0)
    assert off["received"], "the sample did not cross the link"
    # two sessions, one link: keep-alives every 3 s and their timers (1.2-1.5 a second measured)
    assert off["wakes_per_s"] < 5.0, off
    # the same with Zenoh's shared memory on: the reactor's ten a second per session (about 21
    # measured); if a later Zenoh drops it, this fails: then the setting no longer matters, and
    # docs/scale.md needs a new look
    on = _child("lean", None, shm=True, idle_s=4.0)
    assert on["received"], "the sample did not cross the link"
    assert on["wakes_per_s"] >= 9.0, on
