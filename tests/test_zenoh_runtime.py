"""A UAV process runs all of Zenoh's runtimes on one worker thread, and a user's choice wins.

Each case is a real child process (Zenoh reads ``ZENOH_RUNTIME`` once, when its first runtime
starts, so it cannot be changed inside this test process): two sessions linked over TCP on
127.0.0.1, one sample delivered across the link, then the process's threads by name.
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
from swarmnet.connectivity import lean_zenoh_runtime
if sys.argv[1] == "lean":
    lean_zenoh_runtime()
port = int(sys.argv[2])
plain = '{mode:"peer", scouting:{multicast:{enabled:false}, gossip:{enabled:false}}, '
a = zenoh.open(zenoh.Config.from_json5(plain + f'listen:{{endpoints:["tcp/127.0.0.1:{port}"]}}}}'))
b = zenoh.open(zenoh.Config.from_json5(plain + f'connect:{{endpoints:["tcp/127.0.0.1:{port}"]}}}}'))
sub = b.declare_subscriber("t/pose", zenoh.handlers.FifoChannel(8))
got = None
deadline = time.monotonic() + 10.0
while got is None and time.monotonic() < deadline:
    a.put("t/pose", b"p")
    got = sub.try_recv()
    time.sleep(0.05)
names = sorted(open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task"))
print(json.dumps({"received": got is not None and got.payload.to_bytes() == b"p",
                  "env": os.environ.get("ZENOH_RUNTIME"), "threads": names}))
a.close(); b.close()
"""


def _child(mode: str, env_value: str | None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}
    env["PYTHONPATH"] = str(ROOT)
    if env_value is not None:
        env["ZENOH_RUNTIME"] = env_value
    res = subprocess.run([sys.executable, "-c", CHILD, mode, str(free_port())], env=env, capture_output=True, text=True,
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
