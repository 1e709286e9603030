"""The host→board line's pace: when the bytes handed out so far have left the wire, and the
reference held back meanwhile, so references never queue behind more than
``max_reference_delay`` of earlier bytes (only the newest reference matters: one replaced
while it waited is counted in ``references_superseded``)."""

from __future__ import annotations

from fpgalink.connection.settings import Settings
from fpgalink.connection.stats import LinkStats
from fpgalink.protocol import References
from fpgalink.protocol.wire import byte_time_s

__all__ = ["LinePacing"]


class LinePacing:
    """The line of one link at the settings' ``baud`` (``None``: not known, never held)."""

    __slots__ = ("_byte_time", "_settings", "_stats", "free_at", "held")

    def __init__(self, settings: Settings, stats: LinkStats) -> None:
        self.free_at = 0.0  #: when the bytes handed out so far have left the line
        self.held: References | None = None  #: the newest reference, waiting for room
        self._stats = stats
        self._byte_time = 0.0
        self._settings = settings
        self.settings = settings

    @property
    def settings(self) -> Settings:
        return self._settings

    @settings.setter
    def settings(self, settings: Settings) -> None:
        self._settings = settings
        self._byte_time = byte_time_s(settings.baud) if settings.baud is not None else 0.0

    def hold(self, reference: References, now: float) -> bool:
        """Keep ``reference`` back (replacing one waiting) when the line is too far behind."""
        if not self._byte_time or self.free_at - now <= self._settings.max_reference_delay:
            return False
        if self.held is not None:
            self._stats.references_superseded += 1
        self.held = reference
        return True

    def sent(self, wire_bytes: int, now: float) -> None:
        if self._byte_time:
            free = self.free_at
            self.free_at = (now if now > free else free) + wire_bytes * self._byte_time

    def deadline(self) -> float | None:
        """When the held reference may go."""
        return None if self.held is None else self.free_at - self._settings.max_reference_delay

    def due(self, now: float) -> References | None:
        """The held reference, when the line has room for it by ``now``."""
        held = self.held
        if held is None or self.free_at - now > self._settings.max_reference_delay:
            return None
        self.held = None
        return held
