"""Beacon tokens: what binds a node's discovery beacons to its certificate.

The swarm's discovery key is shared by every member, so by itself it lets any member announce
(or say goodbye for) any other. Each node therefore also holds a **beacon token** of its own,
written beside its certificate (``<cn>.beacon``, 0600) when ``mrswarm keys issue`` issues it::

    token = HMAC-SHA256(beacon key, "mrswarm-beacon" 0x00 <cn> 0x00 <certificate serial>)

The beacon key (``beacon.key`` in the key directory, 0600) stays with whoever issues and with the
discovery server (the edge bundle carries it); nodes hold only their own token. The node tags every
beacon and goodbye with it (discovery/protocol.py), and a server started with the swarm's key
directory (``--identities``) derives the token of the identity a beacon speaks for from the roster
(its current certificate's serial; none for a revoked or unknown name) and refuses any other.
A renewed or re-issued certificate has a new serial, hence a new token.

Tokens are derived only by the key tools and the discovery server: a UAV reads its token from a
file and tags with discovery's built-in HMAC, so it loads no OpenSSL for this.
"""

from __future__ import annotations

import os
from pathlib import Path

BEACON_KEY_FILE = "beacon.key"
TOKEN_SUFFIX = ".beacon"
TOKEN_LEN = 32


def token_path(keys: str | Path, cn: str) -> Path:
    return Path(keys) / f"{cn}{TOKEN_SUFFIX}"


def new_beacon_key() -> bytes:
    return os.urandom(32).hex().encode()


def derive_token(beacon_key: bytes, cn: str, serial: str) -> bytes:
    """The beacon token of certificate ``serial`` of ``cn`` (the key tools and the discovery server only)."""
    import hmac  # here: loads OpenSSL, which a UAV never needs

    return hmac.new(beacon_key, b"mrswarm-beacon\0" + cn.encode() + b"\0" + serial.encode(), "sha256").digest()


def read_token(keys: str | Path, cn: str) -> bytes | None:
    """``cn``'s token from its file in ``keys`` (hex); None if there is none. ValueError for a damaged one."""
    path = token_path(keys, cn)
    try:
        text = path.read_text().strip()
    except FileNotFoundError:
        return None
    try:
        token = bytes.fromhex(text)
    except ValueError:
        raise ValueError(f"{path}: not a beacon token (hex)") from None
    if len(token) != TOKEN_LEN:
        raise ValueError(f"{path}: a beacon token has {TOKEN_LEN} bytes, this one {len(token)}")
    return token
