"""``uartcommand``: the SPEC §3 frame decoder in FPGA logic, the RX block RAM writer, the
receive interrupt, the direct commands ``RE``/``RD`` and the ``global_enable`` watchdog.

The state machine is written here independently of :mod:`fpgalink.protocol.framing` so the two
check each other. It steps byte by byte as the logic does, except that a run of ordinary
content bytes is copied into the block RAM in one write (same result, one call).

Exact timing without an event per byte: bytes arrive as :class:`~fpgaemu.uart.ByteRun`\\ s
with computed completion cycles and are processed *lazily* but never early —

* the only bytes with effects outside this module at their own cycle are STOPs (interrupt,
  registers, ``global_enable``), so the next byte that could be a STOP gets one timeline
  event at its completion cycle, which processes everything up to and including it;
* every other observation (the processor reading the RX RAM or registers, acknowledging,
  reading counters) first calls :meth:`UartCommand.sync`, which processes the bytes
  completed by now, stopping short of that STOP candidate.

So anything that looks at the module sees exactly the state the logic would have then.

Decisions (see ``docs/emulator.md``):

* Content is written to half ``0`` (byte address 0) or half ``1`` (address 200); the write
  half toggles on each delivered frame. Aborted frames and direct commands leave the write
  half where it was (their bytes were written there, but it is not exposed).
* A delivered frame stays *owned by the processor* until it writes the read-done register
  (:meth:`UartCommand.ack` with the frame's start address). The logic does not wait for it:
  the first write into a half the processor still owns overwrites that frame, which is
  counted as an ``overrun`` (a third frame before the first was acknowledged, or any
  bytes — an aborted frame, a direct command — landing there).
* ``RE`` and ``RD`` (content exactly those two bytes) are consumed by the logic: no
  interrupt, the registers keep describing the last message frame.
* ``global_enable`` rises at the STOP of ``RE`` and falls exactly ``watchdog_cycles``
  (30,000,000 = 300 ms) after the STOP of the last ``RE``, or at the STOP of ``RD``. The
  watchdog is one timeline deadline, re-armed on each ``RE``; an ``RE`` completing in the
  lapse cycle itself counts as in time (no zero-width low pulse).
"""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Final

from fpgaemu.bram import BlockRam
from fpgaemu.timeline import CLOCK_HZ, EventHandle, Timeline
from fpgaemu.uart import ByteRun
from fpgalink.protocol import DEFAULT_FRAMING, Framing

__all__ = [
    "DIRECT_DISABLE",
    "DIRECT_ENABLE",
    "WATCHDOG_CYCLES",
    "EnableCause",
    "EnableChange",
    "FrameFilter",
    "RxInterrupt",
    "UartCommand",
    "UartCommandStats",
]

#: 300 ms of the 100 MHz clock: the enable watchdog (SPEC §6).
WATCHDOG_CYCLES: Final = CLOCK_HZ * 300 // 1000
DIRECT_ENABLE: Final = b"RE"
DIRECT_DISABLE: Final = b"RD"

_HUNT: Final = 0
_FRAME: Final = 1
_ESCAPE: Final = 2

#: ``(content, cycle) -> keep?``: a fault-injection hook on complete frames.
FrameFilter = Callable[[bytes, int], bool]


class EnableCause(Enum):
    ENABLE = "RE"
    DISABLE = "RD"
    WATCHDOG = "watchdog"


class RxInterrupt:
    """A message frame is in the RX RAM: ``length`` content bytes at byte ``start_address``
    (a plain class: one is made for every frame received)."""

    __slots__ = ("cycle", "length", "start_address")

    def __init__(self, cycle: int, start_address: int, length: int) -> None:
        self.cycle = cycle
        self.start_address = start_address
        self.length = length

    def __repr__(self) -> str:
        return (f"RxInterrupt(cycle={self.cycle}, start_address={self.start_address}, "
                f"length={self.length})")


@dataclass(frozen=True, slots=True)
class EnableChange:
    """``global_enable`` changed level at ``cycle``."""

    cycle: int
    enabled: bool
    cause: EnableCause


@dataclass(slots=True)
class UartCommandStats:
    bytes_received: int = 0
    frames: int = 0  #: message frames delivered to the processor (interrupts)
    direct_commands: int = 0  #: ``RE`` and ``RD`` frames consumed by the logic
    noise_bytes: int = 0  #: bytes dropped while hunting for START
    restarts: int = 0  #: frames discarded by an unescaped START
    overflows: int = 0  #: frames dropped at the first content byte past the limit
    overruns: int = 0  #: unacknowledged frames overwritten
    filtered: int = 0  #: complete frames a fault hook (``frame_filter``) made disappear

    @property
    def errors(self) -> int:
        return self.restarts + self.overflows


class _Cursor:
    """A received run and how far the state machine has consumed it."""

    __slots__ = ("pos", "run")

    def __init__(self, run: ByteRun) -> None:
        self.run = run
        self.pos = 0


class UartCommand:
    """Registers: ``start_address``, ``length`` (the last delivered frame), ``global_enable``,
    the read-done register (:meth:`ack`); counters in :attr:`stats`."""

    def __init__(
        self,
        timeline: Timeline,
        bram: BlockRam,
        framing: Framing = DEFAULT_FRAMING,
        watchdog_cycles: int = WATCHDOG_CYCLES,
    ) -> None:
        self._timeline = timeline
        self.bram = bram
        self.half_size = bram.size // 2
        self.watchdog_cycles = watchdog_cycles
        # registers
        self.start_address = 0
        self.length = 0
        self.global_enable = False
        self.watchdog_deadline: int | None = None
        #: the STOP cycle of the last RE received (None: none yet)
        self.last_enable_cycle: int | None = None
        #: the cycle global_enable last fell, and why (None: it has not)
        self.last_disable: tuple[int, EnableCause] | None = None
        #: Fault hook: called with (content, cycle) at each complete frame, direct commands
        #: included; returning False loses the frame as if its STOP had never arrived.
        self.frame_filter: FrameFilter | None = None
        self._stats = UartCommandStats()
        # state machine
        self._state = _HUNT
        self._length = 0
        self._write_half = 0
        self._owned = [False, False]
        # pending input and the one scheduled STOP candidate
        self._runs: deque[_Cursor] = deque()
        self._candidate: EventHandle | None = None
        self._candidate_cursor: _Cursor | None = None
        self._candidate_index = 0
        self._watchdog: EventHandle | None = None
        self._due: list[RxInterrupt | EnableChange] = []
        self._rx_listeners: list[Callable[[RxInterrupt], None]] = []
        self._enable_listeners: list[Callable[[EnableChange], None]] = []
        self._configure(framing)

    # --- configuration and listeners ------------------------------------------------------

    def _configure(self, framing: Framing) -> None:
        self.framing = framing
        self._limit = min(framing.max_content, self.half_size)
        self._start_b = bytes((framing.start,))
        self._stop_b = bytes((framing.stop,))
        specials = b"".join(re.escape(bytes((b,))) for b in framing.specials)
        self._ordinary_run = re.compile(b"[^" + specials + b"]*").match

    def set_framing(self, framing: Framing) -> None:
        """The processor sets the framing bytes (at start-up)."""
        self.sync()
        if self._candidate is not None:
            self._candidate.cancel()
            self._candidate = None
        self._configure(framing)
        self._arm()

    def on_interrupt(self, listener: Callable[[RxInterrupt], None]) -> None:
        self._rx_listeners.append(listener)

    def on_enable_change(self, listener: Callable[[EnableChange], None]) -> None:
        self._enable_listeners.append(listener)

    # --- processor side -------------------------------------------------------------------

    @property
    def stats(self) -> UartCommandStats:
        self.sync()
        return self._stats

    @property
    def rx_pending(self) -> bool:
        """A delivered frame the processor has not acknowledged."""
        self.sync()
        return self._owned[0] or self._owned[1]

    def ack(self, start_address: int) -> None:
        """Read-done register: the processor is finished with the frame at ``start_address``
        (0 or ``half_size``), so the logic may reuse that half without an overrun."""
        self.sync()
        self.ack_synced(start_address)

    def ack_synced(self, start_address: int) -> None:
        """:meth:`ack` for a caller that has just called :meth:`sync` in this cycle."""
        if start_address not in (0, self.half_size):
            raise ValueError(f"{start_address} is not the start of an RX RAM half")
        self._owned[start_address // self.half_size] = False

    def sync(self) -> None:
        """Process every byte completed by now, short of the pending STOP candidate."""
        runs = self._runs
        if not runs:
            return
        now = self._timeline.now
        cursor = runs[0]
        run = cursor.run
        if run.first + cursor.pos * run.step > now:
            # The next byte to process has not completed: nothing to do (the usual case,
            # the processor reading a frame while the host's next one is on its way).
            return
        while runs:
            cursor = runs[0]
            done = cursor.run.completed_by(now)
            is_candidate = cursor is self._candidate_cursor and self._candidate is not None
            if is_candidate:
                done = min(done, self._candidate_index)
            if done > cursor.pos:
                self._process(cursor.run, cursor.pos, done)
                cursor.pos = done
            if done < len(cursor.run.data) or is_candidate:
                break
            runs.popleft()

    # --- line side ------------------------------------------------------------------------

    def receive(self, run: ByteRun) -> None:
        """``uartread`` hands over bytes with their completion cycles (all in the future or
        present, later than any run before)."""
        self._runs.append(_Cursor(run))
        self._stats.bytes_received += len(run.data)
        if self._candidate is None:
            self._arm()

    def discard_from(self, cycle: int) -> int | None:
        """The sender was unplugged at ``cycle``: bytes whose start bit had not begun by then
        never arrive. Returns the completion cycle of the last byte that still does (``None``
        when none is pending)."""
        self.sync()
        runs = self._runs
        last: int | None = None
        for index in range(len(runs) - 1, -1, -1):
            cursor = runs[index]
            run = cursor.run
            # Byte i starts one byte time before it completes.
            kept = max(cursor.pos, min(len(run.data), run.completed_by(cycle + run.step - 1)))
            if kept == len(run.data):
                last = run.last
                break
            self._stats.bytes_received -= len(run.data) - kept
            if kept == cursor.pos:
                del runs[index]
                continue
            cursor.run = ByteRun(run.data[:kept], run.first, run.step)
            last = cursor.run.last
            break
        if self._candidate is not None:
            self._candidate.cancel()
            self._candidate = None
        self._arm()
        return last

    def _arm(self) -> None:
        stop_b = self._stop_b
        for cursor in self._runs:
            index = cursor.run.data.find(stop_b, cursor.pos)
            if index >= 0:
                self._candidate_cursor = cursor
                self._candidate_index = index
                run = cursor.run
                self._candidate = self._timeline.schedule(
                    run.first + index * run.step, self._on_candidate  # run.cycle_of(index)
                )
                return
        self._candidate = None
        self._candidate_cursor = None

    def _on_candidate(self, cycle: int) -> None:
        target, end = self._candidate_cursor, self._candidate_index + 1
        self._candidate = None
        self._candidate_cursor = None
        runs = self._runs
        while runs:
            cursor = runs[0]
            last = end if cursor is target else len(cursor.run.data)
            self._process(cursor.run, cursor.pos, last)
            cursor.pos = last
            if last == len(cursor.run.data):
                runs.popleft()
            if cursor is target:
                break
        self._arm()
        self._dispatch()

    def _dispatch(self) -> None:
        due = self._due
        if not due:
            return
        self._due = []
        for event in due:
            if isinstance(event, RxInterrupt):
                for rx_listener in self._rx_listeners:
                    rx_listener(event)
            else:
                for enable_listener in self._enable_listeners:
                    enable_listener(event)

    # --- the state machine ----------------------------------------------------------------

    def _process(self, run: ByteRun, pos: int, end: int) -> None:
        data = run.data
        framing = self.framing
        start, stop, skip = framing.start, framing.stop, framing.skip
        start_b = self._start_b
        ordinary_run = self._ordinary_run
        limit = self._limit
        stats = self._stats
        state, length = self._state, self._length
        i = pos
        while i < end:
            if state == _HUNT:
                j = data.find(start_b, i, end)
                if j < 0:
                    stats.noise_bytes += end - i
                    break
                stats.noise_bytes += j - i
                # The usual case at once: START, content with no special byte, STOP — what
                # the byte-by-byte states below do for it, without a pass through each.
                k = ordinary_run(data, j + 1, end).end()  # type: ignore[union-attr]
                if k < end and data[k] == stop and k - j - 1 <= limit:
                    if k > j + 1:
                        self._store(0, data[j + 1 : k])
                    i = k + 1
                    self._complete(k - j - 1, run.first + k * run.step)
                    continue
                state, length, i = _FRAME, 0, j + 1
                continue
            if state == _ESCAPE:
                state, j = _FRAME, i + 1
            else:
                match = ordinary_run(data, i, end)
                j = match.end() if match is not None else i
                if j == i:
                    b = data[i]
                    i += 1
                    if b == skip:
                        state = _ESCAPE
                    elif b == start:
                        stats.restarts += 1
                        length = 0
                    elif b == stop:
                        state = _HUNT
                        self._complete(length, run.first + (i - 1) * run.step)
                    continue
            room = limit - length
            if j - i > room:
                # The (limit + 1)th content byte: the frame is garbage; hunt from the next byte.
                if room:
                    self._store(length, data[i : i + room])
                stats.overflows += 1
                state, i = _HUNT, i + room + 1
                continue
            self._store(length, data[i:j])
            length += j - i
            i = j
        self._state, self._length = state, length

    def _store(self, offset: int, content: bytes) -> None:
        half = self._write_half
        if self._owned[half]:
            self._overrun(half)
        self.bram.write_bytes(half * self.half_size + offset, content)

    def _overrun(self, half: int) -> None:
        self._owned[half] = False
        self._stats.overruns += 1

    def _complete(self, length: int, cycle: int) -> None:
        half = self._write_half
        base = half * self.half_size
        frame_filter = self.frame_filter
        if frame_filter is not None and not frame_filter(
            self.bram.read_bytes(base, length), cycle
        ):
            self._stats.filtered += 1
            return
        if length == 2:
            content = self.bram.read_bytes(base, 2)
            if content == DIRECT_ENABLE:
                self._stats.direct_commands += 1
                self._rearm_watchdog(cycle)
                self._set_enable(True, cycle, EnableCause.ENABLE)
                return
            if content == DIRECT_DISABLE:
                self._stats.direct_commands += 1
                if self._watchdog is not None:
                    self._watchdog.cancel()
                    self._watchdog = None
                self.watchdog_deadline = None
                self._set_enable(False, cycle, EnableCause.DISABLE)
                return
        if self._owned[half]:  # an empty frame wrote nothing but still takes the half
            self._overrun(half)
        self._owned[half] = True
        self._write_half = half ^ 1
        self.start_address = base
        self.length = length
        self._stats.frames += 1
        self._due.append(RxInterrupt(cycle, base, length))

    # --- global_enable --------------------------------------------------------------------

    def _rearm_watchdog(self, cycle: int) -> None:
        self.last_enable_cycle = cycle
        if self._watchdog is not None:
            self._watchdog.cancel()
        self.watchdog_deadline = cycle + self.watchdog_cycles
        # Late phase: an RE whose STOP completes in the very cycle the count runs out is
        # "the last RE" and re-arms first, so the outcome does not hang on event order.
        self._watchdog = self._timeline.schedule(
            self.watchdog_deadline, self._on_watchdog, late=True
        )

    def _on_watchdog(self, cycle: int) -> None:
        self._watchdog = None
        self.watchdog_deadline = None
        self._set_enable(False, cycle, EnableCause.WATCHDOG)
        self._dispatch()

    def _set_enable(self, level: bool, cycle: int, cause: EnableCause) -> None:
        if level != self.global_enable:
            self.global_enable = level
            if not level:
                self.last_disable = (cycle, cause)
            self._due.append(EnableChange(cycle, level, cause))
