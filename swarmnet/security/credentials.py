"""A node's credentials, and what they change in its Zenoh configuration.

:class:`Credentials` names a key directory (or a node's bundle of one, see
:mod:`swarmnet.security.pki`) and the identity to speak as. :meth:`Credentials.secure` turns a
plain session configuration into a secured one:

* every link is TLS with mutual authentication: the node presents its certificate when it
  listens and when it dials, and accepts only certificates of the swarm's CA;
* every ``tcp/`` endpoint becomes ``tls/`` (the discovery proxy then advertises ``tls/``
  locators, and peers dial them as such), and ``tls`` is the only link protocol the session
  opens or accepts (``transport.link.protocols``): nothing makes it dial a plaintext locator;
* the swarm's access control, generated from the roster (:mod:`swarmnet.security.acl`).

Names are not verified on connect (``verify_name_on_connect: false``): peers dial each other
by the addresses discovery advertises, which no certificate can list in advance. Mutual
authentication against the swarm's CA plus access control by common name does the job a name
check would. Links close when the certificate at either end expires.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import msgspec
from msgspec import Meta

from groundfloor.schema import Config, ConfigError
from swarmnet.security.identity import NodeName
from swarmnet.security.roster import CA_CERT_FILE, Roster

SECURE_SCHEMES = ("tls",)
PLAIN_SCHEMES = ("tcp",)  # turned into tls/ by secure_endpoint


def secure_endpoint(endpoint: str) -> str:
    """``tcp/HOST:PORT`` -> ``tls/HOST:PORT`` (``tls/`` unchanged); ValueError for other protocols."""
    proto, sep, rest = endpoint.partition("/")
    if not sep or not rest:
        raise ValueError(f"{endpoint!r} is not a Zenoh endpoint (PROTO/ADDRESS)")
    if proto in SECURE_SCHEMES:
        return endpoint
    if proto in PLAIN_SCHEMES:
        return f"tls/{rest}"
    raise ValueError(f"{endpoint!r}: a secured swarm speaks tls/ (or tcp/, turned into tls/), not {proto}/")


class Credentials(Config, frozen=True):
    """Where a node finds its certificate, key, CA and roster, and which identity it speaks as."""

    keys: Annotated[str, Meta(min_length=1, description="key directory (mrswarm keys init) or a node's bundle")]
    # the certificate's common name; "" = the node's own (uav-<id>.<swarm>), filled in by for_node
    identity: str = ""

    def for_node(self, name: NodeName) -> Credentials:
        """These credentials for ``name`` unless they already name an identity."""
        return self if self.identity else msgspec.structs.replace(self, identity=name.cn)

    @property
    def name(self) -> NodeName:
        try:
            return NodeName.parse(self.identity)
        except ValueError as exc:
            raise ConfigError("identity", str(exc)) from None

    def files(self) -> tuple[Path, Path, Path]:
        """(CA certificate, node certificate, node key); ConfigError naming what is missing."""
        name = self.name
        d = Path(self.keys)
        ca, cert, key = d / CA_CERT_FILE, d / f"{name.cn}.pem", d / f"{name.cn}.key"
        wanted = ((ca, "the swarm's CA certificate"), (cert, f"{name.cn}'s certificate"), (key, f"{name.cn}'s private key"))
        for p, what in wanted:
            if not p.is_file():
                raise ConfigError("keys", f"{p} missing ({what}); issue it with `mrswarm keys issue {name.short} "
                                          f"--dir <the swarm's key directory>` and copy its bundle here")
        return ca, cert, key

    def beacon_token(self) -> bytes | None:
        """This identity's beacon token (``<cn>.beacon``), which binds its discovery beacons to it; None
        if the directory has none (one made before beacon tokens: ``mrswarm keys bundle`` writes it)."""
        from swarmnet.security.beacon import read_token

        try:
            return read_token(self.keys, self.name.cn)
        except ValueError as exc:
            raise ConfigError("keys", str(exc)) from None

    def roster(self) -> Roster:
        roster = Roster.load(self.keys)
        if roster.swarm != self.name.swarm:
            raise ConfigError("keys", f"{self.keys} is swarm {roster.swarm!r}'s, not {self.name.swarm!r}'s")
        return roster

    def tls(self) -> dict[str, Any]:
        """The ``transport.link.tls`` section: mutual TLS with this node's certificate both ways."""
        ca, cert, key = self.files()
        return {
            "root_ca_certificate": str(ca.resolve()),
            "enable_mtls": True,
            "listen_certificate": str(cert.resolve()), "listen_private_key": str(key.resolve()),
            "connect_certificate": str(cert.resolve()), "connect_private_key": str(key.resolve()),
            "verify_name_on_connect": False,
            "close_link_on_expiration": True,
        }

    def secure(self, cfg: dict[str, Any]) -> dict[str, Any]:
        """``cfg`` (a Zenoh configuration as a dict) with TLS, tls/ endpoints and access control."""
        from swarmnet.security.acl import access_control

        for section in ("connect", "listen"):
            if section not in cfg:
                continue
            try:
                cfg[section]["endpoints"] = [secure_endpoint(e) for e in cfg[section].get("endpoints", [])]
            except ValueError as exc:
                raise ConfigError(section, str(exc)) from None
        link = cfg.setdefault("transport", {}).setdefault("link", {})
        link["tls"] = self.tls()
        # the only link protocol the session opens or accepts: a Hello, a gossip message or a registry
        # entry with a tcp/ (or any other) locator never makes a secured node open a plaintext link
        link["protocols"] = list(SECURE_SCHEMES)
        cfg["access_control"] = access_control(self.roster())
        return cfg
