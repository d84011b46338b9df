"""Connecting the ground station to a swarm, and resolving UAV target lists."""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

from groundfloor.errors import MrswarmError
from swarmnet.connectivity import Rendezvous
from swarmnet.keyspace import check_swarm
from swarmnet.observer import SwarmObserver
from swarmnet.security.credentials import Credentials
from swarmnet.security.identity import NodeName

DISCOVERY_WAIT = 2.0  # s: how long liveliness may take to list every UAV


class GcsError(MrswarmError):
    """A usage problem the CLI reports in one line, with exit code 2."""


@dataclass(frozen=True)
class Target:
    swarm: str
    endpoints: tuple[str, ...]
    discovery: tuple[str, str] | None = None  # (server HOST:PORT, swarm key): the registry, when known
    credentials: Credentials | None = None  # None: a plain (tcp/) link, which only an insecure swarm accepts


def resolve_target(run: str | None, connect: list[str], swarm: str | None, keys: str | None = None,
                   identity: str | None = None) -> Target:
    """``--run DIR`` (reads DIR/network.json written by ``mrswarm run``) or ``--connect EP --swarm NAME``.

    Credentials (docs/security.md): ``keys`` (a key directory, or a ground station's bundle) and
    ``identity`` (default ``gcs-1.<swarm>``), else the run's key directory from its network.json.
    Without any, the link is plain and reaches only a swarm run with ``network.security: off``.
    """
    target = _resolve(run, connect, swarm)
    if keys is None and run:
        keys = _run_keys(Path(run))
    if keys is None:
        tls = [ep for ep in target.endpoints if ep.startswith("tls/")]
        if tls:
            raise GcsError(f"{tls[0]} speaks TLS: give the ground station's credentials with --keys DIR "
                           "(the swarm's key directory or a gcs bundle, `mrswarm keys bundle gcs-1`; docs/security.md)")
        return target
    try:
        name = NodeName.in_swarm(identity, target.swarm) if identity else NodeName("gcs", 1, target.swarm)
        creds = Credentials(keys=keys, identity=name.cn)
        creds.files()
        creds.roster()
    except ValueError as exc:  # ConfigError too
        raise GcsError(f"--keys {keys}: {exc}") from None
    return Target(target.swarm, target.endpoints, target.discovery, creds)


def _run_keys(run: Path) -> str | None:
    """The key directory a run's network.json names (None: an insecure run, or one from before security)."""
    try:
        sec = json.loads((run / "network.json").read_text()).get("security") or {}
    except (OSError, ValueError, AttributeError):
        return None
    keys = sec.get("keys") if isinstance(sec, dict) and sec.get("mode") == "mtls" else None
    return str(keys) if keys else None


def _resolve(run: str | None, connect: list[str], swarm: str | None) -> Target:
    if run:
        path = Path(run) / "network.json"
        try:
            data = json.loads(path.read_text())
            sw, eps = data["swarm"], tuple(data["endpoints"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise GcsError(f"--run {run}: cannot read {path} ({exc.__class__.__name__});"
                           " is it a folder of `mrswarm run`?") from None
        swarm = swarm or sw
        connect = list(connect) or list(eps)
        disc = data.get("discovery")
        if isinstance(disc, dict) and swarm == sw:
            try:
                from discovery.server import load_keys

                key = load_keys(Path(run) / str(disc["key_file"])).get(sw)
                registry = (str(disc["server"]), key) if key else None
            except (OSError, ValueError, KeyError):
                registry = None  # the list then comes from liveliness alone
            if registry:
                return _checked(swarm, connect, registry)
    return _checked(swarm, connect, None)


def _checked(swarm: str | None, connect: list[str], registry: tuple[str, str] | None) -> Target:
    if not connect:
        raise GcsError("where is the swarm? give --run RUN_DIR, or --connect tls/HOST:PORT (the edge router) and --swarm NAME")
    if not swarm:
        raise GcsError("--swarm NAME is required with --connect")
    try:
        check_swarm(swarm)
    except ValueError as exc:
        raise GcsError(str(exc)) from None
    for ep in connect:
        if "/" not in ep:
            raise GcsError(f"--connect {ep!r}: expected a Zenoh endpoint such as tls/127.0.0.1:7447")
    return Target(swarm, tuple(connect), registry)


def open_observer(target: Target, name: str = "gcs") -> SwarmObserver:
    """A client-mode observer with the role ``gcs`` (its liveliness token is alive/gcs/<id>)."""
    import zenoh

    node_id = os.getpid() % 65535 + 1
    try:
        return SwarmObserver(target.swarm, Rendezvous(target.endpoints, mode="client", credentials=target.credentials),
                             node_id=node_id, role="gcs", name=name).open()
    except zenoh.ZError as exc:
        hint = "" if target.credentials else " (a secured swarm needs --keys)"
        raise GcsError(f"cannot reach the swarm's router at {', '.join(target.endpoints)} (is the run still going?{hint}): "
                       f"{str(exc).split(' at ')[0]}") from None


def parse_ids(text: str) -> list[int]:
    """``3``, ``1,2,5-7`` -> sorted unique ids; raises GcsError on anything else."""
    out: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part:
                a, b = (int(x) for x in part.split("-", 1))
                if b < a or b - a > 65535:
                    raise ValueError
                out.update(range(a, b + 1))
            else:
                out.add(int(part))
        except ValueError:
            raise GcsError(f"bad UAV list {text!r}: use ids and ranges like 3 or 1,2,5-7") from None
    bad = [u for u in out if not 1 <= u <= 65535]
    if bad or not out:
        raise GcsError(f"bad UAV list {text!r}: ids are 1..65535")
    return sorted(out)


def wait_alive(obs: SwarmObserver, want: set[int] | None, timeout: float = DISCOVERY_WAIT) -> set[int]:
    """Poll until every wanted UAV is alive (or, with ``want=None``, until the set stops growing)."""
    deadline = time.monotonic() + timeout
    last: set[int] = set()
    stable_since = time.monotonic()
    while time.monotonic() < deadline:
        obs.poll()
        alive = obs.alive_uavs()
        if want is not None and want <= alive:
            return alive
        if alive != last:
            last, stable_since = set(alive), time.monotonic()
        elif want is None and alive and time.monotonic() - stable_since > 0.5:
            return alive
        time.sleep(0.05)
    return obs.alive_uavs()
