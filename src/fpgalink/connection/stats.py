"""What a connection counted: :class:`LinkStats`, each count kept in one place."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from fpgalink.protocol import AbortReason, FrameAborted, FramingError, Malformed, NoiseDropped

__all__ = ["LinkStats", "WireCounts"]


@dataclass(slots=True)
class WireCounts:
    """What the wire carried and how it decoded."""

    bytes_received: int = 0
    bytes_sent: int = 0
    frames_received: int = 0
    frames_sent: int = 0
    messages_received: int = 0
    telemetry_received: int = 0
    alive_received: int = 0
    noise_bytes: int = 0
    aborted_frames: int = 0  #: restarted by an unescaped START
    overflows: int = 0  #: content over the limit
    malformed: int = 0
    lost: int = 0  #: counter gaps net of late arrivals
    duplicates: int = 0
    reordered: int = 0
    #: counters judged damaged: a jump the next counter did not confirm (no checksum)
    corrupt_counters: int = 0


@dataclass(slots=True)
class LinkStats(WireCounts):
    """Everything the link counted. ``snapshot()`` copies."""

    retries: int = 0  #: parameter requests resent (a new round's first send included)
    echo_mismatches: int = 0  #: PA echoes with another value than the pending request's
    heartbeats_sent: int = 0
    heartbeat_misses: int = 0  #: times the board went silent past the liveness timeout
    restarts: int = 0  #: the board restarted (or may have: out of reach, reconnected)
    resync_failures: int = 0  #: parameters that could not be set again after a restart
    watchdog_lapses: int = 0  #: the board's watchdog disabled it while it was meant enabled
    telemetry_stalls: int = 0  #: telemetry configured on stopped coming
    #: references replaced by a newer one before the line had room to send them
    references_superseded: int = 0
    #: requests refused by the asyncio link, the line backed up (``LineBusy``)
    line_busy: int = 0
    events_dropped: int = 0
    subscriber_drops: int = 0  #: telemetry samples a slow subscriber lost (asyncio layer)
    port_losses: int = 0
    reconnects: int = 0
    #: frames dropped because their wire CRC did not match (only while the CRC is on)
    crc_failures: int = 0
    #: frames in the other wire-CRC mode than this host's (the board's CRC on and this
    #: host's off, or the reverse): dropped, never messages
    crc_mode_mismatches: int = 0
    malformed_by_reason: dict[str, int] = field(default_factory=dict)

    def snapshot(self) -> LinkStats:
        copy = LinkStats(**{f.name: getattr(self, f.name) for f in fields(self)})
        copy.malformed_by_reason = dict(self.malformed_by_reason)
        return copy

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def decode_errors(self) -> int:
        return self.aborted_frames + self.overflows + self.malformed

    def count_framing_error(self, item: FramingError) -> None:
        if isinstance(item, NoiseDropped):
            self.noise_bytes += item.dropped
        elif isinstance(item, FrameAborted):
            if item.reason is AbortReason.OVERFLOW:
                self.overflows += item.count
            else:
                self.aborted_frames += item.count

    def count_malformed(self, msg: Malformed) -> None:
        self.malformed += 1
        key = msg.reason.name
        self.malformed_by_reason[key] = self.malformed_by_reason.get(key, 0) + 1
