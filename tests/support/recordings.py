"""Reading an MCAP recording that may be cut short."""

from __future__ import annotations

import contextlib
from pathlib import Path


def readable_topics(path: Path) -> list[str]:
    """The topics of the messages readable in ``path`` now, in file order: a file without
    summary or footer (abandoned, killed) or still being written, up to its torn end."""
    from mcap.reader import NonSeekingReader

    found: list[str] = []
    with path.open("rb") as stream, contextlib.suppress(Exception):
        for _, channel, _ in NonSeekingReader(stream).iter_messages(log_time_order=False):
            found.append(channel.topic)
    return found
