"""asyncio layer: :func:`open_link` and :class:`Link` over serial, TCP or ``emu://``."""

from fpgalink.aio.link import (
    Link,
    LinkEvent,
    LinkEventKind,
    LinkState,
    SyncResult,
    TelemetrySubscription,
    open_link,
)

__all__ = [
    "Link",
    "LinkEvent",
    "LinkEventKind",
    "LinkState",
    "SyncResult",
    "TelemetrySubscription",
    "open_link",
]
