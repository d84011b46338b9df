"""The roster of a swarm: every identity the swarm's CA issued, and the revoked ones.

``roster.json`` sits in the key directory next to ``ca.pem`` (:mod:`swarmnet.security.pki`
writes it) and travels with every node's credentials: each node generates its access-control
rules from it when its session opens (:mod:`swarmnet.security.acl`). Reading it needs no
cryptography, so a UAV process never imports the ``cryptography`` package.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import msgspec
from msgspec import Meta, field

from groundfloor.files import write_atomic
from groundfloor.schema import Config, ConfigError, decode_json
from swarmnet.security.identity import NodeName

ROSTER_FILE = "roster.json"
CA_CERT_FILE = "ca.pem"
CA_KEY_FILE = "ca.key"
MAVLINK_KEY_FILE = "mavlink.key"  # the swarm's MAVLink 2 signing passphrase (uav_stack.mavlink_signing reads it)

Seconds = Annotated[float, Meta(ge=0.0, description="Unix time, s")]


class Issued(Config, frozen=True):
    """A certificate the CA issued to one identity."""

    serial: Annotated[str, Meta(pattern=r"^[0-9a-f]{1,40}$", description="certificate serial number, hex")]
    not_after: Seconds  # the certificate expires then
    issued: Seconds
    # a pool's certificate (``pool-<id>``): the UAV ids its session speaks for (access control grants it
    # theirs and nothing else, swarmnet/security/acl.py); empty for every other identity
    uavs: tuple[Annotated[int, Meta(ge=1, le=65535)], ...] = ()


class Revoked(Config, frozen=True):
    serial: Annotated[str, Meta(pattern=r"^[0-9a-f]{1,40}$")]
    at: Seconds  # when it was revoked


class Roster(Config, frozen=True):
    """Who belongs to the swarm (``nodes``: CN -> current certificate) and who was thrown out."""

    swarm: Annotated[str, Meta(pattern=r"^[A-Za-z0-9_\-]{1,32}$")]
    ca_serial: Annotated[str, Meta(pattern=r"^[0-9a-f]{1,40}$", description="serial of the CA certificate")]
    nodes: dict[str, Issued] = field(default_factory=dict)
    revoked: dict[str, list[Revoked]] = field(default_factory=dict)  # CN -> its revoked certificates

    def __post_init__(self) -> None:
        for cn in list(self.nodes) + list(self.revoked):
            try:
                name = NodeName.parse(cn)
            except ValueError as exc:
                raise ConfigError(f"nodes.{cn}", str(exc)) from None
            if name.swarm != self.swarm:
                raise ConfigError(f"nodes.{cn}", f"belongs to swarm {name.swarm!r}, the roster is swarm {self.swarm!r}")
        for cn, issued in self.nodes.items():
            is_pool = cn.startswith("pool-")
            if is_pool and not issued.uavs:
                raise ConfigError(f"nodes.{cn}.uavs", "a pool's certificate speaks for at least one UAV")
            if not is_pool and issued.uavs:
                raise ConfigError(f"nodes.{cn}.uavs", "only a pool's certificate speaks for UAVs")

    def names(self) -> list[NodeName]:
        """The identities in good standing (issued, not revoked), sorted."""
        return sorted(NodeName.parse(cn) for cn in self.nodes if cn not in self.revoked)

    def is_member(self, cn: str) -> bool:
        return cn in self.nodes and cn not in self.revoked

    def speaks_for(self, cn: str) -> tuple[int, ...]:
        """The UAV ids a member pool's certificate speaks for (empty: not a member pool)."""
        return self.nodes[cn].uavs if self.is_member(cn) else ()

    def to_json(self) -> bytes:
        return msgspec.json.format(msgspec.json.encode(self), indent=2) + b"\n"

    @classmethod
    def load(cls, keys: str | Path) -> Roster:
        """The roster in key directory ``keys``; :class:`~groundfloor.schema.ConfigError` names what is wrong."""
        path = Path(keys) / ROSTER_FILE
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise ConfigError("", f"{path}: cannot read the swarm's roster ({exc.strerror}); "
                                  "make a key directory with `mrswarm keys init`") from None
        try:
            return decode_json(data, cls)
        except ConfigError as exc:
            raise ConfigError(exc.path, f"{path}: {exc.msg}") from None

    def save(self, keys: str | Path) -> None:
        """Write atomically (a node reading it meanwhile sees the old or the new roster, never half)."""
        write_atomic(Path(keys) / ROSTER_FILE, self.to_json())
