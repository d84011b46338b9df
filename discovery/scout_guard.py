"""Only this node's own discovery proxy may speak to its Zenoh session's scouting sockets.

Zenoh 1.10.2 binds a session's scouting sockets to the wildcard address, ``0.0.0.0:<ephemeral>``,
whatever ``scouting.multicast.interface`` says (``Runtime::bind_ucast_port`` in
``zenoh/src/net/runtime/orchestrator.rs``; the interface only picks the multicast egress), and it
dials the locators of any Hello that reaches them, from anyone. Zenoh has no option to bind them
elsewhere or to filter their senders. So, once the proxy has learnt them
(:meth:`discovery.proxy.DiscoveryProxy.learn`), this module attaches a classic BPF socket filter
to each of them in the kernel (``SO_ATTACH_FILTER``, then ``SO_LOCK_FILTER`` so it cannot be
taken off): a datagram is delivered only if it comes from a loopback address (``127.0.0.0/8``;
the kernel drops loopback sources arriving from any other interface) **and** from one of the
node's own UDP ports: the proxy's injection socket, and the scouting sockets themselves (Zenoh's
own scouts and their answers). Everything else is dropped by the kernel before Zenoh sees it,
and counted in the socket's drop counter (``SO_MEMINFO``), which the proxy reads into
``refused.scouting``. No other process can send from those ports (they are bound) or from a
loopback address on another interface, short of root (raw sockets).

The session's scouting responder (``127.0.0.1:P``) gets the same filter with the scouting
sockets as its only senders, so no other process can ask it for the node's Hello.

Linux only (classic BPF socket filters); :class:`GuardError` elsewhere.
"""

from __future__ import annotations

import ctypes
import socket
import struct
from collections.abc import Iterable

from groundfloor.errors import MrswarmError
from swarmnet.own_sockets import kernel_drops, udp_sockets

SO_ATTACH_FILTER = getattr(socket, "SO_ATTACH_FILTER", 26)
SO_LOCK_FILTER = getattr(socket, "SO_LOCK_FILTER", 44)

# classic BPF (linux/filter.h)
_LD_W_ABS, _LD_H_ABS, _ALU_AND_K, _JEQ_K, _RET_K = 0x20, 0x28, 0x54, 0x15, 0x06
_SKF_NET_OFF = -0x100000  # loads relative to the network (IP) header instead of the UDP header
_LOOPBACK_NET, _LOOPBACK_MASK = 0x7F000000, 0xFF000000
_ACCEPT, _DROP = 0xFFFFFFFF, 0


class GuardError(OSError, MrswarmError):
    """The scouting sockets could not be found or filtered."""


def _insn(code: int, jt: int, jf: int, k: int) -> bytes:
    return struct.pack("HBBI", code, jt, jf, k & 0xFFFFFFFF)


def loopback_ports_filter(ports: Iterable[int]) -> bytes:
    """A BPF program for a UDP socket: accept datagrams from 127.0.0.0/8 whose source port is one of ``ports``."""
    allowed = sorted(set(ports))
    if not 1 <= len(allowed) <= 64:
        raise ValueError("1..64 allowed ports")
    n = len(allowed)
    prog = [
        _insn(_LD_W_ABS, 0, 0, _SKF_NET_OFF + 12),  # A = IPv4 source address
        _insn(_ALU_AND_K, 0, 0, _LOOPBACK_MASK),
        _insn(_JEQ_K, 0, n + 1, _LOOPBACK_NET),  # not loopback: to the drop
        _insn(_LD_H_ABS, 0, 0, 0),  # A = UDP source port
    ]
    for i, port in enumerate(allowed):  # a match jumps over the remaining tests and the drop to the accept
        prog.append(_insn(_JEQ_K, n - i, 0, port))
    prog += [_insn(_RET_K, 0, 0, _DROP), _insn(_RET_K, 0, 0, _ACCEPT)]
    return b"".join(prog)


def attach_filter(sock: socket.socket, program: bytes) -> None:
    """Attach ``program`` to ``sock`` and lock it there (it applies to every descriptor of the socket)."""
    buf = ctypes.create_string_buffer(program, len(program))
    fprog = struct.pack("HP", len(program) // 8, ctypes.addressof(buf))
    sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, fprog)
    sock.setsockopt(socket.SOL_SOCKET, SO_LOCK_FILTER, 1)


class ScoutGuard:
    """The filters on one session's scouting sockets and responder; :meth:`dropped` counts what they kept out."""

    def __init__(self, sockets: list[socket.socket]):
        self.sockets = sockets
        self._base = [kernel_drops(s) for s in sockets]

    @classmethod
    def install(cls, scouting_ports: list[int], responder_port: int, proxy_port: int) -> ScoutGuard:
        """Filter the session's scouting sockets (``0.0.0.0:<port>``) and its responder (``127.0.0.1:<port>``)."""
        wanted = {("0.0.0.0", p) for p in scouting_ports} | {("127.0.0.1", responder_port)}
        found = udp_sockets(wanted)
        missing = wanted - set(found)
        if missing:
            for s in found.values():
                s.close()
            raise GuardError(f"scouting sockets not found in this process: {sorted(missing)}")
        try:
            scouts = loopback_ports_filter([proxy_port, *scouting_ports])
            answers = loopback_ports_filter(scouting_ports)
            for addr, s in found.items():
                attach_filter(s, answers if addr[1] == responder_port and addr[0] == "127.0.0.1" else scouts)
            return cls(list(found.values()))
        except OSError as exc:
            for s in found.values():
                s.close()
            raise GuardError(f"cannot filter the scouting sockets: {exc}") from None

    def dropped(self) -> int:
        """Datagrams the guarded sockets dropped since :meth:`install` (0 for a socket closed meanwhile)."""
        total = 0
        for s, base in zip(self.sockets, self._base, strict=True):
            try:
                total += kernel_drops(s) - base
            except OSError:
                pass
        return total

    def close(self) -> None:
        for s in self.sockets:
            s.close()
        self.sockets = []
        self._base = []
