"""Simple reference models the fast implementations are checked against."""

from __future__ import annotations

from fpgalink._framing import DEFAULT_FRAMING, Framing


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
