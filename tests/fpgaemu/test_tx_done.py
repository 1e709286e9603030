"""The TX-done interrupt on demand: ``UartSend.on_next_done``, ``AxiBus.on_next_tx_done`` and
``TxQueue``, which asks for it only while it holds a message.

A frame nobody waits for must cost no timeline event at its end, yet everyone who does wait
must be told exactly once, at exactly the cycle the frame's last stop bit ends, with that
frame's own wire size — even when the next frame is strobed in that very cycle. Default
board: 1,000 cycles per wire byte, a frame of ``n`` content bytes without specials is
``n + 2`` wire bytes.
"""

from __future__ import annotations

import pytest

from fpgaemu.axi import TxQueue
from fpgaemu.board import Board
from fpgaemu.uartsend import TxDone

BYTE = 1_000  #: cycles per wire byte at the default baud rate


def events_scheduled(board: Board) -> int:
    """How many events the board's timeline has ever scheduled."""
    return board.timeline._seq


def send_now(board: Board, content: bytes) -> int:
    """Write and strobe ``content`` (the module must be idle); the cycle its frame ends."""
    board.axi.write_tx(content)
    assert board.axi.strobe_tx()
    return board.uartsend.busy_until


class Recorder:
    """A TX-done listener that notes the cycle it ran in with each event."""

    def __init__(self, board: Board) -> None:
        self.board = board
        self.calls: list[tuple[int, TxDone]] = []

    def __call__(self, event: TxDone) -> None:
        self.calls.append((self.board.now, event))


# --- no listener: no event ------------------------------------------------------------------


def test_a_frame_nobody_waits_for_schedules_no_event() -> None:
    """A strobe with no done listener schedules nothing for the frame's end (the emulator's
    speed-up), and the host still gets the frame's bytes at line rate."""
    board = Board()
    board.run_until(300)
    before = events_scheduled(board)
    end = send_now(board, b"abc")
    assert end == 300 + 5 * BYTE
    assert events_scheduled(board) == before
    assert board.timeline.next_deadline is None
    board.run_until(end - 1)
    assert board.axi.tx_busy
    assert board.read_host_bytes() == b"Sabc"
    board.run_until(end)
    assert not board.axi.tx_busy
    assert board.read_host_bytes() == b"P"
    assert board.uartsend.stats.frames == 1
    assert events_scheduled(board) == before


def test_back_to_back_frames_nobody_waits_for_schedule_no_event() -> None:
    """A second frame strobed right at the first one's end also costs no event, and both
    frames' bytes arrive complete with exact completion cycles."""
    board = Board()
    end1 = send_now(board, b"ab")
    board.run_until(end1)
    end2 = send_now(board, b"xyz")
    assert end2 == end1 + 5 * BYTE
    assert events_scheduled(board) == 0
    board.run_until(end2)
    wire = b"SabP" + b"SxyzP"
    assert board.read_host_bytes_timed() == [(w, BYTE * (i + 1)) for i, w in enumerate(wire)]


# --- on_next_done: once, for the frame on the wire ------------------------------------------


def test_next_done_runs_once_at_the_frame_end_with_its_wire_bytes() -> None:
    """on_next_done during a frame calls the listener exactly once, in the frame's end cycle
    (busy_until), with that frame's wire size: the firmware's one-shot done interrupt."""
    board = Board()
    end = send_now(board, b"abc")  # 5 wire bytes
    board.run_until(1_234)
    listener = Recorder(board)
    board.uartsend.on_next_done(listener)
    board.run_until(end - 1)
    assert listener.calls == []
    board.run_until(end)
    assert listener.calls == [(end, TxDone(end, 5))]
    # A later frame, of another size, does not call it again.
    board.run_until(end + 777)
    end2 = send_now(board, b"hello world")
    board.run_until(end2 + 10 * BYTE)
    assert listener.calls == [(end, TxDone(end, 5))]


def test_next_done_counts_escapes_in_wire_bytes() -> None:
    """wire_bytes is the frame's size on the wire, SKIP bytes included, not its content size."""
    board = Board()
    end = send_now(board, b"PS\\x")  # 4 content bytes, 3 of them escaped: 2 + 4 + 3 wire
    assert end == 9 * BYTE
    listener = Recorder(board)
    board.axi.on_next_tx_done(listener)
    board.run_until(end)
    assert listener.calls == [(end, TxDone(end, 9))]
    assert board.read_host_bytes() == b"S\\P\\S\\\\xP"


def test_next_done_asked_in_the_strobe_cycle() -> None:
    """Asked in the very cycle the frame was strobed, the listener still gets that frame."""
    board = Board()
    board.run_until(42)
    end = send_now(board, b"")  # START + STOP: 2 wire bytes
    listener = Recorder(board)
    board.axi.on_next_tx_done(listener)
    board.run_until(end + 5 * BYTE)
    assert listener.calls == [(42 + 2 * BYTE, TxDone(42 + 2 * BYTE, 2))]


def test_next_done_while_idle_never_calls() -> None:
    """Idle, on_next_done neither calls the listener nor schedules anything, and the next
    frame does not call it either: nothing was on the wire to wait for."""
    board = Board()
    listener = Recorder(board)
    board.uartsend.on_next_done(listener)
    assert events_scheduled(board) == 0
    end = send_now(board, b"abc")
    board.run_until(end)
    # Idle again in the frame's own end cycle: nothing left to wait for.
    board.uartsend.on_next_done(listener)
    end2 = send_now(board, b"def")
    board.run_until(end2 + 3 * BYTE)
    assert listener.calls == []
    assert events_scheduled(board) == 0


def test_next_done_in_the_end_cycle_before_the_done_event_is_too_late() -> None:
    """In the frame's end cycle the module is idle (busy reads the cycle), so asking then, even
    before that cycle's done event has run, waits for nothing."""
    board = Board()
    end = send_now(board, b"abc")
    late = Recorder(board)
    asked_at: list[tuple[int, bool]] = []

    def ask(_cycle: int) -> None:
        asked_at.append((board.now, board.axi.tx_busy))
        board.axi.on_next_tx_done(late)

    board.schedule(end, ask)  # scheduled first: runs before the done event of that cycle
    early = Recorder(board)
    board.axi.on_next_tx_done(early)  # schedules the done event at `end`
    board.run_until(end + 3 * BYTE)
    assert asked_at == [(end, False)]
    assert early.calls == [(end, TxDone(end, 5))]
    assert late.calls == []


def test_several_waiters_on_one_frame_share_one_event() -> None:
    """Two one-shot listeners and a permanent one on one frame: one event at its end, and each
    listener called once."""
    board = Board()
    end = send_now(board, b"abc")
    first, second, always = Recorder(board), Recorder(board), Recorder(board)
    before = events_scheduled(board)
    board.axi.on_next_tx_done(first)
    board.axi.on_next_tx_done(second)
    board.axi.on_tx_done(always)
    assert events_scheduled(board) == before + 1
    board.run_until(end)
    expected = [(end, TxDone(end, 5))]
    assert first.calls == second.calls == always.calls == expected


# --- on_done: every frame from now on, the one on the wire included --------------------------


@pytest.mark.parametrize("strobe_first", [True, False],
                         ids=["strobe-before-done-event", "done-event-before-strobe"])
def test_permanent_listener_gets_the_frame_on_the_wire_and_every_later_one(
    strobe_first: bool,
) -> None:
    """on_done registered mid-frame reports that frame and every later one, each with its own
    wire size, when the next frame is strobed in the very cycle the previous ends — whichever
    of the strobe and the done event runs first in that cycle."""
    board = Board()
    contents = [b"abc", b"hello world", b"P"]  # 5, 13 and 4 wire bytes
    wires = [5, 13, 4]
    ends = [sum(wires[: i + 1]) * BYTE for i in range(3)]
    #: (cycle, accepted, TxDone events seen by then) of each strobe
    strobed: list[tuple[int, bool, int]] = []
    listener = Recorder(board)

    def strobe(index: int) -> None:
        board.axi.write_tx(contents[index])
        strobed.append((board.now, board.axi.strobe_tx(), len(listener.calls)))

    strobe(0)
    if strobe_first:
        # Scheduled before any done event exists: each runs first in its cycle.
        board.schedule(ends[0], lambda _cycle: strobe(1))
        board.schedule(ends[1], lambda _cycle: strobe(2))
        board.run_until(2_500)
        board.axi.on_tx_done(listener)
    else:
        board.run_until(2_500)
        board.axi.on_tx_done(listener)  # the done event at ends[0] comes first

        def chain(index: int) -> None:
            strobe(index)  # schedules this frame's done event before the next strobe
            if index + 1 < len(contents):
                board.schedule(board.uartsend.busy_until, lambda _cycle: chain(index + 1))

        board.schedule(ends[0], lambda _cycle: chain(1))
    board.run_until(ends[2] + 10 * BYTE)
    # Which ran first in each end cycle: the previous frame's done event, or the strobe.
    done_before = [0, 0, 1] if strobe_first else [0, 1, 2]
    assert strobed == [(at, True, seen) for at, seen in zip([0, *ends[:2]], done_before,
                                                            strict=True)]
    assert listener.calls == [(end, TxDone(end, wire)) for end, wire in zip(ends, wires,
                                                                             strict=True)]
    assert board.read_host_bytes() == b"SabcP" + b"Shello worldP" + b"S\\PP"


def test_permanent_listener_registered_while_idle_waits_for_the_next_frame() -> None:
    """on_done while idle schedules nothing and reports the next frame at its end."""
    board = Board()
    listener = Recorder(board)
    board.axi.on_tx_done(listener)
    assert events_scheduled(board) == 0
    board.run_until(10_000)
    end = send_now(board, b"ab")
    board.run_until(end + BYTE)
    assert listener.calls == [(end, TxDone(end, 4))]


# --- TxQueue ----------------------------------------------------------------------------------


def test_queue_sends_back_to_back_with_tags_and_drops_when_full() -> None:
    """Three sends while idle: the first goes at once, each other starts in the previous
    frame's end cycle, on_start gets each tag in order with its done cycle and wire size, and
    a send past the depth is dropped and counted."""
    board = Board()
    starts: list[tuple[int, int | None, int, int]] = []
    queue = TxQueue(board.axi, depth=2,
                    on_start=lambda tag, done, wire: starts.append((board.now, tag, done, wire)))
    board.run_until(100)
    assert queue.send(b"one", 1)
    assert starts == [(100, 1, 100 + 5 * BYTE, 5)]
    assert queue.send(b"two", 2) and queue.send(b"three", 3)
    assert len(queue) == 2
    assert not queue.send(b"four", 4)
    assert queue.stats.dropped == 1
    board.run_until(100 + 17 * BYTE)
    assert starts == [
        (100, 1, 100 + 5 * BYTE, 5),
        (100 + 5 * BYTE, 2, 100 + 10 * BYTE, 5),
        (100 + 10 * BYTE, 3, 100 + 17 * BYTE, 7),
    ]
    wire = b"SoneP" + b"StwoP" + b"SthreeP"
    assert board.read_host_bytes_timed() == [(w, 100 + BYTE * (i + 1))
                                             for i, w in enumerate(wire)]
    assert len(queue) == 0
    assert (queue.stats.sent, queue.stats.queued, queue.stats.dropped,
            queue.stats.max_depth) == (3, 2, 1, 2)


def test_queue_tags_default_to_none() -> None:
    """A message sent without a tag reaches on_start with None, in send order with the others."""
    board = Board()
    tags: list[int | None] = []
    queue = TxQueue(board.axi, on_start=lambda tag, _done, _wire: tags.append(tag))
    assert queue.send(b"m")
    assert queue.send(b"m", 7)
    assert queue.send(b"m")
    assert queue.send(b"m", 9)
    board.run_until(20 * BYTE)
    assert tags == [None, 7, None, 9]


def test_queue_asks_for_the_done_interrupt_only_while_holding_a_message() -> None:
    """The queue schedules one done event per frame it must follow, none for the last frame
    of a burst nor for a message sent while idle: no event is left after it drains."""
    board = Board()
    queue = TxQueue(board.axi, depth=4)
    queue.send(b"one")  # at once: nobody waits for its end
    assert events_scheduled(board) == 0
    queue.send(b"two")
    queue.send(b"three")
    assert events_scheduled(board) == 1  # the end of "one", asked for once
    board.run_until(5 * BYTE)
    assert events_scheduled(board) == 2  # "two" on the wire, "three" held: its end
    board.run_until(10 * BYTE)
    assert events_scheduled(board) == 2  # "three" on the wire, nothing held: no event
    assert board.timeline.next_deadline is None
    board.run_until(30 * BYTE)
    assert queue.send(b"four")
    board.run_until(40 * BYTE)
    assert events_scheduled(board) == 2
    assert board.timeline.next_deadline is None
    assert queue.stats.sent == 4
    assert board.read_host_bytes() == b"SoneP" + b"StwoP" + b"SthreeP" + b"SfourP"


def test_queue_follows_a_frame_it_did_not_send() -> None:
    """A message sent while another sender's frame is on the wire starts at that frame's end."""
    board = Board()
    starts: list[tuple[int, int | None]] = []
    queue = TxQueue(board.axi, on_start=lambda tag, _done, _wire: starts.append((board.now, tag)))
    end = send_now(board, b"foreign")  # 9 wire bytes
    assert queue.send(b"mine", 1)
    assert starts == []
    board.run_until(end + 6 * BYTE)
    assert starts == [(end, 1)]
    assert board.read_host_bytes() == b"SforeignP" + b"SmineP"


def test_queue_waits_again_when_another_strobe_wins_the_end_cycle() -> None:
    """If another sender strobes in the cycle the queue's awaited frame ends, before the done
    event, the queue keeps its message and starts it at the end of that other frame."""
    board = Board()
    starts: list[tuple[int, int | None]] = []
    queue = TxQueue(board.axi, on_start=lambda tag, _done, _wire: starts.append((board.now, tag)))
    end1 = send_now(board, b"abc")  # 5 wire bytes
    foreign: list[bool] = []

    def foreign_strobe(_cycle: int) -> None:
        board.axi.write_tx(b"zz")
        foreign.append(board.axi.strobe_tx())

    board.schedule(end1, foreign_strobe)  # before the done event the queue will ask for
    assert queue.send(b"q", 5)
    end2 = end1 + 4 * BYTE
    board.run_until(end2 + 3 * BYTE)
    assert foreign == [True]
    assert starts == [(end2, 5)]
    assert board.read_host_bytes() == b"SabcP" + b"SzzP" + b"SqP"
    assert board.timeline.next_deadline is None


def test_queue_with_a_permanent_listener_reports_each_frame_once() -> None:
    """A queue and a permanent listener on the same frames: one done per frame, right sizes,
    and the queue's chain is unchanged by the shared event."""
    board = Board()
    listener = Recorder(board)
    board.axi.on_tx_done(listener)
    starts: list[tuple[int | None, int, int]] = []
    queue = TxQueue(board.axi, on_start=lambda tag, done, wire: starts.append((tag, done, wire)))
    for tag, content in enumerate((b"a", b"bb", b"ccc")):
        assert queue.send(content, tag)
    board.run_until(20 * BYTE)
    assert starts == [(0, 3 * BYTE, 3), (1, 7 * BYTE, 4), (2, 12 * BYTE, 5)]
    assert listener.calls == [(c, TxDone(c, w)) for _tag, c, w in starts]
    assert events_scheduled(board) == 3
