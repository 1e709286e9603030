"""Damaged recordings are never read as if whole (issue 37 item 11): every reader of a
recording (``plot``, and :class:`fpgalink.recording.RecordingReader` for any other) checks
each chunk, uses what is intact, names each damaged chunk with its time span, and ``plot``
exits 8 when anything was skipped."""

from __future__ import annotations

import json
import random
import struct
from pathlib import Path

import pytest
from mcap.reader import make_reader

from fpgalink.recording import RecordingReader
from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import run_cli

pytestmark = pytest.mark.timeout(300)

#: The issue's experiment: this many single-bit flips, each at a random place inside a
#: chunk record of a real recording.
FLIPS = 300


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    done = run_cli("record", str(path), "--duration", "2", "--port", "emu://")
    assert done.returncode == 0, done.stderr
    return path


def chunk_spans(path: Path) -> list[tuple[int, int]]:
    """(offset, length) of every chunk record, from the file's own index."""
    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return [(c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes]


def read_all(path: Path) -> tuple[list[tuple[str, int, int, bytes]], list[str]]:
    with RecordingReader(path) as reader:
        messages = [(channel.topic, m.log_time, m.publish_time, m.data)
                    for _, channel, m in reader.messages()]
        return messages, [d.describe(reader.origin_ns) for d in reader.damage]


def test_every_chunk_the_writers_write_carries_a_crc(recording: Path, tmp_path: Path) -> None:
    # The bags had none (rosbags writes 0): damage inside them could not be found.
    pytest.importorskip("rosbags")
    bag = tmp_path / "bag"
    done = run_cli("drive", "--for", "0.5", "--rosbag2", str(bag), timeout=60)
    assert done.returncode == 0, done.stderr
    for path in (recording, *bag.glob("*.mcap")):
        with path.open("rb") as stream:
            reader = make_reader(stream, validate_crcs=True)
            summary = reader.get_summary()
            assert summary is not None and summary.chunk_indexes, path
            for index in summary.chunk_indexes:
                stream.seek(index.chunk_start_offset + 9 + 8 + 8 + 8)
                assert struct.unpack("<I", stream.read(4))[0] != 0, path
            assert sum(1 for _ in reader.iter_messages()) > 100


def test_every_single_bit_flip_inside_a_chunk_is_found_or_harmless(recording: Path,
                                                                     tmp_path: Path) -> None:
    data = recording.read_bytes()
    whole, damage = read_all(recording)
    assert not damage and len(whole) > 1000
    every = set(whole)
    spans = chunk_spans(recording)
    rng = random.Random(37_11)
    found = harmless = 0
    flipped = tmp_path / "flipped.mcap"
    for _ in range(FLIPS):
        offset, length = rng.choice(spans)
        at = offset + rng.randrange(length)
        damaged = bytearray(data)
        damaged[at] ^= 1 << rng.randrange(8)
        flipped.write_bytes(damaged)
        messages, damage = read_all(flipped)
        if damage:
            found += 1
            # What was used is what was written: the damaged chunk skipped whole, named.
            assert set(messages) <= every
            if messages != whole:
                assert any(f"bytes {offset}–{offset + length}" in d and "chunk " in d
                           for d in damage), damage
            else:  # a bit the decoder does not read (a zstd frame header's): only the
                # data section's CRC sees it, and says so
                assert damage == [d for d in damage if "data section fails its CRC" in d]
        else:
            # Not found: then it must change nothing that was read (no such flip so far).
            assert messages == whole, f"a flip at byte {at} changed the data unseen"
            harmless += 1
    assert found + harmless == FLIPS
    assert found == FLIPS  # each flip lands in a chunk's CRC-checked content or its header


def test_plot_of_a_damaged_recording_names_the_chunk_and_exits_8(recording: Path,
                                                                 tmp_path: Path) -> None:
    # Was: plotted as if whole, exit 0 (a flipped bit decoded to other numbers).
    offset, length = chunk_spans(recording)[1]
    damaged = bytearray(recording.read_bytes())
    damaged[offset + length // 2] ^= 0x10  # inside its compressed content
    path = tmp_path / "damaged.mcap"
    path.write_bytes(damaged)
    out = tmp_path / "damaged.png"
    done = run_cli("plot", str(path), "-o", str(out))
    assert done.returncode == 9, done.stderr
    notes = [line for line in done.stderr.splitlines() if "damaged:" in line
             and "error:" not in line]
    assert len(notes) == 1, done.stderr
    assert f"chunk 2 (bytes {offset}–{offset + length})" in notes[0]
    assert "log time" in notes[0] and " s: " in notes[0] and "skipped" in notes[0]
    assert done.stderr.splitlines()[-1].startswith("fpgalink-cli: error: ")
    assert "1 part(s) skipped" in done.stderr.splitlines()[-1]
    assert out.read_bytes().startswith(b"\x89PNG")  # the rest is plotted


def test_plot_of_a_damaged_bag_names_the_chunk_and_exits_8(tmp_path: Path) -> None:
    pytest.importorskip("rosbags")
    bag = tmp_path / "bag"
    done = run_cli("drive", "--v", "0.1", "--for", "2", "--rosbag2", str(bag), timeout=60)
    assert done.returncode == 0, done.stderr
    [storage] = bag.glob("*.mcap")
    offset, length = chunk_spans(storage)[0]
    damaged = bytearray(storage.read_bytes())
    damaged[offset + length - 10] ^= 0x01
    storage.write_bytes(damaged)
    done = run_cli("plot", str(bag), "-o", str(tmp_path / "bag.png"), timeout=60)
    assert done.returncode == 9, done.stderr
    assert f"chunk 1 (bytes {offset}–" in done.stderr


def test_a_recording_damaged_everywhere_is_one_line_exit_8(recording: Path,
                                                            tmp_path: Path) -> None:
    damaged = bytearray(recording.read_bytes())
    for offset, length in chunk_spans(recording):
        damaged[offset + length - 5] ^= 0xFF
    path = tmp_path / "all.mcap"
    path.write_bytes(damaged)
    done = run_cli("plot", str(path), "-o", str(tmp_path / "all.png"))
    assert done.returncode == 9, done.stderr
    assert "nothing intact to plot" in done.stderr.splitlines()[-1]
    assert not (tmp_path / "all.png").exists()


def test_a_damaged_summary_is_said_and_every_message_still_read(recording: Path,
                                                                tmp_path: Path) -> None:
    whole, _ = read_all(recording)
    damaged = bytearray(recording.read_bytes())
    last_offset, last_length = chunk_spans(recording)[-1]
    summary_at = last_offset + last_length + (len(damaged) - last_offset - last_length) // 2
    damaged[summary_at] ^= 0x04
    path = tmp_path / "summary.mcap"
    path.write_bytes(damaged)
    messages, damage = read_all(path)
    assert messages == whole
    assert len(damage) == 1 and "summary" in damage[0]


def test_hostile_chunks_cost_bounded_memory_and_are_named(tmp_path: Path,
                                                          recording: Path) -> None:
    # A chunk that says it holds 2^60 bytes, its content 0x06 bytes that each look like the
    # start of a chunk, in a file without its summary (no index to jump by): each is
    # skipped as what it is, nothing allocated for what a header claims, and reading goes
    # on at the next intact chunk.
    spans = chunk_spans(recording)
    first, first_length = spans[1]  # the first defines the channels: left intact
    last, last_length = spans[-1]
    data = bytearray(recording.read_bytes()[:last + last_length])  # no summary, no footer
    struct.pack_into("<Q", data, first + 9 + 16, 1 << 60)  # its uncompressed size
    data[first + 60:first + first_length] = b"\x06" * (first_length - 60)
    path = tmp_path / "hostile.mcap"
    path.write_bytes(data)
    whole, _ = read_all(recording)
    with RecordingReader(path) as reader:
        messages = list(reader.messages())
        damage = list(reader.damage)
    assert [(d.offset, d.end, d.chunk) for d in damage] == [
        (first, first + first_length, 2)], damage
    assert "larger than a chunk can be" in damage[0].reason
    assert 0 < len(messages) < len(whole)
    # With the summary, the header is checked against the index first.
    data = bytearray(recording.read_bytes())
    struct.pack_into("<Q", data, first + 9 + 16, 1 << 60)
    path.write_bytes(data)
    with RecordingReader(path) as reader:
        list(reader.messages())
        assert [d.reason for d in reader.damage] == [
            "its header differs from the file's index of it"]


def test_something_that_is_not_mcap_is_one_line_exit_2(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 40)
    done = run_cli("plot", str(path), "-o", str(tmp_path / "x.png"))
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, "not a readable MCAP file")


@pytest.mark.parametrize("command", ["calibrate", "identify"])
def test_the_bring_up_commands_read_a_damaged_recording_as_plot_does(
        tmp_path: Path, command: str) -> None:
    # calibrate --from read with mcap's own reader: a flipped bit inside a chunk was a
    # "not a readable calibration recording" (or other numbers); identify --from said
    # nothing of damage. Now: each damaged part named, what is intact used, exit 9.
    path = tmp_path / "run.mcap"
    if command == "calibrate":
        made = run_cli("calibrate", "--turn", "90", "--omega", "45", "--reference", "truth",
                       "--record", str(path),
                       "--port", "L=emu://robot/L?body=kinematic",
                       "--port", "R=emu://robot/R?body=kinematic", timeout=120)
        again = ["calibrate", "--from", str(path), "--format", "json"]
    else:
        made = run_cli("identify", "-c", "A", "--wheels", "air", "--max-duty", "50",
                       "--duration", "6", "--record", str(path),
                       "--port", "emu://", timeout=120)
        again = ["identify", "-c", "A", "--from", str(path), "--format", "json"]
    assert made.returncode == 0, made.stderr
    whole = run_cli(*again)
    assert whole.returncode == 0, whole.stderr
    spans = chunk_spans(path)
    assert len(spans) > 3
    offset, length = spans[len(spans) // 2]
    damaged = bytearray(path.read_bytes())
    damaged[offset + length // 2] ^= 0x10
    path.write_bytes(damaged)
    done = run_cli(*again)
    assert done.returncode == 9, done.stderr
    notes = [line for line in done.stderr.splitlines() if "damaged:" in line
             and "error:" not in line]
    assert len(notes) == 1 and f"(bytes {offset}–{offset + length})" in notes[0], done.stderr
    assert done.stderr.splitlines()[-1].startswith("fpgalink-cli: error: ")
    assert json.loads(done.stdout)  # what is intact was used
