"""Clients that stopped reading, found and let go.

foxglove-sdk bounds what waits for each client (``message_backlog_size`` messages, the
oldest dropped first) but keeps a client that reads nothing connected for ever. This finds
such a client by its TCP connection: on Linux the kernel says how many bytes wait unsent on
each of the server's sockets (``/proc/net/tcp``); a queue that is not empty and has not
moved for :data:`STALL_S` seconds is a client that stopped reading. Its socket (one of this
process's, the SDK's) is shut down, not closed: the SDK sees the connection end, lets the
client go as it does any that leaves, and closes it itself. Elsewhere (no ``/proc``) the
backlog alone bounds a stalled client.

:class:`StallJudge` decides, time passed in; :func:`connections` and :func:`shut_down` are
the I/O."""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["STALL_S", "Connection", "StallJudge", "connections", "parse_proc_net_tcp",
           "shut_down"]

#: How long a client's unsent bytes may stand still before it is let go.
STALL_S = 5.0
_ESTABLISHED = "01"


@dataclass(frozen=True, slots=True)
class Connection:
    inode: int
    peer: str  #: ``ip:port`` of the client
    unsent: int  #: bytes waiting in the kernel for the client to read


def parse_proc_net_tcp(text: str, local_port: int) -> list[Connection]:
    """The established connections to ``local_port`` in a ``/proc/net/tcp{,6}`` table."""
    found = []
    for line in text.splitlines()[1:]:
        fields = line.split()
        if len(fields) < 10 or fields[3] != _ESTABLISHED:
            continue
        local, remote = fields[1], fields[2]
        if int(local.rsplit(":", 1)[1], 16) != local_port:
            continue
        tx_queue = int(fields[4].split(":")[0], 16)
        found.append(Connection(int(fields[9]), _peer(remote), tx_queue))
    return found


def _peer(hex_address: str) -> str:
    address, port = hex_address.rsplit(":", 1)
    raw = bytes.fromhex(address)
    if len(raw) == 4:
        host = socket.inet_ntop(socket.AF_INET, raw[::-1])
    else:  # four little-endian 32-bit words
        words = b"".join(raw[i:i + 4][::-1] for i in range(0, 16, 4))
        host = f"[{socket.inet_ntop(socket.AF_INET6, words)}]"
    return f"{host}:{int(port, 16)}"


@dataclass
class StallJudge:
    """Which connections have had bytes waiting, the same number, for :attr:`stall_s`."""

    stall_s: float = STALL_S
    _still: dict[int, tuple[int, float]] = field(default_factory=dict)  #: inode → (unsent, since)

    def stalled(self, seen: list[Connection], now: float) -> list[Connection]:
        stalled = []
        alive = set()
        for conn in seen:
            alive.add(conn.inode)
            last = self._still.get(conn.inode)
            if conn.unsent == 0 or last is None or last[0] != conn.unsent:
                self._still[conn.inode] = (conn.unsent, now)
                continue
            if now - last[1] >= self.stall_s:
                stalled.append(conn)
        for inode in set(self._still) - alive:
            del self._still[inode]
        return stalled


def connections(local_port: int) -> list[Connection] | None:
    """This machine's connections to ``local_port``; ``None`` where the kernel does not say
    (no ``/proc/net/tcp``)."""
    found: list[Connection] = []
    readable = False
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            text = Path(table).read_text(encoding="ascii")
        except OSError:
            continue
        readable = True
        found += parse_proc_net_tcp(text, local_port)
    return found if readable else None


def shut_down(inode: int) -> bool:
    """Shut down this process's socket ``inode`` (both ways), leaving its descriptor to its
    owner; ``False`` if this process holds no such socket."""
    target = f"socket:[{inode}]"
    for name in os.listdir("/proc/self/fd"):
        try:
            if os.readlink(f"/proc/self/fd/{name}") != target:
                continue
            duplicate = socket.socket(fileno=os.dup(int(name)))
        except OSError:
            continue
        try:
            if os.fstat(duplicate.fileno()).st_ino != inode:  # the number was reused
                continue
            duplicate.shutdown(socket.SHUT_RDWR)
            return True
        except OSError:
            return False
        finally:
            duplicate.close()
    return False
