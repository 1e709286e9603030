"""Bring-up experiments on a board, over its :class:`~fpgalink.aio.link.Link`'s public API:
the identification run (:func:`identify_channel`: the excitation of :mod:`.excitation`
with the speed PID as a unit gain) and the closed-loop step that confirms a design
(:func:`step_channel`).

Every parameter an experiment changes is read first and set back afterwards
(:class:`Parameters`), also when it fails or is interrupted; the board is enabled only
while it runs and disabled at its end. An experiment starts driving only once the board's
telemetry shows it enabled (``TM`` flag bit 0), and stops at the first fault the link
reports (a restart, a watchdog lapse, telemetry stopped, the board lost), or when the
board's enable falls, with :class:`ExperimentError`: its data would describe something
else. Time in the data is the board's own (``t_us``), so what the host's load does to the
arrival of samples does not reach the fit; a sample lost on the way is a gap in the grid
(:class:`ChannelRecord`), not a shift.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from fpgalink.aio.link import Link
from fpgalink.bringup.design import Gains
from fpgalink.bringup.excitation import OPEN_LOOP_GAINS, Excitation
from fpgalink.bringup.plant import Array
from fpgalink.errors import FpgalinkError
from fpgalink.events import (
    BoardRestarted,
    BoardSilent,
    Closed,
    PortLost,
    StatusEvent,
    TelemetryStale,
    WatchdogLapsed,
)
from fpgalink.protocol import ChannelTelemetry, Telemetry

__all__ = [
    "FAULTS",
    "ChannelRecord",
    "ExperimentError",
    "Parameters",
    "StepRecord",
    "apply_gains",
    "identify_channel",
    "step_channel",
]

#: Status events that end an experiment.
FAULTS = (BoardSilent, BoardRestarted, WatchdogLapsed, TelemetryStale, PortLost, Closed)
#: How long the board may take to show itself enabled after RE.
ENABLE_TIMEOUT_S = 1.0
_WRAP = 1 << 32


class ExperimentError(FpgalinkError):
    """An experiment could not run or was cut short; the message says why."""


class Parameters:
    """The parameters an experiment sets, each read first and set back by :meth:`restore`
    (best effort: a board that went away keeps what it had)."""

    def __init__(self, link: Link) -> None:
        self.link = link
        self.saved: dict[str, int | float] = {}

    async def read(self, name: str) -> int | float:
        return await self.link.get_param(name)

    async def set(self, name: str, value: int | float) -> int | float:
        if name not in self.saved:
            self.saved[name] = await self.link.get_param(name)
        return await self.link.set_param(name, value)

    async def restore(self) -> None:
        for name, value in reversed(list(self.saved.items())):
            if not self.link.board_alive:
                return
            with contextlib.suppress(FpgalinkError):
                await self.link.set_param(name, value)
        self.saved.clear()


@dataclass
class ChannelRecord:
    """One channel's samples, in the board's time."""

    channel: str  #: "A" or "B"
    period_s: float  #: the board's timer period while recorded
    t_us: list[int] = field(default_factory=list)  #: unwrapped
    pwm: list[int] = field(default_factory=list)
    speed: list[float] = field(default_factory=list)
    reference: list[float] = field(default_factory=list)
    enabled: list[bool] = field(default_factory=list)

    def add(self, t_us: int, sample: ChannelTelemetry) -> None:
        if self.t_us:
            last = self.t_us[-1]
            t_us = last + ((t_us - last) % _WRAP)
        self.t_us.append(t_us)
        self.pwm.append(sample.pwm)
        self.speed.append(sample.speed)
        self.reference.append(sample.reference)
        self.enabled.append(sample.enabled)

    def times(self) -> Array:
        """s from the first sample (none: an empty array)."""
        if not self.t_us:
            return np.zeros(0)
        return (np.asarray(self.t_us, dtype=float) - self.t_us[0]) / 1e6

    def grid(self) -> tuple[Array, Array, int]:
        """(duty, speed) one per timer period from the first sample to the last, NaN where
        a sample is missing, and how many are missing."""
        if not self.t_us:
            return np.zeros(0), np.zeros(0), 0
        period_us = self.period_s * 1e6
        index = np.rint((np.asarray(self.t_us, dtype=float) - self.t_us[0]) / period_us)
        n = int(index[-1]) + 1
        u, y = np.full(n, np.nan), np.full(n, np.nan)
        slots = index.astype(int)
        u[slots] = self.pwm
        y[slots] = [v if math.isfinite(v) else np.nan for v in self.speed]
        return u, y, n - len(set(slots.tolist()))


class _Watch:
    """Faults while an experiment runs, and the stop the caller may ask for."""

    def __init__(self, link: Link, stop: asyncio.Event | None) -> None:
        self.faults: list[StatusEvent] = []
        self.stop = stop
        self._remove = link.on_event(
            lambda event: self.faults.append(event) if isinstance(event, FAULTS) else None)

    def check(self) -> None:
        if self.faults:
            fault = self.faults[0]
            detail = fault.describe()
            raise ExperimentError(f"stopped: {fault.name.replace('_', ' ')}"
                                  + (f" ({detail})" if detail else ""))

    @property
    def stopped(self) -> bool:
        return self.stop is not None and self.stop.is_set()

    def close(self) -> None:
        self._remove()


@contextlib.contextmanager
def _watching(link: Link, stop: asyncio.Event | None) -> Iterator[_Watch]:
    watch = _Watch(link, stop)
    try:
        yield watch
    finally:
        watch.close()


def _pick(sample: Telemetry, channel: str) -> ChannelTelemetry:
    return sample.a if channel == "A" else sample.b


async def _collect(link: Link, channel: str, record: ChannelRecord,
                   on_sample: Callable[[Telemetry], None] | None) -> None:
    async for sample in link.telemetry(maxsize=1 << 16):
        record.add(sample.t_us, _pick(sample, channel))
        if on_sample is not None:
            on_sample(sample)


@contextlib.asynccontextmanager
async def _collecting(link: Link, channel: str, record: ChannelRecord,
                      on_sample: Callable[[Telemetry], None] | None) -> AsyncIterator[None]:
    """``record`` fills from the link's telemetry while the block runs; the board is
    disabled when it ends, however it ends."""
    collector = asyncio.ensure_future(_collect(link, channel, record, on_sample))
    try:
        yield
    finally:
        with contextlib.suppress(FpgalinkError):
            link.disable()
        collector.cancel()
        await asyncio.gather(collector, return_exceptions=True)


async def _enabled(link: Link, record: ChannelRecord, watch: _Watch) -> None:
    """Enable the board and wait until its telemetry shows it enabled."""
    link.enable()
    loop = asyncio.get_running_loop()
    deadline = loop.time() + ENABLE_TIMEOUT_S
    while not (record.enabled and record.enabled[-1]):
        watch.check()
        if watch.stopped:
            return
        if loop.time() > deadline:
            raise ExperimentError(
                f"the board did not enable within {ENABLE_TIMEOUT_S:g} s of RE (its telemetry "
                "says disabled): is its enable wired, or does another program control it?")
        await asyncio.sleep(0.01)


async def _pace(seconds: float, watch: _Watch, record: ChannelRecord, started: int) -> bool:
    """Wait ``seconds`` of host time; False when stopped. Faults raise; the board's enable
    falling after it showed raises too."""
    loop = asyncio.get_running_loop()
    end = loop.time() + seconds
    while (left := end - loop.time()) > 0:
        watch.check()
        if watch.stopped:
            return False
        if len(record.enabled) > started and not record.enabled[-1]:
            raise ExperimentError("the board's enable fell during the experiment (its "
                                  "watchdog, or another program's RD)")
        await asyncio.sleep(min(0.02, left))
    return True


def _references(channel: str, value: float) -> tuple[float, float]:
    return (value, 0.0) if channel == "A" else (0.0, value)


async def identify_channel(link: Link, channel: str, excitation: Excitation, *,
                           period_ms: int, limit: int, stop: asyncio.Event | None = None,
                           on_sample: Callable[[Telemetry], None] | None = None
                           ) -> ChannelRecord:
    """Run ``excitation`` on ``channel`` (``"A"``/``"B"``) with the speed PID as a unit gain
    and the duty clamped to ``limit``, the timer at ``period_ms``; return what was recorded.
    Every parameter touched is set back, the board disabled, also on a fault or a stop."""
    params = Parameters(link)
    record = ChannelRecord(channel, period_ms / 1000.0)
    kp, ti, td = OPEN_LOOP_GAINS
    with _watching(link, stop) as watch:
        try:
            await params.set("GetDataPeriodical", 0)  # quiet while set up
            await params.set("TsTimerPeriod", period_ms)
            for name, value in ((f"ActiveController{channel}", 0),
                                (f"MaxControlSignal{channel}", limit),
                                (f"Kp_Wheel_Pid{channel}", kp), (f"Ti_Wheel_Pid{channel}", ti),
                                (f"Td_Wheel_Pid{channel}", td)):
                await params.set(name, value)
            async with _collecting(link, channel, record, on_sample):
                await link.set_param("GetDataPeriodical", 1)
                link.set_references(0.0, 0.0)
                await _enabled(link, record, watch)
                started = len(record.enabled)
                loop = asyncio.get_running_loop()
                origin = loop.time()
                for at, duty in excitation.changes():
                    if not await _pace(origin + at - loop.time(), watch, record, started):
                        break
                    link.set_references(*_references(channel, float(duty)))
                # the last change is the duty back to 0: let the wheel slow down on record
                await _pace(0.5, watch, record, started)
        finally:
            await params.restore()
    return record


@dataclass(frozen=True, slots=True)
class StepRecord:
    """A closed-loop step: the samples from the step on (time 0: the first sample whose
    reference shows the target), and the samples before it."""

    t: Array  #: s
    speed: Array
    pwm: Array
    record: ChannelRecord


async def step_channel(link: Link, channel: str, gains: Gains, target: float, *,
                       hold: float, pre: float = 0.5, limit: int | None = None,
                       stop: asyncio.Event | None = None,
                       on_sample: Callable[[Telemetry], None] | None = None) -> StepRecord:
    """Run the board's speed PID on ``channel`` with ``gains`` (and ``limit`` as its clamp,
    if given), step its reference 0 → ``target`` deg/s after ``pre`` s and record ``hold``
    s. Everything is set back afterwards, the gains included (:func:`apply_gains` keeps
    them). Stopped (``stop``) before the step was taken: an empty record."""
    params = Parameters(link)
    period = float(await link.get_param("TsTimerPeriod")) / 1000.0
    record = ChannelRecord(channel, period)
    with _watching(link, stop) as watch:
        try:
            await params.set(f"ActiveController{channel}", 0)
            if limit is not None:
                await params.set(f"MaxControlSignal{channel}", limit)
            await params.set(f"Kp_Wheel_Pid{channel}", gains.kp)
            await params.set(f"Ti_Wheel_Pid{channel}", gains.ti)
            await params.set(f"Td_Wheel_Pid{channel}", gains.td)
            await params.set("GetDataPeriodical", 1)
            async with _collecting(link, channel, record, on_sample):
                link.set_references(0.0, 0.0)
                await _enabled(link, record, watch)
                started = len(record.enabled)
                if await _pace(pre, watch, record, started):
                    link.set_references(*_references(channel, target))
                    await _pace(hold, watch, record, started)
                link.set_references(0.0, 0.0)
        finally:
            await params.restore()
    times = record.times()
    stored = float(np.float32(target))
    zero = next((i for i, r in enumerate(record.reference)
                 if math.isclose(r, stored, rel_tol=1e-6, abs_tol=1e-6)), None)
    if zero is None and stop is not None and stop.is_set():
        empty = np.zeros(0)
        return StepRecord(empty, empty, empty, record)
    if zero is None:
        raise ExperimentError("the board never took the step's reference")
    after = slice(zero, None)
    return StepRecord(times[after] - times[zero], np.asarray(record.speed, dtype=float)[after],
                      np.asarray(record.pwm, dtype=float)[after], record)


async def apply_gains(link: Link, channel: str, gains: Gains) -> None:
    """Put ``gains`` into ``channel``'s software speed PID, each confirmed by the board."""
    await link.set_param(f"ActiveController{channel}", 0)
    await link.set_param(f"Kp_Wheel_Pid{channel}", gains.kp)
    await link.set_param(f"Ti_Wheel_Pid{channel}", gains.ti)
    await link.set_param(f"Td_Wheel_Pid{channel}", gains.td)
