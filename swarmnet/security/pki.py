"""A swarm's certificate authority and its key directory (``mrswarm keys``).

One CA per swarm signs one certificate per node; the certificate's common name says who the
node is (:mod:`swarmnet.security.identity`). The key directory holds::

    ca.pem            the CA certificate: every node trusts exactly this
    ca.key            the CA's private key (0600): keep it off the UAVs
    roster.json       who was issued a certificate, who was revoked
    beacon.key        the swarm's beacon key (0600): the discovery server derives every node's
                      beacon token from it (swarmnet/security/beacon.py)
    <cn>.pem, <cn>.key  one certificate and private key (0600) per node, e.g. uav-3.alpha.pem
    mavlink.key       the swarm's MAVLink 2 signing passphrase (0600): UAVs' MAVLink routers
                      take commands only from ground stations that sign with it (docs/security.md)
    <cn>.beacon       the node's beacon token (0600): binds its discovery beacons to this certificate

A node needs only ``ca.pem``, ``roster.json``, its own pair and its token, and a UAV or a ground
station ``mavlink.key`` too: :meth:`KeyDir.bundle` copies those into a directory of their own for a
UAV's companion computer or a container (the edge's bundle also carries ``beacon.key``, for the
discovery server beside the edge router).

Keys are ECDSA P-256 (small, fast handshakes, supported by Zenoh's TLS). Certificates carry
the CN as a DNS name too (TLS libraries verify names against the subject alternative names),
plus any extra names or IP addresses given (for ``verify_name_on_connect``).

Revocation: Zenoh 1.10 has no option to check a certificate revocation list when a link opens.
A revoked identity is taken out of the roster, so no node's access control grants it anything
and Zenoh refuses its links (docs/security.md). A revoked name is never issued again under the
same CA: the old certificate would come back with it, since access control matches names, not
serial numbers. :meth:`KeyDir.rotate` makes a new CA and re-issues every member instead.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import ipaddress
import shutil
import time
from collections.abc import Iterable
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from groundfloor.errors import MrswarmError
from groundfloor.files import write_atomic
from swarmnet.security.beacon import BEACON_KEY_FILE, derive_token, new_beacon_key, token_path
from swarmnet.security.identity import NodeName
from swarmnet.security.roster import CA_CERT_FILE, CA_KEY_FILE, MAVLINK_KEY_FILE, Issued, Revoked, Roster

CA_DAYS = 5 * 365  # the CA outlives many node certificates
NODE_DAYS = 90  # short-lived: expiry is the revocation Zenoh does enforce (close_link_on_expiration)
CLOCK_SKEW = dt.timedelta(minutes=5)  # not_before this far back: a node whose clock is a little behind accepts it


class KeysError(ValueError, MrswarmError):
    """A key directory that cannot do what was asked; the message says why and what to do."""


def write_passphrase(path: Path) -> Path:
    """A new random passphrase in ``path`` (0600, replacing any): 256 bits as 43 URL-safe
    characters, which MAVProxy (``signing key``) and QGroundControl take as typed (never one
    that starts with ``-``, which a command line would read as an option)."""
    import secrets

    passphrase = secrets.token_urlsafe(32)
    while passphrase.startswith("-"):
        passphrase = secrets.token_urlsafe(32)
    write_atomic(path, (passphrase + "\n").encode("ascii"), private=True)
    return path


def _new_key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())


def _san(names: Iterable[str]) -> list[x509.GeneralName]:
    out: list[x509.GeneralName] = []
    for n in names:
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(n)))
        except ValueError:
            out.append(x509.DNSName(n))
    return out


def fingerprint(cert_pem: bytes) -> str:
    """SHA-256 of the certificate (DER), hex: what `mrswarm keys list` shows to compare CAs."""
    der = x509.load_pem_x509_certificate(cert_pem).public_bytes(serialization.Encoding.DER)
    return hashlib.sha256(der).hexdigest()


class KeyDir:
    """A swarm's key directory: its CA, roster and node credentials (see the module docstring)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    # ---- files ------------------------------------------------------------------------------
    def cert_path(self, name: NodeName) -> Path:
        return self.path / f"{name.cn}.pem"

    def key_path(self, name: NodeName) -> Path:
        return self.path / f"{name.cn}.key"

    @property
    def mavlink_key_path(self) -> Path:
        return self.path / MAVLINK_KEY_FILE

    def new_mavlink_key(self) -> Path:
        """A new MAVLink signing passphrase for the swarm (the old one stops working once each
        UAV has the new one); needs the CA, as only the swarm's own directory may change it."""
        self._ca()
        return write_passphrase(self.mavlink_key_path)

    @property
    def roster(self) -> Roster:
        from groundfloor.schema import ConfigError

        try:
            return Roster.load(self.path)
        except ConfigError as exc:
            raise KeysError(str(exc)) from None

    def _ca(self) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey]:
        try:
            cert = x509.load_pem_x509_certificate((self.path / CA_CERT_FILE).read_bytes())
            key = serialization.load_pem_private_key((self.path / CA_KEY_FILE).read_bytes(), password=None)
        except FileNotFoundError as exc:
            raise KeysError(f"{self.path}: no CA here ({Path(exc.filename).name} missing); a node's bundle cannot "
                            "issue, revoke or rotate: use the swarm's key directory (mrswarm keys init)") from None
        if not isinstance(key, ec.EllipticCurvePrivateKey):
            raise KeysError(f"{self.path / CA_KEY_FILE}: not an EC private key")
        return cert, key

    # ---- the CA -------------------------------------------------------------------------------
    @classmethod
    def init(cls, path: str | Path, swarm: str, days: int = CA_DAYS) -> KeyDir:
        """Make a new key directory with a fresh CA for ``swarm``; refuses to overwrite one."""
        kd = cls(path)
        NodeName("edge", 0, swarm)  # checks the swarm name
        if (kd.path / CA_CERT_FILE).exists() or (kd.path / CA_KEY_FILE).exists():
            raise KeysError(f"{kd.path} already holds a CA; `mrswarm keys rotate` replaces it")
        kd.path.mkdir(parents=True, exist_ok=True)
        kd.path.chmod(0o700)
        serial = kd._write_ca(swarm, days)
        Roster(swarm=swarm, ca_serial=serial).save(kd.path)
        write_passphrase(kd.mavlink_key_path)
        kd.beacon_key()
        return kd

    def beacon_key(self) -> bytes:
        """The swarm's beacon key, made now if this directory (one with the CA) has none yet."""
        path = self.path / BEACON_KEY_FILE
        try:
            return path.read_bytes().strip()
        except FileNotFoundError:
            if not (self.path / CA_KEY_FILE).exists():
                raise KeysError(f"{self.path}: no {BEACON_KEY_FILE} here, and no CA to make one (a node's bundle?)") from None
        write_atomic(path, new_beacon_key(), private=True)
        return path.read_bytes().strip()

    def ensure_tokens(self, names: Iterable[NodeName]) -> list[NodeName]:
        """Write the beacon tokens a directory made before them lacks, for these members; the ones written."""
        roster = self.roster
        done = []
        for name in names:
            if roster.is_member(name.cn) and not token_path(self.path, name.cn).exists():
                self.write_token(name, roster.nodes[name.cn].serial)
                done.append(name)
        return done

    def write_token(self, name: NodeName, serial: str, dest: Path | None = None) -> Path:
        """``<cn>.beacon``: the beacon token of ``name``'s certificate ``serial`` (in ``dest``, default here)."""
        path = token_path(dest or self.path, name.cn)
        write_atomic(path, derive_token(self.beacon_key(), name.cn, serial).hex().encode() + b"\n", private=True)
        return path

    def _write_ca(self, swarm: str, days: int) -> str:
        key = _new_key()
        name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"mrswarm {swarm} CA"),
                          x509.NameAttribute(NameOID.ORGANIZATION_NAME, f"mrswarm swarm {swarm}")])
        now = dt.datetime.now(dt.UTC)
        ski = x509.SubjectKeyIdentifier.from_public_key(key.public_key())
        cert = (
            x509.CertificateBuilder()
            .subject_name(name).issuer_name(name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - CLOCK_SKEW).not_valid_after(now + dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                                         data_encipherment=False, key_agreement=False, key_cert_sign=True, crl_sign=True,
                                         encipher_only=False, decipher_only=False), critical=True)
            .add_extension(ski, critical=False)
            .sign(key, hashes.SHA256())
        )
        write_atomic(self.path / CA_KEY_FILE, _key_pem(key), private=True)
        (self.path / CA_CERT_FILE).write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        return format(cert.serial_number, "x")

    def rotate(self, days: int = CA_DAYS, node_days: int = NODE_DAYS) -> list[NodeName]:
        """A new CA, a new certificate for every member and a new MAVLink signing key: every
        older certificate, revoked or not, and the old MAVLink key stop working at once. Revoked
        names may be issued again afterwards. Returns the re-issued identities (hand each its
        new bundle)."""
        old = self.roster
        members = old.names()
        serial = self._write_ca(old.swarm, days)
        write_passphrase(self.mavlink_key_path)
        roster = Roster(swarm=old.swarm, ca_serial=serial)
        roster.save(self.path)
        for cn in old.revoked:  # their certificates no longer chain to the CA: delete the leftovers
            for p in (self.path / f"{cn}.pem", self.path / f"{cn}.key", token_path(self.path, cn)):
                p.unlink(missing_ok=True)
        for name in members:
            self.issue(name, days=node_days, uavs=old.nodes[name.cn].uavs)
        return members

    # ---- node certificates ------------------------------------------------------------------------
    def issue(self, name: NodeName, days: int = NODE_DAYS, extra_names: Iterable[str] = (), renew: bool = False,
              uavs: Iterable[int] = ()) -> Issued:
        """A new key and certificate for ``name``, added to the roster; a pool's (``pool-<id>``) speaks
        for the UAV ids ``uavs`` (at least one), which the roster records for access control.

        Refuses a name already issued (``renew=True`` replaces its certificate: the old one stays
        valid until it expires, as it belongs to the same node) and a revoked name (see the module
        docstring: rotate the CA to reuse it).
        """
        roster = self.roster
        if name.swarm != roster.swarm:
            raise KeysError(f"{name.cn} is not of swarm {roster.swarm!r} (this key directory's swarm)")
        if name.cn in roster.revoked:
            raise KeysError(f"{name.cn} was revoked: Zenoh cannot check revocation lists, and its access control matches "
                            "names, so a new certificate with this name would let the revoked one back in. "
                            "Rotate the CA (`mrswarm keys rotate`) to reuse the name, or issue another id")
        if name.cn in roster.nodes and not renew:
            raise KeysError(f"{name.cn} already has a certificate (renew it with --renew)")
        if not 1 <= days <= CA_DAYS:
            raise KeysError(f"days must be 1..{CA_DAYS}, got {days}")
        speaks_for = tuple(sorted(set(uavs)))
        if (name.role == "pool") != bool(speaks_for):
            raise KeysError(f"{name.cn}: a pool's certificate names the UAVs it speaks for (--speaks-for), "
                            "and only a pool's does")
        if any(not 1 <= u <= 65535 for u in speaks_for):
            raise KeysError(f"{name.cn}: UAV ids are 1..65535, got {list(speaks_for)}")
        ca_cert, ca_key = self._ca()
        key = _new_key()
        now = dt.datetime.now(dt.UTC)
        not_after = min(now + dt.timedelta(days=days), ca_cert.not_valid_after_utc)
        cert = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name.cn)]))
            .issuer_name(ca_cert.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - CLOCK_SKEW).not_valid_after(not_after)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                         data_encipherment=False, key_agreement=False, key_cert_sign=False, crl_sign=False,
                                         encipher_only=False, decipher_only=False), critical=True)
            # every node both listens (server) and dials (client)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.SubjectAlternativeName(_san([name.cn, *extra_names])), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256())
        )
        write_atomic(self.key_path(name), _key_pem(key), private=True)
        self.cert_path(name).write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        entry = Issued(serial=format(cert.serial_number, "x"), not_after=not_after.timestamp(), issued=time.time(),
                       uavs=speaks_for)
        self.write_token(name, entry.serial)
        self._save_roster(roster, nodes={**roster.nodes, name.cn: entry})
        return entry

    def revoke(self, name: NodeName) -> Revoked:
        """Take ``name`` out of the swarm: out of the roster's members, its files deleted here."""
        roster = self.roster
        entry = roster.nodes.get(name.cn)
        if entry is None:
            raise KeysError(f"{name.cn} has no certificate in {self.path} (see `mrswarm keys list`)")
        rev = Revoked(serial=entry.serial, at=time.time())
        nodes = {cn: e for cn, e in roster.nodes.items() if cn != name.cn}
        revoked = {**roster.revoked, name.cn: [*roster.revoked.get(name.cn, []), rev]}
        self._save_roster(roster, nodes=nodes, revoked=revoked)
        self.key_path(name).unlink(missing_ok=True)
        self.cert_path(name).unlink(missing_ok=True)
        token_path(self.path, name.cn).unlink(missing_ok=True)
        return rev

    def _save_roster(self, roster: Roster, **changes: object) -> None:
        import msgspec

        msgspec.structs.replace(roster, **changes).save(self.path)

    def bundle(self, name: NodeName, out: str | Path) -> Path:
        """Copy what node ``name`` needs (CA certificate, roster, its own pair, its beacon token, and for
        a UAV or a ground station the MAVLink signing key) into directory ``out``; the edge's bundle also
        gets the beacon key (its discovery server checks every token)."""
        roster = self.roster
        if not roster.is_member(name.cn):
            raise KeysError(f"{name.cn} is not a member of swarm {roster.swarm!r} (issue it first)")
        dest = Path(out)
        dest.mkdir(parents=True, exist_ok=True)
        dest.chmod(0o700)
        shutil.copyfile(self.path / CA_CERT_FILE, dest / CA_CERT_FILE)
        roster.save(dest)
        shutil.copyfile(self.cert_path(name), dest / self.cert_path(name).name)
        write_atomic(dest / self.key_path(name).name, self.key_path(name).read_bytes(), private=True)
        if name.role in ("uav", "gcs") and self.mavlink_key_path.is_file():
            write_atomic(dest / MAVLINK_KEY_FILE, self.mavlink_key_path.read_bytes(), private=True)
        token = token_path(self.path, name.cn)
        if token.exists():
            write_atomic(token_path(dest, name.cn), token.read_bytes(), private=True)
        else:  # a directory from before beacon tokens: made from its beacon key
            self.write_token(name, roster.nodes[name.cn].serial, dest)
        if name.role == "edge":
            write_atomic(dest / BEACON_KEY_FILE, self.beacon_key() + b"\n", private=True)
        return dest
