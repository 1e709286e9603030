"""The MCAP writer (:mod:`fpgalink.recording`) cut short: what it leaves readable."""

from __future__ import annotations

from pathlib import Path

import pytest

from fpgalink import recording
from fpgalink.recording import McapSink
from tests.support.recordings import readable_topics


def test_an_abandoned_recording_keeps_every_complete_chunk(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A writer abandoned between its timed flushes (a signal's exception, which may break
    into a write) is cut back to its last complete chunk, not to its last flush: a fast
    writer fills many chunks in one flush period."""
    monkeypatch.setattr(recording, "FLUSH_S", float("inf"))
    path = tmp_path / "r.mcap"
    sink = McapSink(path, ["L"], {}, library="test")
    record = {"kind": "x", "detail": "y" * 900, "timestamp": 0.0}
    per_chunk = recording.CHUNK_BYTES // 1000
    written = 6 * per_chunk
    for i in range(written):
        sink.add("/board/L/params", record, float(i))
    sink.abandon()
    readable = len(readable_topics(path))
    # Every message but those of the chunk still open (at most a chunk's worth).
    assert written - per_chunk - 10 <= readable < written
