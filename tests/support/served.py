"""Shared pieces of the end-to-end tests: waits on conditions with deadlines and telemetry
streaming checks, over links to a real ``fpgaemu serve`` (started by :mod:`tests.support.serving`).

Nothing here sleeps a fixed time and hopes: every wait is for a condition, bounded by a
deadline, and fails with a message naming what did not happen.
"""

from __future__ import annotations

import asyncio
import itertools
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from fpgalink import PortError, Telemetry
from fpgalink.aio import Link, open_link
from fpgalink.events import StatusEvent
from fpgalink.protocol import Event, ParamAck, ParamNack
from fpgalink.protocol.params import Param, ParamType, Scope
from tests.support.waiting import wait_until

__all__ = [
    "COUNTER_MODULUS",
    "PATIENCE",
    "StreamResult",
    "connect_when_free",
    "next_event",
    "open_when_free",
    "stream",
    "valid_value",
    "wait_for_sample",
    "wait_until",
]

E = TypeVar("E", bound=StatusEvent)
COUNTER_MODULUS = 100_000
T_US_MODULUS = 1 << 32


async def next_event(
    events: AsyncIterator[StatusEvent], kinds: tuple[type[E], ...], timeout: float
) -> E:
    """The next status event of one of ``kinds`` (others are skipped), within ``timeout``."""

    async def find() -> E:
        async for event in events:
            if isinstance(event, kinds):
                return event
        raise AssertionError("the event stream ended")

    try:
        return await asyncio.wait_for(find(), timeout)
    except TimeoutError:
        names = sorted(k.name for k in kinds)
        raise AssertionError(f"no {names} event within {timeout} s") from None


async def wait_for_sample(
    samples: AsyncIterator[Telemetry], predicate: Callable[[Telemetry], bool], timeout: float,
    what: str,
) -> Telemetry:
    """The first telemetry sample satisfying ``predicate``, within ``timeout``."""

    async def find() -> Telemetry:
        async for sample in samples:
            if predicate(sample):
                return sample
        raise AssertionError("the telemetry stream ended")

    try:
        return await asyncio.wait_for(find(), timeout)
    except TimeoutError:
        raise AssertionError(f"no telemetry sample with {what} within {timeout} s") from None


#: How long a test waits for something that should happen. Waits return as soon as the
#: condition holds, so a generous bound costs nothing when all is well and keeps a loaded
#: machine from failing a test that is only slow.
PATIENCE = 10.0


@dataclass
class StreamResult:
    samples: list[Telemetry]
    lost_during: int  #: ``link.stats.lost`` growth over the stretch
    dropped: int  #: samples the subscription had to drop
    #: counters the board gave to its other messages meanwhile (a PA answering the link's
    #: own question when a loaded machine's telemetry came late)
    answers: frozenset[int] = frozenset()

    @property
    def missing(self) -> int:
        """Counters missing between the first and the last sample delivered."""
        return sum(((b.counter or 0) - (a.counter or 0)) % COUNTER_MODULUS - 1
                   - self._answered_between(a, b)
                   for a, b in itertools.pairwise(self.samples))

    def _answered_between(self, a: Telemetry, b: Telemetry) -> int:
        gap = ((b.counter or 0) - (a.counter or 0)) % COUNTER_MODULUS
        return sum(((a.counter or 0) + k) % COUNTER_MODULUS in self.answers
                   for k in range(1, gap)) if self.answers else 0

    def check_accounting(self, period_us: int) -> None:
        """What holds however loaded the machine is: samples in order, each missing period
        a missing counter (nothing lost silently, the board's clock and its counter agree),
        and every missing counter counted by the link or by the subscription."""
        for a, b in itertools.pairwise(self.samples):
            counters = ((b.counter or 0) - (a.counter or 0)) % COUNTER_MODULUS
            elapsed = (b.t_us - a.t_us) % T_US_MODULUS
            assert counters >= 1, f"counter {b.counter} after {a.counter}: not in order"
            counters -= self._answered_between(a, b)
            assert elapsed == counters * period_us, (
                f"{elapsed} µs between counters {a.counter} and {b.counter}")
        assert self.missing == self.lost_during + self.dropped, (
            f"{self.missing} missing, link counted {self.lost_during} lost and the "
            f"subscription {self.dropped} dropped")


async def stream(link: Link, count: int, timeout: float = 3 * PATIENCE) -> StreamResult:
    """The next ``count`` telemetry samples the link delivers, read as they arrive (so the
    subscription never fills), with the link's loss count over the same stretch."""
    sub = link.telemetry(maxsize=4 * 1024)
    lost_before = link.stats.lost
    answers: set[int] = set()

    def answer(event: Event) -> None:
        counter = getattr(event, "counter", None)
        if isinstance(event, ParamAck | ParamNack) and isinstance(counter, int):
            answers.add(counter)

    forget = link.add_listener(answer)
    samples: list[Telemetry] = []

    async def consume() -> None:
        async for sample in sub:
            samples.append(sample)
            if len(samples) >= count:
                return

    try:
        await asyncio.wait_for(consume(), timeout)
    except TimeoutError:
        raise AssertionError(f"only {len(samples)} of {count} samples in {timeout:g} s"
                             ) from None
    finally:
        sub.close()
        forget()
    return StreamResult(samples, link.stats.lost - lost_before, sub.dropped, frozenset(answers))


async def open_when_free(url: str, **options: Any) -> Link:
    """Open ``url`` as soon as serve listens again: one host at a time, so a TCP port
    refuses the next host until serve has seen the previous one leave."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + PATIENCE
    while True:
        try:
            return await open_link(url, **options).open()
        except PortError:
            if loop.time() > deadline:
                raise
            await asyncio.sleep(0.02)


async def connect_when_free(host: str, port: int) -> tuple[asyncio.StreamReader,
                                                         asyncio.StreamWriter]:
    """A raw TCP connection, as soon as serve listens again (see :func:`open_when_free`)."""
    while True:
        try:
            return await asyncio.open_connection(host, port)
        except (ConnectionRefusedError, ConnectionResetError):  # reset: queued, then refused
            await asyncio.sleep(0.02)


def valid_value(param: Param, channel: int) -> int | float:
    """A value in range that differs from the board's power-up default and from the other
    channel's, so a set that went nowhere (or to the wrong channel) is noticed."""
    offset = 0 if param.scope is Scope.BOARD else channel - 1
    chosen: dict[str, int | float] = {
        "TsTimerPeriod": 7,
        "GetDataPeriodical": 1,
        "TorqueCoef": 0.35 + offset,
        "ActiveController": 1 - offset,  # A: 1 (HW speed PID), B: 0 — both run
        "MaxControlSignal": 30_000 - 1000 * offset,
        "IncSenzRes": 1024 + offset,
        "IncSenzCountDirection": -1 if offset == 0 else 1,
        "Kp_Wheel_Pid": 9.5 + offset,
        "Ti_Wheel_Pid": 30.25 + offset,
        "Td_Wheel_Pid": 0.5 + offset,
        "WireCrc": 1,  # everything after it runs with the wire CRC on
    }
    value = chosen[param.name]
    return float(value) if param.type is ParamType.FLOAT else int(value)
