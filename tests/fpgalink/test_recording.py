"""The MCAP writer (:mod:`fpgalink.recording`) cut short: what it leaves readable."""

from __future__ import annotations

from pathlib import Path

import pytest

from fpgalink.recording import McapSink, files, mcapfile, partial_path
from tests.support.recordings import readable_topics

#: One message of about 1 kB: a chunk holds CHUNK_BYTES // 1000 of them.
RECORD = {"kind": "x", "detail": "y" * 900, "timestamp": 0.0}


def fast_writer(path: Path, monkeypatch: pytest.MonkeyPatch) -> McapSink:
    """A recording written faster than its timed flushes: none comes."""
    monkeypatch.setattr(mcapfile, "FLUSH_S", float("inf"))
    return McapSink(path, ["L"], {}, library="test")


def test_an_abandoned_recording_keeps_every_complete_chunk(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A writer abandoned between its timed flushes (a signal's exception, which may break
    into a write) is cut back to its last complete chunk, not to its last flush: a fast
    writer fills many chunks in one flush period."""
    path = tmp_path / "r.mcap"
    sink = fast_writer(path, monkeypatch)
    per_chunk = mcapfile.CHUNK_BYTES // 1000
    written = 6 * per_chunk
    for i in range(written):
        sink.add("/board/L/params", RECORD, float(i))
    sink.abandon()
    assert not path.exists()  # not finished: it stays under its partial name
    readable = len(readable_topics(partial_path(path)))
    # Every message but those of the chunk still open (at most a chunk's worth).
    assert written - per_chunk - 10 <= readable < written


def test_the_summarys_room_stays_reserved_ahead_of_a_fast_writer(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Room for the summary is reserved past every chunk that lands, not only at the timed
    flushes: a fast writer fills more than the reserve between two of them, and a disk that
    fills then must still take the summary."""
    path = tmp_path / "r.mcap"
    sink = fast_writer(path, monkeypatch)
    for i in range(3 * files.RESERVE_BYTES // 1000):  # three reserves' worth
        sink.add("/board/L/params", RECORD, float(i))
    stat = partial_path(path).stat()  # being written
    allocated_past_end = stat.st_blocks * 512 - stat.st_size
    sink.close()
    if files._fallocate() is None:
        pytest.skip("no fallocate here: the reserve is the writes' to find")
    # Reserved from the last chunk's end: the reserve, less what of its last block the
    # file's end already used.
    assert allocated_past_end >= files.RESERVE_BYTES - 4096, allocated_past_end
