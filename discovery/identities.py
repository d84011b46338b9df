"""The discovery server's side of identity-bound beacons: who may speak for which registry entry.

A swarm whose key directory the server was given (``mrswarm discovery serve --identities DIR``:
the swarm's key directory, or the edge's bundle, which holds ``roster.json`` and ``beacon.key``)
accepts a BEACON or a BYE only with the node tag of the identity it speaks for
(swarmnet/security/beacon.py): the entry's role and id name a certificate of the roster
(:func:`certificate_of`), whose current serial gives the token the tag must be made with. One
member's credentials therefore add, replace or remove only that member's own entry; a revoked or
unknown identity is refused. The roster is read again when its file changes (a revocation takes
effect within a second, without restarting the server).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from groundfloor.schema import ConfigError
from swarmnet.security.beacon import BEACON_KEY_FILE, derive_token
from swarmnet.security.roster import ROSTER_FILE, Roster

RELOAD_EVERY_S = 1.0  # s between two looks at the roster file's modification time


def certificate_of(role: str, node: int, swarm: str) -> str:
    """The certificate a discovery role speaks with: ``uav-N``, ``gcs-N``; the runner's observer is
    ``ctl``, an edge node ``edge`` (one identity per swarm, whatever its discovery id)."""
    if role in ("uav", "gcs"):
        return f"{role}-{node}.{swarm}"
    return f"{'ctl' if role == 'observer' else role}.{swarm}"


@dataclass
class SwarmIdentities:
    """One swarm's roster and beacon key, as the discovery server checks tags against them."""

    path: Path
    swarm: str = ""
    beacon_key: bytes = b""
    roster: Roster | None = None
    _mtime: float = -1.0
    _checked: float = 0.0
    _tokens: dict[str, bytes | None] = field(default_factory=dict)

    @classmethod
    def load(cls, keys: str | Path) -> SwarmIdentities:
        """From a key directory (or an edge bundle); ValueError naming what is missing."""
        ids = cls(Path(keys))
        try:
            ids.beacon_key = (ids.path / BEACON_KEY_FILE).read_bytes().strip()
        except OSError as exc:
            raise ValueError(f"{ids.path / BEACON_KEY_FILE}: {exc.strerror} (the swarm's key directory, or the edge's "
                             "bundle, holds it)") from None
        ids.reload(force=True)
        assert ids.roster is not None
        ids.swarm = ids.roster.swarm
        return ids

    def reload(self, force: bool = False, now: float | None = None) -> None:
        """Read the roster again if its file changed (looked at once per RELOAD_EVERY_S)."""
        now = time.monotonic() if now is None else now
        if not force and now - self._checked < RELOAD_EVERY_S:
            return
        self._checked = now
        try:
            mtime = os.stat(self.path / ROSTER_FILE).st_mtime
        except OSError:
            if force:
                raise ValueError(f"{self.path / ROSTER_FILE}: cannot read the swarm's roster") from None
            return  # keep the last one read
        if mtime == self._mtime and not force:
            return
        try:
            roster = Roster.load(self.path)
        except ConfigError as exc:
            if force:
                raise ValueError(str(exc)) from None
            return
        self.roster, self._mtime, self._tokens = roster, mtime, {}

    def token(self, role: str, node: int) -> bytes | None:
        """The token a beacon of ``(role, node)`` must be tagged with; None: no member may speak for it."""
        self.reload()
        cn = certificate_of(role, node, self.swarm)
        if cn not in self._tokens:
            roster = self.roster
            issued = roster.nodes.get(cn) if roster is not None and roster.is_member(cn) else None
            self._tokens[cn] = derive_token(self.beacon_key, cn, issued.serial) if issued is not None else None
        return self._tokens[cn]
