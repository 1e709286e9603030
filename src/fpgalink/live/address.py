"""Where a live view listens: ``--foxglove [HOST:]PORT``. Loopback unless a host is given;
port 0 takes a free one."""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass

__all__ = ["DEFAULT_PORT", "LiveAddress", "parse_address"]

#: Foxglove's own default for a WebSocket connection (its "Open connection" dialog).
DEFAULT_PORT = 8765


@dataclass(frozen=True, slots=True)
class LiveAddress:
    host: str
    port: int

    @property
    def loopback(self) -> bool:
        if self.host == "localhost":
            return True
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:  # a host name: only what it resolves to can tell
            return False

    def url(self, port: int | None = None) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port if port is None else port}"


def parse_address(text: str) -> LiveAddress:
    """``8765`` (loopback), ``127.0.0.1:8765``, ``[::1]:0``, ``0.0.0.0:8765`` (every
    interface: asked for by giving it). ``ValueError`` with the form expected."""
    text = text.strip()
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host, port_text = "127.0.0.1", text
    host = host.strip("[]")
    if not host or not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise ValueError(f"{text!r}: expected [HOST:]PORT, PORT 0..65535 (0: a free one), "
                         "HOST loopback unless given")
    return LiveAddress(host, int(port_text))
