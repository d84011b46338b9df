"""Who a certificate speaks for: the common name (CN) of every swarm node's certificate.

A CN says the node's role, its id where the role has one, and its swarm:

======================  =====================================================================
``uav-3.alpha``          UAV 3 of swarm ``alpha``: puts only its own pose, telemetry, state, acks
``gcs-1.alpha``          a ground station: may command the swarm's UAVs
``ctl.alpha``            the experiment controller (``mrswarm run``): commands, netem, faults
``edge.alpha``           the swarm's edge router: forwards what others publish, runs the pose feed
``pool-2.alpha``         pool 2 of virtual UAVs: one session speaking for the UAVs its roster
                         entry lists (:class:`~swarmnet.security.roster.Issued`, ``uavs``), and
                         for no other
======================  =====================================================================

Zenoh's access control matches a link's certificate CN exactly (``cert_common_names``), so the
swarm's rules are generated per CN from the roster (:mod:`swarmnet.security.acl`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from swarmnet.keyspace import check_swarm

ROLES = ("uav", "gcs", "ctl", "edge", "pool")
NUMBERED = ("uav", "gcs", "pool")  # roles whose CN carries an id
_CN_RE = re.compile(r"^(uav|gcs|pool)-([0-9]{1,5})\.([A-Za-z0-9_\-]{1,32})$|^(ctl|edge)\.([A-Za-z0-9_\-]{1,32})$")
_NAME_RE = re.compile(r"^(uav|gcs|pool)-([0-9]{1,5})$|^(ctl|edge)$")


@dataclass(frozen=True, order=True)
class NodeName:
    """One identity of a swarm: ``role`` (uav, gcs, ctl, edge, pool), ``node`` id (uav, gcs, pool; else 0), ``swarm``."""

    role: str
    node: int
    swarm: str

    def __post_init__(self) -> None:
        check_swarm(self.swarm)
        if self.role not in ROLES:
            raise ValueError(f"role must be one of {ROLES}, not {self.role!r}")
        if self.role in NUMBERED:
            if not 1 <= self.node <= 65535:
                raise ValueError(f"a {self.role} id is 1..65535, got {self.node}")
        elif self.node != 0:
            raise ValueError(f"a {self.role} identity has no id (one per swarm)")

    @property
    def cn(self) -> str:
        """The certificate common name, e.g. ``uav-3.alpha``."""
        return f"{self.short}.{self.swarm}"

    @property
    def short(self) -> str:
        """The name within the swarm, e.g. ``uav-3`` or ``edge``."""
        return f"{self.role}-{self.node}" if self.role in NUMBERED else self.role

    def __str__(self) -> str:
        return self.cn

    @classmethod
    def parse(cls, cn: str) -> NodeName:
        """``uav-3.alpha`` -> NodeName("uav", 3, "alpha"); ValueError for anything else."""
        m = _CN_RE.match(cn) if isinstance(cn, str) else None
        if m is None:
            raise ValueError(f"{cn!r} is not a swarm identity: expected uav-<id>.<swarm>, gcs-<id>.<swarm>, "
                             "pool-<id>.<swarm>, ctl.<swarm> or edge.<swarm>")
        if m.group(1):
            return cls(m.group(1), int(m.group(2)), m.group(3))
        return cls(m.group(4), 0, m.group(5))

    @classmethod
    def in_swarm(cls, name: str, swarm: str) -> NodeName:
        """A name within a swarm (``uav-3``, ``gcs-1``, ``ctl``, ``edge``) or a full CN of that swarm."""
        m = _NAME_RE.match(name)
        if m is None:
            ident = cls.parse(name)
            if ident.swarm != swarm:
                raise ValueError(f"{name!r} belongs to swarm {ident.swarm!r}, not {swarm!r}")
            return ident
        if m.group(1):
            return cls(m.group(1), int(m.group(2)), swarm)
        return cls(m.group(3), 0, swarm)

    @classmethod
    def uav(cls, uav: int, swarm: str) -> NodeName:
        return cls("uav", uav, swarm)
