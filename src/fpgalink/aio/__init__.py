"""asyncio layer: :func:`open_link` and :class:`Link` over serial, TCP or any registered
scheme (``emu://`` comes from the emulator package)."""

from fpgalink.aio.link import (
    Link,
    LinkState,
    Subscription,
    SyncResult,
    open_link,
)
from fpgalink.aio.transport import open_transport, register_scheme

__all__ = [
    "Link",
    "LinkState",
    "Subscription",
    "SyncResult",
    "open_link",
    "open_transport",
    "register_scheme",
]
