"""The ready lines a server prints once every board is served, ``ready NAME WHERE``, and
what ``WHERE`` is: an address a client can use as given (docs/emulator.md, "The ready
lines"; docs/cli.md, ``router``). Scripts and tests read them: three words, or with a
``--link`` five (``ready NAME LINK -> PTY``)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["pty_where", "ready_line", "usable_url"]


def ready_line(name: str, where: str) -> str:
    """The line that says board (or endpoint) ``name`` is served at ``where``."""
    return f"ready {name} {where}"


def pty_where(path: str, link: Path | None = None) -> str:
    """Where a pty is: its path, or ``LINK -> PTY`` behind a stable link."""
    return path if link is None else f"{link} -> {path}"


def usable_url(address: str, port: int) -> str:
    """``socket://…`` a client can connect to: a wildcard address becomes its family's
    loopback."""
    address = {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(address, address)
    host = f"[{address.split('%')[0]}]" if ":" in address else address
    return f"socket://{host}:{port}"
