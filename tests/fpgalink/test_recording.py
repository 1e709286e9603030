"""The MCAP writer (:mod:`fpgalink.recording`) cut short: what it leaves readable."""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any

import pytest

from fpgalink.recording import (
    McapSink,
    RecordingError,
    RecordingReader,
    files,
    mcapfile,
    partial_path,
)
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


class FailingFile:
    """A file whose writes fail with EIO once ``limit`` bytes have gone through (a disk that
    stops answering): the writer's state can no longer be trusted after one."""

    def __init__(self, real: Any, limit: int) -> None:
        self._real = real
        self._left = limit

    def write(self, data: bytes) -> int:
        if len(data) > self._left:
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        self._left -= len(data)
        written: int = self._real.write(data)
        return written

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)


def failing_after(monkeypatch: pytest.MonkeyPatch, limit: int) -> None:
    real = files.Output.file
    monkeypatch.setattr(files.Output, "file",
                        lambda self: FailingFile(real(self), limit))


def test_an_io_error_keeps_the_complete_chunks_as_partial_and_says_so(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "r.mcap"
    failing_after(monkeypatch, 200_000)
    sink = fast_writer(path, monkeypatch)
    with pytest.raises(RecordingError, match="recording stopped: cannot write: Input/output"):
        for i in range(1000):  # 1 kB each that does not compress
            sink.add("/board/L/params", {"detail": os.urandom(500).hex()}, float(i))
    with pytest.raises(RecordingError) as stopped:
        sink.add("/board/L/params", RECORD, 2000.0)  # stopped: every later write says so
    assert "recording stopped" in str(stopped.value)
    with pytest.raises(RecordingError) as closed:
        sink.close()
    said = str(closed.value)
    assert "Input/output error; the recording could not be finished" in said
    kept = int(said.split("its ")[1].split()[0])
    assert str(partial_path(path)) in said and not path.exists()
    with RecordingReader(partial_path(path)) as reader:
        assert sum(1 for _ in reader.messages()) == kept > 100
        assert not reader.damage and not reader.complete


def test_an_io_error_before_the_first_message_leaves_nothing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "r.mcap"
    failing_after(monkeypatch, 20)  # the magic, not the header
    with pytest.raises(RecordingError, match="could not be started; no file left"):
        McapSink(path, ["L"], {}, library="test")
    assert list(tmp_path.iterdir()) == []


def test_a_finished_recording_gives_its_reserve_back(tmp_path: Path) -> None:
    path = tmp_path / "r.mcap"
    sink = McapSink(path, ["L"], {}, library="test")
    sink.add("/board/L/params", RECORD, 1.0)
    sink.close()
    stat = path.stat()
    assert stat.st_blocks * 512 < stat.st_size + 8192  # no 512 KiB kept past its end
