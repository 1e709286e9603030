"""Simple reference models the fast implementations are checked against."""

from __future__ import annotations

from fpgalink.protocol import DEFAULT_FRAMING, Framing


class NaiveFrameDecoder:
    """SPEC §3 decoding written the obvious way: one byte at a time, exactly as the
    ``uartcommand`` logic steps. Counts what it drops. Also the benchmark's baseline."""

    def __init__(self, framing: Framing = DEFAULT_FRAMING) -> None:
        self.framing = framing
        self.state = "hunt"
        self.content = bytearray()
        self.wire = 0
        self.frames: list[bytes] = []
        self.noise_bytes = 0
        self.restarts = 0
        self.overflows = 0
        self.dropped = 0

    def feed(self, data: bytes) -> list[bytes]:
        f = self.framing
        got: list[bytes] = []
        for b in data:
            if self.state == "hunt":
                if b == f.start:
                    self.state, self.wire = "frame", 1
                    self.content.clear()
                else:
                    self.noise_bytes += 1
                    self.dropped += 1
                continue
            self.wire += 1
            if self.state == "escape":
                self.state = "frame"
            elif b == f.skip:
                self.state = "escape"
                continue
            elif b == f.start:
                self.restarts += 1
                self.dropped += self.wire - 1
                self.wire = 1
                self.content.clear()
                continue
            elif b == f.stop:
                got.append(bytes(self.content))
                self.state = "hunt"
                continue
            self.content.append(b)
            if len(self.content) > f.max_content:
                self.overflows += 1
                self.dropped += self.wire
                self.state = "hunt"
        self.frames.extend(got)
        return got


def naive_encode(content: bytes, framing: Framing = DEFAULT_FRAMING) -> bytes:
    out = bytearray([framing.start])
    for b in content:
        if b in (framing.start, framing.stop, framing.skip):
            out.append(framing.skip)
        out.append(b)
    out.append(framing.stop)
    return bytes(out)


# --- fpgaemu reference models -------------------------------------------------------------


def naive_line_timing(
    writes: list[tuple[int, bytes]], cycles_per_byte: int
) -> list[tuple[int, int]]:
    """8N1 line with queuing, one byte at a time: ``(byte, completion cycle)`` for each byte of
    ``writes`` (``(cycle the host wrote, data)``, in order)."""
    out: list[tuple[int, int]] = []
    free = 0
    for cycle, data in writes:
        for b in data:
            start = max(cycle, free)
            free = start + cycles_per_byte
            out.append((b, free))
    return out


class NaiveUartCommand:
    """``uartcommand`` as a per-byte loop over ``(byte, cycle)`` pairs: the frames it would
    store, where, and when it would interrupt; RE/RD and the watchdog as a list of level
    changes. The processor is assumed to acknowledge every frame at once."""

    def __init__(self, framing: Framing = DEFAULT_FRAMING, watchdog: int = 30_000_000,
                 half: int = 200) -> None:
        self.decoder = NaiveFrameDecoder(framing)
        self.watchdog = watchdog
        self.half = half
        self.next_half = 0
        self.interrupts: list[tuple[int, int, bytes]] = []  # (cycle, start address, content)
        self.enable: list[tuple[int, bool]] = []
        self._level = False
        self._deadline: int | None = None

    def _set(self, cycle: int, level: bool) -> None:
        if level != self._level:
            self._level = level
            self.enable.append((cycle, level))

    def feed(self, timed: list[tuple[int, int]]) -> None:
        for b, cycle in timed:
            if self._deadline is not None and cycle > self._deadline:
                self._set(self._deadline, False)
                self._deadline = None
            for content in self.decoder.feed(bytes([b])):
                if content == b"RE":
                    self._deadline = cycle + self.watchdog
                    self._set(cycle, True)
                elif content == b"RD":
                    self._deadline = None
                    self._set(cycle, False)
                else:
                    self.interrupts.append((cycle, self.next_half * self.half, content))
                    self.next_half ^= 1

    def finish(self, cycle: int) -> None:
        if self._deadline is not None and cycle >= self._deadline:
            self._set(self._deadline, False)
            self._deadline = None
