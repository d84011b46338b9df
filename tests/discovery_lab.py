"""Test helper: a routed namespace lab with a discovery server on the edge host and probe nodes.

Used by the discovery tests and ``benchmarks/discovery_mesh.py``. Every process runs
inside a namespace of the lab (``ip netns exec``) and is killed when the lab closes; the
namespaces are deleted afterwards, also when a test fails.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from discovery.client import QueryTimeout
from discovery.netlab import Netlab, cleanup_stale

ROOT = Path(__file__).resolve().parents[1]
SERVER_PORT = 7450


@dataclass
class Proc:
    name: str
    host: str
    proc: subprocess.Popen[bytes]
    log: Path
    status: Path | None = None


class SwarmLab:
    def __init__(self, workdir: Path, hosts: list[str], keys: dict[str, str], second_octet: int = 66):
        cleanup_stale()
        self.dir = workdir
        self.dir.mkdir(parents=True, exist_ok=True)
        self.lab = Netlab(["edge", *hosts], second_octet=second_octet)
        self.keys = keys
        self.key_files = {}
        for swarm, key in keys.items():
            p = self.dir / f"{swarm}.key"
            p.write_text(key + "\n")
            p.chmod(0o600)
            self.key_files[swarm] = p
        self.procs: dict[str, Proc] = {}
        self.env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")

    # ---- lifecycle ---------------------------------------------------------------------------------
    def __enter__(self) -> SwarmLab:
        self.lab.up()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        for p in self.procs.values():
            if p.proc.poll() is None:
                p.proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + 5
        for p in self.procs.values():
            try:
                p.proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.proc.kill()
                p.proc.wait(5)
        self.lab.down()

    @property
    def server(self) -> str:
        return f"{self.lab['edge'].addr}:{SERVER_PORT}"

    def addr(self, host: str) -> str:
        return self.lab[host].addr

    def _spawn(self, name: str, host: str, argv: list[str], status: Path | None = None) -> Proc:
        log = self.dir / f"{name}.log"
        with open(log, "ab") as out:
            proc = self.lab.popen(host, argv, cwd=ROOT, env=self.env, stdin=subprocess.DEVNULL, stdout=out,
                                  stderr=subprocess.STDOUT)
        p = self.procs[name] = Proc(name, host, proc, log, status)
        return p

    # ---- the discovery server ------------------------------------------------------------------------
    def start_server(self, ttl: float = 3.0, timeout: float = 30.0) -> Proc:
        keys = self.dir / "server.keys"
        keys.write_text("".join(f"{s} {k}\n" for s, k in self.keys.items()))
        keys.chmod(0o600)
        log = self.dir / "server.log"
        before = log.read_text().count("discovery server on") if log.exists() else 0
        p = self._spawn("server", "edge", [sys.executable, "-m", "discovery.server", "--listen", self.server,
                                            "--keys", str(keys), "--ttl", str(ttl)])
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if p.proc.poll() is not None:
                raise RuntimeError(f"discovery server exited: {p.log.read_text()[-2000:]}")
            if p.log.read_text().count("discovery server on") > before:
                return p
            time.sleep(0.05)
        raise RuntimeError("discovery server did not start")

    def kill(self, name: str) -> None:
        p = self.procs[name]
        p.proc.kill()
        p.proc.wait(10)

    def query(self, swarm: str, timeout: float = 0.5, attempts: int = 1) -> tuple[list[Any], dict[str, Any]]:
        """Ask the server from the edge namespace's neighbour: run the query inside host 'edge'."""
        code = ("import json,sys;from discovery.client import query_registry as q;"
                f"r,s=q({self.server!r},{swarm!r},{self.keys[swarm]!r},timeout={timeout},attempts={attempts});"
                "print(json.dumps({'nodes':[x.to_dict() for x in r],'stats':s}))")
        res = self.lab.run("edge", [sys.executable, "-c", code], cwd=ROOT, env=self.env, timeout=30)
        if res.returncode != 0:
            raise QueryTimeout(res.stderr.strip().splitlines()[-1] if res.stderr.strip() else "query failed")
        d = json.loads(res.stdout)
        return d["nodes"], d["stats"]

    def watch_registry(self, swarm: str, duration: float, period: float = 0.1) -> Proc:
        """Query the registry every ``period`` s from the edge host for ``duration`` s; read it with
        :meth:`watched`. Each line: {"t": wall time of the answer, "nodes": [...]} or {"t", "error"}."""
        out = self.dir / f"watch-{swarm}-{time.time():.3f}.jsonl"
        code = (
            "import json,sys,time\n"
            "from discovery.client import query_registry, QueryTimeout\n"
            f"end=time.time()+{duration}\n"
            f"f=open({str(out)!r},'a',buffering=1)\n"
            "while time.time()<end:\n"
            "    t0=time.time()\n"
            "    try:\n"
            f"        r,s=query_registry({self.server!r},{swarm!r},{self.keys[swarm]!r},timeout=0.2,attempts=1)\n"
            "        f.write(json.dumps({'t':time.time(),'nodes':[x.to_dict() for x in r]})+'\\n')\n"
            "    except QueryTimeout as e:\n"
            "        f.write(json.dumps({'t':time.time(),'error':str(e)})+'\\n')\n"
            f"    time.sleep(max(0.0,{period}-(time.time()-t0)))\n"
        )
        p = self._spawn(out.stem, "edge", [sys.executable, "-c", code])
        p.status = out
        return p

    @staticmethod
    def watched(p: Proc) -> list[dict[str, Any]]:
        assert p.status is not None
        if not p.status.exists():
            return []
        lines = p.status.read_text().splitlines()
        out = []
        for line in lines:
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:  # the line being written
                pass
        return out

    # ---- probe nodes ---------------------------------------------------------------------------------------
    def start_probe(self, name: str, host: str, swarm: str, node_id: int, role: str = "uav", key_file: Path | None = None,
                    extra_swarms: tuple[str, ...] = (), publish: float = 10.0, connectivity: str = "discovery",
                    connect: str | None = None, extra_args: tuple[str, ...] = (), listen: str | None = None) -> Proc:
        status = self.dir / f"{name}.json"
        if status.exists():
            status.unlink()
        argv = [sys.executable, "-m", "discovery.probe", "--swarm", swarm, "--id", str(node_id), "--role", role,
                "--connectivity", connectivity, "--server", self.server,
                "--key-file", str(key_file or self.key_files[swarm]),
                "--listen", listen or f"tcp/{self.addr(host)}:7447", "--publish", str(publish), "--status", str(status),
                *extra_args]
        for s in extra_swarms:
            argv += ["--extra-swarm", f"{s}={self.key_files[s]}"]
        if connect:
            argv += ["--connect", connect]
        return self._spawn(name, host, argv, status)

    def status(self, name: str) -> dict[str, Any] | None:
        p = self.procs[name]
        if p.proc.poll() is not None:
            raise RuntimeError(f"{name} exited with {p.proc.returncode}: {p.log.read_text()[-3000:]}")
        assert p.status is not None
        try:
            return json.loads(p.status.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return None

    def statuses(self, names: list[str]) -> dict[str, dict[str, Any]]:
        out = {}
        for n in names:
            st = self.status(n)
            if st is not None:
                out[n] = st
        return out

    def wait_status(self, names: list[str], pred: Any, timeout: float, period: float = 0.1) -> dict[str, dict[str, Any]]:
        """Poll the probes' status files until ``pred(statuses)`` holds (bounded); returns the last statuses."""
        deadline = time.monotonic() + timeout
        st: dict[str, dict[str, Any]] = {}
        while time.monotonic() < deadline:
            st = self.statuses(names)
            if len(st) == len(names) and pred(st):
                return st
            time.sleep(period)
        return st
