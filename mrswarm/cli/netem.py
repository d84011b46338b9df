"""``mrswarm netem``: list presets, change a running swarm's impairments, show what applies.

    mrswarm netem presets
    mrswarm netem set --run results/coverage-20250101-120000 --preset degraded
    mrswarm netem set --connect tls/127.0.0.1:7447 --swarm alpha --keys keys/alpha --class v2v --delay 150ms --jitter 40ms \\
        --distribution normal --loss 10% --burst 3
    mrswarm netem status --run results/coverage-20250101-120000

``set`` builds a ``network.netem`` mapping (docs/netem.md) from a preset, a file and flags,
validates it here (errors name the field), publishes it on ``mrs/<swarm>/netem/set`` and
waits until every live UAV has acknowledged it. On a secured swarm only the experiment
controller (``ctl.<swarm>``) may publish there: ``--run`` takes the run's credentials,
``--connect`` needs ``--keys`` (docs/security.md). The change replaces the UAVs' whole netem
configuration (their seed is kept unless ``--seed`` is given). Light imports only: no
scenario loader or rich, so the command starts fast.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from swarmnet.security.credentials import Credentials

_UNITS_S = {"us": 1e-6, "ms": 1e-3, "s": 1.0, "": 1e-3}
_UNITS_KBIT = {"bit": 1e-3, "kbit": 1.0, "mbit": 1e3, "gbit": 1e6, "": 1.0}


def parse_time_ms(text: str, what: str) -> float:
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(us|ms|s|)\s*", text.lower())
    if not m:
        raise ValueError(f"{what}: {text!r} is not a time (e.g. 50ms, 0.2s)")
    return float(m.group(1)) * _UNITS_S[m.group(2)] * 1000.0


def parse_fraction(text: str, what: str) -> float:
    t = text.strip()
    try:
        v = float(t[:-1]) / 100.0 if t.endswith("%") else float(t)
    except ValueError:
        raise ValueError(f"{what}: {text!r} is not a probability (e.g. 10% or 0.1)") from None
    return v


def parse_rate_kbit(text: str) -> float:
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(bit|kbit|mbit|gbit|)\s*", text.lower())
    if not m:
        raise ValueError(f"--rate: {text!r} is not a rate (e.g. 256kbit, 10mbit)")
    return float(m.group(1)) * _UNITS_KBIT[m.group(2)]


def parse_duration_range(text: str) -> float | list[float]:
    if ":" in text:
        lo, hi = text.split(":", 1)
        return [parse_time_ms(lo, "--outage"), parse_time_ms(hi, "--outage")]
    return parse_time_ms(text, "--outage")


def profile_from_flags(a: argparse.Namespace) -> dict[str, Any]:
    """A profile patch from the command-line flags (empty if none were given)."""
    p: dict[str, Any] = {}
    if a.delay is not None or a.jitter is not None:
        d: dict[str, Any] = {"ms": parse_time_ms(a.delay or "0ms", "--delay")}
        if a.jitter is not None:
            d["jitter_ms"] = parse_time_ms(a.jitter, "--jitter")
            d["distribution"] = a.distribution
        if a.correlation is not None:
            d["correlation"] = a.correlation
        p["delay"] = d
    if a.loss is not None:
        rate = parse_fraction(a.loss, "--loss")
        p["loss"] = {"model": "gilbert_elliott", "rate": rate, "burst": a.burst} if a.burst else {"model": "bernoulli", "p": rate}
    if a.duplicate is not None:
        p["duplicate"] = parse_fraction(a.duplicate, "--duplicate")
    if a.reorder is not None:
        p["reorder"] = {"p": parse_fraction(a.reorder, "--reorder"), "gap": a.gap}
    if a.rate is not None:
        p["rate"] = {"kbit": parse_rate_kbit(a.rate)}
    if a.limit is not None:
        p["limit"] = a.limit
    if a.outage_every is not None:
        p["outage"] = {"every_s": parse_time_ms(a.outage_every, "--outage-every") / 1000.0,
                       "duration_ms": parse_duration_range(a.outage or "100ms"), "mode": a.outage_mode}
    if a.range is not None:
        m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*m?\s*", a.range)
        if not m:
            raise ValueError(f"--range: {a.range!r} is not a distance (e.g. 150m)")
        p["distance"] = {"model": "range", "range_m": float(m.group(1))}
    return p


def build_config(a: argparse.Namespace) -> dict[str, Any]:
    cfg: dict[str, Any] = {}
    if a.file:
        text = Path(a.file).read_text()
        if a.file.endswith((".yaml", ".yml")):
            import yaml

            from groundfloor import strict_yaml

            try:
                cfg = strict_yaml.load(text) or {}
            except yaml.YAMLError as exc:
                mark = getattr(exc, "problem_mark", None)
                raise ValueError(f"{a.file}{f':{mark.line + 1}' if mark else ''}: not valid YAML: "
                                 f"{getattr(exc, 'problem', exc)}") from None
        else:
            cfg = json.loads(text)
        if isinstance(cfg, dict) and isinstance(cfg.get("network"), dict) and "netem" in cfg["network"]:
            cfg = cfg["network"]["netem"] or {}  # a whole scenario file: take its network.netem
        if not isinstance(cfg, dict):
            raise ValueError(f"{a.file}: expected a mapping (the network.netem section)")
    if a.preset:
        cfg["preset"] = a.preset
    if a.seed is not None:
        cfg["seed"] = a.seed
    if a.exempt_commands is not None:
        cfg["exempt_commands"] = a.exempt_commands
    patch = profile_from_flags(a)
    if patch:
        from swarmnet.netem.config import merge_profile

        for cls in a.cls or ["v2v", "v2p", "ground"]:
            cfg[cls] = merge_profile(cfg.get(cls) or {}, patch)  # a patch: parse_netem merges it onto the preset
    return cfg


def endpoint_and_swarm(a: argparse.Namespace) -> tuple[list[str], str, Credentials | None]:
    """Where the swarm's router is, the swarm's name, and the experiment controller's credentials.

    Only the controller (``ctl.<swarm>``) may change netem on a secured swarm (docs/security.md):
    ``--keys`` (the swarm's key directory, or the controller's bundle), else the run's key directory.
    """
    from swarmnet.security.credentials import Credentials
    from swarmnet.security.identity import NodeName

    keys = a.keys
    if a.run:
        info_path = Path(a.run) / "network.json"
        try:
            info = json.loads(info_path.read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"--run: cannot read {info_path}: {exc}") from None
        endpoints, swarm = list(info["endpoints"]), a.swarm or info["swarm"]
        sec = info.get("security") or {}
        if keys is None and isinstance(sec, dict) and sec.get("mode") == "mtls":
            keys = sec.get("keys")
    elif not a.connect:
        raise ValueError("give --run RUN_DIR (of a running `mrswarm run`) or --connect ENDPOINT --swarm NAME")
    else:
        endpoints, swarm = list(a.connect), a.swarm or "alpha"
    if keys is None:
        if any(ep.startswith("tls/") for ep in endpoints):
            raise ValueError("the swarm's router speaks TLS: give the controller's credentials with --keys DIR "
                             "(docs/security.md)")
        return endpoints, swarm, None
    name = NodeName.in_swarm(a.identity, swarm) if a.identity else NodeName("ctl", 0, swarm)
    creds = Credentials(keys=str(keys), identity=name.cn)
    creds.files()
    return endpoints, swarm, creds


def send(endpoints: list[str], swarm: str, config: dict[str, Any], targets: list[int] | None, wait: bool,
         timeout: float, sender: str = "cli", credentials: Credentials | None = None) -> tuple[int, dict[int, Any], set[int]]:
    """Publish a netem set; return (message id, acks by UAV, UAVs that were expected to answer)."""
    from swarmnet.connectivity import Rendezvous
    from swarmnet.messages import Command
    from swarmnet.netem.control import NetemSet, encode_netem_set
    from swarmnet.observer import PendingCommand, SwarmObserver

    obs = SwarmObserver(swarm, Rendezvous(tuple(endpoints), mode="client", credentials=credentials), name=sender).open()
    try:
        expected: set[int] = set(targets) if targets else set()
        if wait and not targets:  # every UAV alive now; liveliness history arrives right after the session opens
            deadline = time.time() + min(timeout, 3.0)
            last, stable_since = -1, time.time()
            while time.time() < deadline:
                obs.poll()
                n = len(obs.alive_uavs())
                if n != last:
                    last, stable_since = n, time.time()
                elif n and time.time() - stable_since > 0.3:
                    break
                time.sleep(0.05)
            expected = obs.alive_uavs()
        msg_id = int(time.time() * 1000) & 0xFFFFFFFF
        msg = NetemSet(id=msg_id, sender=sender, t_wall=time.time(), config=config, targets=tuple(targets) if targets else None)
        pending = obs.pending[msg_id] = PendingCommand(Command(sender, msg_id, 0, "netem", {}, msg.t_wall), expected)
        assert obs.node.session is not None
        obs.node.session.put(obs.keys.netem_set, encode_netem_set(msg))
        if wait:
            deadline = time.time() + timeout
            while time.time() < deadline and not pending.complete:
                obs.poll()
                time.sleep(0.02)
        return msg_id, dict(pending.acks), expected
    finally:
        obs.close()


def _cmd_set(a: argparse.Namespace) -> int:
    from swarmnet.netem import NetemConfigError, parse_netem
    from swarmnet.netem.control import NetemSet, encode_netem_set

    try:
        cfg = build_config(a)
        parsed = parse_netem(cfg)
        endpoints, swarm, creds = endpoint_and_swarm(a)
        targets = [int(t) for t in a.targets.split(",")] if a.targets else None
        # the message as it will be sent (its targets, its size): refused here, naming the field
        encode_netem_set(NetemSet(0, "cli", time.time(), cfg, tuple(targets) if targets else None))
    except (NetemConfigError, ValueError, OSError) as exc:  # ConfigError (bad --keys) is a ValueError
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"netem -> swarm '{swarm}' via {', '.join(endpoints)}: {parsed.describe()}")
    t0 = time.time()
    msg_id, acks, expected = send(endpoints, swarm, cfg, targets, not a.no_wait, a.timeout, credentials=creds)
    if a.no_wait:
        print(f"sent (id {msg_id})")
        return 0
    bad = {u: k.message for u, k in acks.items() if not k.ok}
    missing = sorted(expected - set(acks))
    print(f"id {msg_id}: {len(acks) - len(bad)}/{len(expected)} UAVs applied it in {time.time() - t0:.2f} s"
          + (f"; refused by {bad}" if bad else "") + (f"; no answer from {missing}" if missing else ""))
    if not expected:
        print("warning: no live UAV seen on the swarm", file=sys.stderr)
        return 1
    return 0 if not bad and not missing else 1


def _cmd_presets(a: argparse.Namespace) -> int:
    from swarmnet.netem import CLASSES, PRESETS, parse_netem

    if a.json:
        print(json.dumps(PRESETS, indent=2))
        return 0
    for name in PRESETS:
        cfg = parse_netem({"preset": name})
        print(name)
        for cls in CLASSES:
            p = cfg.class_profile(cls)
            print(f"  {cls:7s} {p.describe() if p else 'no impairment'}")
    return 0


def _cmd_status(a: argparse.Namespace) -> int:
    run = Path(a.run)
    rows = []
    for path in sorted(run.glob("uav*.json"), key=lambda p: int(p.stem[3:]) if p.stem[3:].isdigit() else 0):
        try:
            st = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        ne = st.get("netem") or {}
        links = ne.get("links", {})
        tot = {k: sum(int(lk.get(k, 0)) for lk in links.values()) for k in ("sent", "delivered", "duplicated", "reordered")}
        dropped = sum(sum(lk.get("dropped", {}).values()) for lk in links.values())
        last = (ne.get("changes") or [{}])[-1]
        rows.append(f"UAV {st.get('uav')}: {ne.get('config', 'off')}\n    since {last.get('source', '-')} "
                    f"at {time.strftime('%H:%M:%S', time.localtime(last['t'])) if 't' in last else '-'}; "
                    f"sent {tot['sent']}, delivered {tot['delivered']}, dropped {dropped}, "
                    f"duplicated {tot['duplicated']}, reordered {tot['reordered']}")
    if not rows:
        print(f"no UAV stats in {run}", file=sys.stderr)
        return 1
    print("\n".join(rows))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mrswarm netem", description="the netem shim: presets, runtime changes, status")
    sub = ap.add_subparsers(dest="what", required=True)
    p = sub.add_parser("presets", help="list the presets and what each does per link class")
    p.add_argument("--json", action="store_true", help="the raw preset definitions")
    p.set_defaults(func=_cmd_presets)

    p = sub.add_parser("set", help="change the impairments of a running swarm (takes effect at once)")
    where = p.add_argument_group("where")
    where.add_argument("--run", help="results folder of a running `mrswarm run` (reads its network.json)")
    where.add_argument("--connect", action="append", help="Zenoh endpoint of the swarm's router (repeatable)")
    where.add_argument("--swarm", help="swarm name (default: from --run, else alpha)")
    where.add_argument("--keys", metavar="DIR", help="the experiment controller's credentials (the swarm's key directory "
                                                     "or a ctl bundle; default with --run: the run's)")
    where.add_argument("--identity", help="certificate to speak as (default ctl): only the controller may change netem")
    where.add_argument("--targets", help="comma-separated UAV ids (default: every node of the swarm)")
    what = p.add_argument_group("what (docs/netem.md)")
    what.add_argument("--preset", help="none, lan, 5g-campus, lte, degraded, wifi-mesh")
    what.add_argument("--file", help="YAML/JSON with a network.netem mapping (or a whole scenario)")
    what.add_argument("--class", dest="cls", action="append", choices=["v2v", "v2p", "ground"],
                      help="link class the flags below change (repeatable; default: all three)")
    what.add_argument("--delay", help="mean one-way delay, e.g. 100ms")
    what.add_argument("--jitter", help="jitter: sd (normal, pareto, paretonormal) or half-width (uniform)")
    what.add_argument("--distribution", default="normal", choices=["uniform", "normal", "pareto", "paretonormal"])
    what.add_argument("--correlation", type=float, help="AR(1) correlation of successive delays, 0..1")
    what.add_argument("--loss", help="loss rate, e.g. 5%% (Bernoulli; with --burst: Gilbert-Elliott)")
    what.add_argument("--burst", type=float, help="mean loss burst length in messages (Gilbert-Elliott)")
    what.add_argument("--duplicate", help="duplication probability, e.g. 1%%")
    what.add_argument("--reorder", help="probability of sending a message at once (overtaking), e.g. 25%%")
    what.add_argument("--gap", type=int, default=1, help="netem's reorder gap")
    what.add_argument("--rate", help="rate limit, e.g. 256kbit")
    what.add_argument("--limit", type=int, help="queue limit per link, messages")
    what.add_argument("--outage-every", help="mean time between radio outages, e.g. 60s")
    what.add_argument("--outage", help="outage duration or MIN:MAX, e.g. 50ms:150ms")
    what.add_argument("--outage-mode", default="drop", choices=["drop", "hold"])
    what.add_argument("--range", help="hard radio range between UAVs, e.g. 150m")
    what.add_argument("--seed", type=int, help="new seed (default: keep the UAVs' seed)")
    what.add_argument("--exempt-commands", dest="exempt_commands", action="store_true", default=None)
    what.add_argument("--impair-commands", dest="exempt_commands", action="store_false")
    p.add_argument("--no-wait", action="store_true", help="do not wait for the UAVs' acknowledgements")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for acknowledgements")
    p.set_defaults(func=_cmd_set)

    p = sub.add_parser("status", help="what each UAV of a run applies, with per-link totals (from its stats file)")
    p.add_argument("--run", required=True, help="results folder of a run")
    p.set_defaults(func=_cmd_status)
    a = ap.parse_args(argv)
    return int(a.func(a) or 0)


if __name__ == "__main__":
    sys.exit(main())
