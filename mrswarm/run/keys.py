"""The credentials a run (or a deployment) needs: throw-away ones made per run, or the swarm's own.

``mrswarm run`` is secure with zero extra steps: unless the scenario names a key directory
(``network.security.keys``), it makes a fresh CA in ``<run>/keys`` (0700, private keys 0600)
and a certificate for every identity the run needs: each UAV, the edge router (``edge``), the
runner (``ctl``) and one ground station (``gcs-1``, for ``mrswarm gcs --run``). They expire a
day after the run is long over (the CA dies with them), so a copied run folder opens nothing.
The directory also holds the run's MAVLink signing key (``mavlink.key``): QGroundControl or
MAVProxy command the run's UAVs with it (``mrswarm keys mavlink --run <run>``).

With ``network.security.keys`` the run uses that directory as it is: each identity must have
been issued there (``mrswarm keys issue``); the run never changes a swarm's own PKI. (A directory
made before beacon tokens gets the tokens of the run's identities written from its beacon key,
docs/security.md: nothing else.)
"""

from __future__ import annotations

from pathlib import Path

from swarmnet.security.identity import NodeName
from swarmnet.security.pki import KeyDir, KeysError
from swarmnet.security.roster import Roster

THROWAWAY_DAYS = 2  # a run lasts at most 2 h (Scenario.duration)
RUN_KEYS = "keys"  # <run>/keys


Pools = dict[int, tuple[int, ...]]  # pool number -> the UAV ids its session speaks for


def run_identities(swarm: str, uavs: list[int]) -> list[NodeName]:
    """Every identity a run of these UAVs speaks as: the UAVs, the edge router, the runner, one ground station."""
    return [*(NodeName.uav(u, swarm) for u in uavs), NodeName("edge", 0, swarm), NodeName("ctl", 0, swarm),
            NodeName("gcs", 1, swarm)]


def throwaway_keys(path: Path, swarm: str, names: list[NodeName], days: int = THROWAWAY_DAYS, pools: Pools | None = None) -> Path:
    """A fresh CA in ``path`` with a certificate for each of ``names`` and each pool of ``pools``."""
    kd = KeyDir.init(path, swarm, days=days)
    for name in names:
        kd.issue(name, days=days, extra_names=("127.0.0.1",))
    for k, uavs in (pools or {}).items():
        kd.issue(NodeName("pool", k, swarm), days=days, extra_names=("127.0.0.1",), uavs=uavs)
    return kd.path


def check_keys(path: Path, swarm: str, names: list[NodeName], pools: Pools | None = None) -> Path:
    """``path`` if it holds a member certificate and key for each of ``names`` and for each pool of
    ``pools``, speaking for at least that pool's UAVs; KeysError saying what is missing."""
    try:
        roster = Roster.load(path)
    except ValueError as exc:
        raise KeysError(str(exc)) from None
    if roster.swarm != swarm:
        raise KeysError(f"{path} holds the keys of swarm {roster.swarm!r}, not {swarm!r}")
    kd = KeyDir(path)
    missing = [n.short for n in names
               if not (roster.is_member(n.cn) and kd.cert_path(n).is_file() and kd.key_path(n).is_file())]
    if missing:
        raise KeysError(f"{path} has no certificate for {', '.join(missing)}: "
                        f"`mrswarm keys issue --dir {path} {' '.join(missing)}`")
    for k, uavs in (pools or {}).items():
        pool = NodeName("pool", k, swarm)
        if not set(uavs) <= set(roster.speaks_for(pool.cn)) or not kd.cert_path(pool).is_file():
            ids = ",".join(str(u) for u in uavs)
            raise KeysError(f"{path} has no certificate for {pool.short} speaking for UAVs {ids} (fleet.pool): "
                            f"`mrswarm keys issue --dir {path} {pool.short} --speaks-for {ids}` (or --renew it), "
                            "or fly a process per UAV (fleet.pool: 1)")
        names = [*names, pool]
    kd.ensure_tokens(names)
    return path.resolve()


def ensure_keys(path: Path, swarm: str, names: list[NodeName]) -> Path:
    """A lasting key directory for a deployment: made if missing, the missing identities (and
    MAVLink signing key) issued."""
    kd = KeyDir(path) if (path / "roster.json").exists() else KeyDir.init(path, swarm)
    if not kd.mavlink_key_path.is_file():
        kd.new_mavlink_key()
    roster = kd.roster
    for n in names:
        if not roster.is_member(n.cn):
            kd.issue(n)
    return check_keys(path, swarm, names)
