"""``mrswarm keys``: a swarm's certificate authority, its members and their credentials (docs/security.md).

    mrswarm keys init --swarm alpha                   # keys/alpha: a new CA and an empty roster
    mrswarm keys issue --swarm alpha edge ctl gcs-1 --uavs 1-10
    mrswarm keys issue --swarm alpha pool-1 --speaks-for 1-50   # one session for virtual UAVs 1 to 50
    mrswarm keys bundle --swarm alpha uav-3 --out /media/usb/uav3   # what UAV 3's companion needs
    mrswarm keys revoke --swarm alpha uav-3           # a lost or stolen UAV
    mrswarm keys rotate --swarm alpha                 # a new CA: every old certificate stops working
    mrswarm keys list --swarm alpha
    mrswarm keys mavlink --swarm alpha                # the MAVLink signing key, for QGroundControl and MAVProxy
    mrswarm keys mavlink --run results/coverage-...   # the key of a run

Names are ``uav-<id>``, ``gcs-<id>``, ``pool-<id>`` (a pool of virtual UAVs), ``ctl`` (the
experiment controller) and ``edge`` (the edge router), or full certificate names such as
``uav-3.alpha``. The key directory is ``keys/<swarm>``
unless ``--dir`` says otherwise. Exit code 2 on any refusal, with one line saying why.

The MAVLink signing key (``mavlink.key``, a passphrase) is made with the CA and renewed by
``rotate`` and ``mavlink --new``; UAVs' MAVLink routers take commands only from ground
stations that sign with it (docs/security.md).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
from pathlib import Path

from swarmnet.security.identity import NodeName
from swarmnet.security.pki import CA_DAYS, NODE_DAYS, KeyDir, KeysError
from swarmnet.security.roster import CA_CERT_FILE, MAVLINK_KEY_FILE


def _dir(a: argparse.Namespace) -> Path:
    if a.dir:
        return Path(a.dir)
    if a.swarm:
        return Path("keys") / a.swarm
    raise KeysError("which swarm? give --swarm NAME (key directory keys/NAME) or --dir DIR")


def _ids(text: str | None, option: str) -> list[int]:
    """UAV ids and ranges (``1-10,12``) -> the ids; KeysError naming ``option`` for anything else."""
    out: list[int] = []
    for part in (text or "").split(","):
        if not part.strip():
            continue
        lo, _, hi = part.partition("-")
        try:
            first, last = int(lo), int(hi or lo)
        except ValueError:
            raise KeysError(f"{option} {text!r}: use ids and ranges like 1-10,12") from None
        if not 1 <= first <= last <= 65535:
            raise KeysError(f"{option} {text!r}: ids are 1..65535, ranges ascending")
        out += range(first, last + 1)
    return out


def _names(kd: KeyDir, a: argparse.Namespace) -> list[NodeName]:
    swarm = kd.roster.swarm
    names = [NodeName.in_swarm(n, swarm) for n in a.names]
    names += [NodeName.uav(u, swarm) for u in _ids(a.uavs, "--uavs")]
    if not names:
        raise KeysError("name at least one identity (uav-3, gcs-1, ctl, edge) or --uavs")
    return names


def _date(t: float) -> str:
    return dt.datetime.fromtimestamp(t, dt.UTC).strftime("%Y-%m-%d %H:%M UTC")


def _init(a: argparse.Namespace) -> int:
    if not a.swarm:
        raise KeysError("init needs --swarm NAME")
    kd = KeyDir.init(_dir(a), a.swarm, days=a.days or CA_DAYS)
    print(f"{kd.path}: CA of swarm {a.swarm!r} (keep {kd.path / 'ca.key'} off the UAVs) and its MAVLink signing key "
          f"(mrswarm keys mavlink --dir {kd.path}); next: mrswarm keys issue --dir {kd.path} edge ctl gcs-1 --uavs 1-10")
    return 0


def _issue(a: argparse.Namespace) -> int:
    kd = KeyDir(_dir(a))
    speaks_for = _ids(a.speaks_for, "--speaks-for")
    for name in _names(kd, a):
        e = kd.issue(name, days=a.days or NODE_DAYS, extra_names=a.name, renew=a.renew,
                     uavs=speaks_for if name.role == "pool" else ())
        print(f"{name.cn}: {kd.cert_path(name)} (serial {e.serial[:16]}..., valid until {_date(e.not_after)})")
    return 0


def _revoke(a: argparse.Namespace) -> int:
    kd = KeyDir(_dir(a))
    for name in _names(kd, a):
        kd.revoke(name)
        print(f"{name.cn}: revoked. Give every node the new {kd.path / 'roster.json'} and restart it: its access "
              "control then grants this certificate nothing. Zenoh cannot refuse the handshake itself (no revocation "
              "lists); `mrswarm keys rotate` makes every old certificate fail the handshake.")
        if name.role in ("uav", "gcs"):
            print(f"{name.cn} also holds the swarm's MAVLink signing key: `mrswarm keys mavlink --dir {kd.path} --new`, "
                  "then give the new one to every UAV and ground station.")
    return 0


def _rotate(a: argparse.Namespace) -> int:
    kd = KeyDir(_dir(a))
    names = kd.rotate(node_days=a.days or NODE_DAYS)
    print(f"{kd.path}: new CA and MAVLink signing key; re-issued {', '.join(n.short for n in names) or 'nobody'}. Hand "
          "every node its new bundle (mrswarm keys bundle): nodes on the old CA can no longer connect, ground stations "
          "with the old MAVLink key can no longer command.")
    return 0


def _bundle(a: argparse.Namespace) -> int:
    kd = KeyDir(_dir(a))
    names = _names(kd, a)
    if len(names) != 1:
        raise KeysError("bundle one identity at a time")
    out = kd.bundle(names[0], a.out)
    mav = f", {MAVLINK_KEY_FILE} (0600)" if (out / MAVLINK_KEY_FILE).is_file() else ""
    print(f"{out}: {CA_CERT_FILE}, roster.json, {names[0].cn}.pem, {names[0].cn}.key (0600){mav}: copy it to the node, "
          f"then e.g. `mrswarm agent --keys {out} ...`")
    return 0


def _list(a: argparse.Namespace) -> int:
    from swarmnet.security.pki import fingerprint

    kd = KeyDir(_dir(a))
    r = kd.roster
    ca = kd.path / CA_CERT_FILE
    fp = fingerprint(ca.read_bytes()) if ca.exists() else "-"
    if a.json:
        print(json.dumps({"swarm": r.swarm, "dir": str(kd.path), "ca_fingerprint": fp,
                          "nodes": {cn: {"serial": e.serial, "not_after": e.not_after} for cn, e in sorted(r.nodes.items())},
                          "revoked": {cn: [{"serial": x.serial, "at": x.at} for x in v] for cn, v in sorted(r.revoked.items())}},
                         indent=2))
        return 0
    print(f"swarm {r.swarm} in {kd.path}, CA sha256 {fp[:32]}...")
    for cn, e in sorted(r.nodes.items(), key=lambda kv: NodeName.parse(kv[0])):
        print(f"  {cn:<24} valid until {_date(e.not_after)}   serial {e.serial[:16]}...")
    for cn, revs in sorted(r.revoked.items()):
        print(f"  {cn:<24} REVOKED {_date(revs[-1].at)}")
    return 0


def _mavlink_key_file(a: argparse.Namespace) -> Path:
    """The passphrase file ``mavlink`` prints: a run's (``--run``), or the key directory's."""
    if a.run:
        from groundfloor.schema import ConfigError, decode_json

        try:
            info = decode_json((Path(a.run) / "network.json").read_bytes(), dict)
        except (OSError, ConfigError) as exc:
            raise KeysError(f"--run {a.run}: cannot read its network.json ({exc}); is it a run folder?") from None
        key = (info.get("mavlink") or {}).get("key_file") if isinstance(info, dict) else None
        if not key:
            raise KeysError(f"--run {a.run}: the run has no MAVLink signing key (gcs.mavlink off, or an older run)")
        return Path(a.run) / key if not Path(key).is_absolute() else Path(key)
    kd = KeyDir(_dir(a))
    if a.new:
        kd.new_mavlink_key()
    elif not kd.mavlink_key_path.is_file():
        raise KeysError(f"{kd.path}: no MAVLink signing key ({MAVLINK_KEY_FILE}); make one: "
                        f"mrswarm keys mavlink --dir {kd.path} --new")
    return kd.mavlink_key_path


def _mavlink(a: argparse.Namespace) -> int:
    from uav_stack.mavlink_signing import SigningKeyError, read_key_file

    if a.run and a.new:
        raise KeysError("--new changes a swarm's key directory, not a run's")
    path = _mavlink_key_file(a)
    try:
        key = read_key_file(path)
    except SigningKeyError as exc:
        raise KeysError(str(exc)) from None
    passphrase = path.read_text(encoding="ascii").strip()
    if a.json:
        print(json.dumps({"key_file": str(path), "passphrase": passphrase, "key_hex": key.hex()}))
        return 0
    print(f"MAVLink signing key ({path}){': new' if a.new else ''}")
    print(f"  passphrase      {passphrase}")
    print(f"  MAVProxy        mavproxy.py --master=... --cmd=\"signing key {passphrase}\"")
    print("                  (or type `signing key <passphrase>` at its prompt; not `signing setup`)")
    print("  QGroundControl  Application Settings > MAVLink > MAVLink 2 Signing: the passphrase as the key")
    print("                  (it derives the same key; no need to send it to the vehicle)")
    print(f"  key, hex        {key.hex()}   (SHA-256 of the passphrase: pymavlink's setup_signing)")
    return 0


def main(argv: list[str] | None = None) -> int:
    doc = __doc__.splitlines()
    ap = argparse.ArgumentParser(prog="mrswarm keys", description=doc[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="\n".join(doc[2:12]))
    sub = ap.add_subparsers(dest="what", required=True, metavar="COMMAND")

    def command(name: str, help: str, func: object, names: bool = False) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help)
        p.add_argument("--swarm", help="the swarm (key directory keys/SWARM)")
        p.add_argument("--dir", help="the key directory (default keys/SWARM)")
        if names:
            p.add_argument("names", nargs="*", metavar="NAME", help="uav-3, gcs-1, ctl, edge (or uav-3.alpha)")
            p.add_argument("--uavs", help="UAV ids and ranges, e.g. 1-10,12")
        p.set_defaults(func=func)
        return p

    p = command("init", "a new key directory: the swarm's CA and an empty roster", _init)
    p.add_argument("--days", type=int, default=None, help=f"CA validity (default {CA_DAYS})")
    p = command("issue", "a key and certificate per identity, added to the roster", _issue, names=True)
    p.add_argument("--days", type=int, default=None, help=f"validity (default {NODE_DAYS}; expiry closes the node's links)")
    p.add_argument("--name", action="append", default=[], metavar="HOST_OR_IP", help="extra subject name (repeatable)")
    p.add_argument("--renew", action="store_true", help="replace the certificate of an identity already issued")
    p.add_argument("--speaks-for", metavar="IDS", help="a pool's certificate (pool-<id>): the UAVs its session speaks "
                                                       "for, e.g. 1-50 (docs/security.md)")
    command("revoke", "take identities out of the swarm (a lost or stolen node)", _revoke, names=True)
    p = command("rotate", "a new CA and a new certificate for every member: all older certificates stop working", _rotate)
    p.add_argument("--days", type=int, default=None, help=f"validity of the re-issued certificates (default {NODE_DAYS})")
    p = command("bundle", "copy what one node needs (CA, roster, its key pair) into a directory", _bundle, names=True)
    p.add_argument("--out", required=True, help="directory to write (made 0700)")
    p = command("list", "the roster: members, expiry, revocations", _list)
    p.add_argument("--json", action="store_true")
    p = command("mavlink", "the MAVLink signing key, in the forms QGroundControl and MAVProxy take", _mavlink)
    p.add_argument("--run", help="a run's folder: its key (throw-away, like its certificates)")
    p.add_argument("--new", action="store_true", help="make a new key first: ground stations with the old one can no "
                                                      "longer command; give every UAV the new one")
    p.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    try:
        return int(a.func(a))
    except (KeysError, ValueError, OSError) as exc:  # ValueError: a bad name or swarm
        print(f"error: {exc}", file=sys.stderr)
        return 2
