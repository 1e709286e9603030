"""What offering a board on this machine's ports takes at the level of the operating system,
shared by ``fpgaemu serve`` and ``fpgalink-cli router``: a raw pseudo-terminal and the
writes to its master side (:mod:`.pty`), the stable ``--link`` symlink to it
(:mod:`.links`), and the ready lines that say where a board is served (:mod:`.ready`).

The standard library only, nothing else of fpgalink: the emulator may import it beside
:mod:`fpgalink.protocol` (docs/architecture.md)."""

from __future__ import annotations

from fpgalink.ports.links import (
    LinkError,
    LinkSpecError,
    LinkTaken,
    make_link,
    parse_links,
    remove_own_link,
)
from fpgalink.ports.pty import PtyOutput, RawPty, open_raw_pty
from fpgalink.ports.ready import pty_where, ready_line, usable_url

__all__ = [
    "LinkError",
    "LinkSpecError",
    "LinkTaken",
    "PtyOutput",
    "RawPty",
    "make_link",
    "open_raw_pty",
    "parse_links",
    "pty_where",
    "ready_line",
    "remove_own_link",
    "usable_url",
]
