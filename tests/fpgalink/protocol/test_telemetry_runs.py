"""Telemetry a run at a time (``parse_telemetry_run``, ``parse_contents`` and Connection's
run path) against ``parse_content`` one frame at a time.

Runs of TM frames are checked with one regular expression and unpacked column by column;
anything else goes through ``parse_content`` frame by frame. A connection with the run path
switched off must see exactly the same events, in the same order, with the same counts, on
any stream cut any way: good telemetry, TM-sized frames that are not quite TM, counter gaps,
duplicates and the wrap, other messages, noise.
"""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgalink import Connection, Telemetry
from fpgalink.buildinfo import COMPILED
from fpgalink.protocol import (
    COUNTER_MODULUS,
    ChannelTelemetry,
    ParamAck,
    content_length,
    encode_frame,
    encode_message,
    parse_content,
    parse_contents,
    parse_telemetry_run,
)
from fpgalink.protocol.messages import MessageId

BODY = content_length(MessageId.TM) - 10  # ID, counter, "{", LEN, and "}" around it


# The reference below is a subclass of Connection with the run path switched off; the
# compiled build's Connection is a native class, which an interpreted class cannot derive
# from. These properties are of the source, so they run on pure Python: in make test's
# pure exactness run (Makefile, EXACTNESS_TESTS), while tests/fpgaemu/test_compiled.py holds
# the compiled Connection to the pure one on the same bytes.
pytestmark = pytest.mark.skipif(
    "fpgalink.connection.core" in COMPILED,
    reason="the compiled Connection cannot be subclassed; run in the pure exactness run")


class OneByOne(Connection):
    """The connection with its run path switched off."""

    def _telemetry(self, frames: list[Any], now: float) -> bool:
        return False


def tm_content(counter: int, body: bytes) -> bytes:
    return b"TM" + b"%05d" % counter + bytes((0x7B, BODY)) + body + b"}"


def test_the_sizes_agree_with_the_catalogue() -> None:
    assert content_length(MessageId.TM) == len(tm_content(0, bytes(BODY)))


@given(st.lists(st.tuples(st.integers(0, COUNTER_MODULUS - 1), st.binary(min_size=BODY,
                                                                          max_size=BODY)),
                min_size=1, max_size=20))
def test_columns_give_what_parse_content_gives(samples: list[tuple[int, bytes]]) -> None:
    contents = [tm_content(c, body) for c, body in samples]
    events = parse_telemetry_run(contents)
    assert events is not None
    expected = [parse_content(c) for c in contents]
    assert all(type(e) is Telemetry for e in expected)
    # repr, not ==: any 4 bytes are a float32, NaN included, and NaN is not equal to itself.
    assert list(map(repr, events)) == list(map(repr, expected))
    assert [e.counter for e in events] == [c for c, _ in samples]
    for event in events:
        assert type(event.a) is ChannelTelemetry and type(event.b) is ChannelTelemetry
        assert type(event.counter) is int


def near_tm(body: bytes) -> st.SearchStrategy[bytes]:
    """52-byte contents that are almost a TM: parse_content makes something else of them."""
    good = tm_content(7, body)
    return st.sampled_from([
        b"TM0a007" + good[7:],  # counter not five digits
        b"TM 0007" + good[7:],
        good[:8] + bytes((BODY - 1,)) + good[9:],  # another LEN
        good[:-1] + b"x",  # not closed
        b"TX" + good[2:],  # an ID nobody catalogued
        b"PA" + good[2:],  # a catalogued ID with another layout
        good[:7] + b"x" + good[8:],  # no section
    ])


@st.composite
def streams(draw: st.DrawFn) -> bytes:
    counter = draw(st.sampled_from([0, 17, COUNTER_MODULUS - 30, COUNTER_MODULUS - 1])
                   | st.integers(COUNTER_MODULUS - 12, COUNTER_MODULUS - 1))
    wire = []
    for _ in range(draw(st.integers(0, 120))):
        kind = draw(st.sampled_from(["tm"] * 12 + ["near", "alive", "pa", "noise", "cut"]))
        body = draw(st.binary(min_size=BODY, max_size=BODY))
        if kind == "tm":
            step = draw(st.sampled_from([1] * 20 + [0, 2, 5, -3, 5000, 40_000]))
            counter = (counter + step) % COUNTER_MODULUS
            wire.append(encode_frame(tm_content(counter, body)))
        elif kind == "near":
            wire.append(encode_frame(draw(near_tm(body))))
        elif kind == "alive":
            wire.append(encode_frame(b"E"))
        elif kind == "pa":
            counter = (counter + 1) % COUNTER_MODULUS
            wire.append(encode_frame(encode_message(ParamAck(1, 0, 1, 5), counter)))
        elif kind == "noise":
            wire.append(draw(st.binary(max_size=8)))
        else:  # a frame cut short by a restart
            wire.append(encode_frame(tm_content(counter, body))[: draw(st.integers(1, 50))])
    return b"".join(wire)


def observed(conn: Connection) -> dict[str, Any]:
    tracker = conn.counter_tracker
    return {
        "events": [repr(e) for e in conn.events()],
        "stats": conn.stats.as_dict(),
        "tracker": (tracker.expected, tracker.received, tracker.skipped, tracker.late,
                    tracker.duplicates, tracker.corrupted, tracker.laps, tracker.suspect,
                    bytes(tracker._missing)),
        "latest": repr(conn.latest_telemetry),
        "liveness": conn.liveness,
        "timer": conn.get_timer(),  # the silence deadline: when the board was last heard
    }


@given(streams(), st.lists(st.integers(0, 20_000), max_size=12),
       st.sampled_from([65536, 65536, 9]))
def test_runs_give_exactly_what_one_frame_at_a_time_gives(stream: bytes, cuts: list[int],
                                                          max_events: int) -> None:
    fast, slow = Connection(max_events=max_events), OneByOne(max_events=max_events)
    pos = 0
    for i, cut in enumerate([*sorted(c % (len(stream) + 1) for c in cuts), len(stream)]):
        for conn in (fast, slow):
            conn.receive_data(stream[pos:cut], now=float(i))
        pos = cut
        # Draining between reads, as a consumer does, so the queue cap is hit mid-stream.
        if i % 3 == 0:
            assert observed(fast) == observed(slow)
    assert observed(fast) == observed(slow)


GOOD_TM = st.builds(tm_content, st.integers(0, COUNTER_MODULUS - 1),
                    st.binary(min_size=BODY, max_size=BODY))


# Good TM four times in six, so runs long enough for the run path are common.
@given(st.lists(st.one_of(
    GOOD_TM, GOOD_TM, GOOD_TM, GOOD_TM,
    st.binary(min_size=BODY, max_size=BODY).flatmap(near_tm),
    st.binary(max_size=60),
), max_size=40))
def test_parse_contents_is_parse_content_of_each(contents: list[bytes]) -> None:
    assert list(map(repr, parse_contents(contents))) == [repr(parse_content(c))
                                                         for c in contents]
    if any(type(parse_content(c)) is not Telemetry for c in contents):
        assert parse_telemetry_run(contents) is None


def test_a_run_that_ends_on_the_wrap() -> None:
    # 99990 … 99999 in one read (after one that set the expectation), 0 … 9 in the next:
    # the wrap is the tracker's to count.
    body = bytes(BODY)
    reads = [b"".join(encode_frame(tm_content(c % COUNTER_MODULUS, body))
                      for c in range(start, start + 10))
             for start in (COUNTER_MODULUS - 20, COUNTER_MODULUS - 10, COUNTER_MODULUS)]
    fast, slow = Connection(), OneByOne()
    for conn in (fast, slow):
        for read in reads:
            conn.receive_data(read, now=0.0)
    assert observed(fast) == observed(slow)
    assert fast.counter_tracker.laps == 1 and fast.stats.lost == 0


def test_a_clean_stream_takes_the_run_path() -> None:
    contents = [tm_content(i, bytes(range(BODY))) for i in range(10)]
    conn = Connection()
    assert conn._telemetry(contents, 0.0)
    assert not conn._telemetry([*contents[:9], b"TX" + contents[9][2:]], 0.0)
    # The refused run left nothing behind.
    assert conn.stats.telemetry_received == 10
    assert len(list(conn.events())) == 11  # BoardFound, then the ten samples
