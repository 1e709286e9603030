"""Setting a robot's boards up at start, over their links: wait until every board is heard,
quiet the ones found streaming, ask each who it is (docs/protocol.md §8: one built from
another protocol declaration is refused before anything else is set), load the
description's parameters, read back what odometry and joint states use, and turn telemetry
on (:meth:`fpgalink.robot.Robot.start`)."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

from fpgalink.aio.link import Link
from fpgalink.errors import BoardLost, FpgalinkError, RequestTimeout, WireCrcMismatchError
from fpgalink.protocol.identity import require_identity
from fpgalink.protocol.robot import RobotDescription
from fpgalink.robot.errors import RobotError

__all__ = ["QUIET_TIMEOUT_S", "START_TIMEOUT_S", "answering", "configure", "identify", "quiet",
           "set_up", "wait_for_boards"]

#: How long :meth:`Robot.start` waits for every board to be heard.
START_TIMEOUT_S = 5.0
#: How long :func:`quiet` waits for a board found streaming to confirm it stopped: its
#: echo comes after the telemetry waiting in the port (serve keeps 1 s of line time, a
#: host reading at a quarter of the line drains that in 4 s).
QUIET_TIMEOUT_S = 10.0


async def wait_for_boards(links: Mapping[str, Link]) -> None:
    """Until every board is heard; :class:`RobotError` naming the silent ones after
    :data:`START_TIMEOUT_S`."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + START_TIMEOUT_S
    while not all(link.board_alive for link in links.values()):
        if loop.time() > deadline:
            silent = [n for n, lk in links.items() if not lk.board_alive]
            raise RobotError(f"board {', '.join(silent)} not answering after "
                             f"{START_TIMEOUT_S:g} s")
        await asyncio.sleep(0.01)


@contextmanager
def answering(name: str, doing: str) -> Iterator[None]:
    """A board that stops answering during a step of the start is named with the step (a
    link's own errors say only what went unanswered): :class:`RobotError` "board NAME not
    answering: DOING: …", which the CLI and the node both exit 4 for."""
    try:
        yield
    except WireCrcMismatchError:
        raise  # it answers, in the other wire-CRC mode: the caller's advice says how to connect
    except (RequestTimeout, BoardLost) as exc:
        raise RobotError(f"board {name} not answering: {doing}: {exc}") from exc


async def quiet(name: str, link: Link) -> int | float:
    """A board found streaming is turned quiet before it is set up; returns whether it
    streamed (``GetDataPeriodical``, set again at close).

    A host slower than the stream (a loaded machine, a board left sending a TM every 1 ms
    by a host before) finds every answer behind the telemetry waiting in its port, later
    than a request's patience (a ROS node gave up at start: "get TorqueCoefB: no answer
    after 8 tries"). The board takes the ``0`` at once, whatever the host is behind on;
    its echo comes once what waits is read, so it is asked again for as long as the board
    is heard, up to :data:`QUIET_TIMEOUT_S` (and the request then under way, its tries).
    A board found sending telemetry counts as streaming: a start that fails after this
    leaves it quiet."""
    if not link.stats.telemetry_received:
        with answering(name, "asking whether it streams"):
            return await link.get_param("GetDataPeriodical")
    loop = asyncio.get_running_loop()
    deadline = loop.time() + QUIET_TIMEOUT_S
    while True:
        try:
            await link.set_param("GetDataPeriodical", 0)
            return 1
        except (RequestTimeout, BoardLost) as exc:
            if isinstance(exc, BoardLost) or loop.time() > deadline \
                    or not link.board_alive:
                raise RobotError(f"board {name} not answering: turning its telemetry "
                                 f"off to set it up: {exc}") from exc


async def identify(name: str, link: Link, allow_mismatch: bool) -> None:
    """Ask board ``name`` who it is; :class:`~fpgalink.protocol.IdentityMismatch` naming the
    board and both hashes when its firmware was built from another protocol declaration
    (unless ``allow_mismatch``). Its link asks again after each restart."""
    with answering(name, "asking who it is"):
        identity = await link.identification.identify(allow_mismatch=True)
    if not allow_mismatch:
        require_identity(identity, f"board {name} ({link.url})")


async def set_up(links: Mapping[str, Link], description: RobotDescription,
                 allow_mismatch: bool = False
                 ) -> tuple[dict[str, int | float], dict[tuple[str, int, str], float]]:
    """Every board heard: quiet the ones streaming, ask each who it is, then configure each.
    Returns each board's telemetry setting as found, and what was read back by (board,
    channel, parameter)."""
    # Every board found streaming is quieted before any is set up, all at once: one set up
    # first would leave the others' telemetry piling up in their ports.
    found = await asyncio.gather(*(quiet(name, link) for name, link in links.items()),
                                 return_exceptions=True)
    streaming_before: dict[str, int | float] = {}
    for name, outcome in zip(links, found, strict=True):
        if isinstance(outcome, BaseException):
            raise outcome
        streaming_before[name] = outcome
    # Quiet first (a GetDataPeriodical the seed's protocol has, as every declaration does):
    # a board streaming answers late. Then who each is, before any of them is configured.
    for name, link in links.items():
        await identify(name, link, allow_mismatch)
    readings: dict[tuple[str, int, str], float] = {}
    for name, link in links.items():
        for channel, (pulses, torque) in (await configure(name, link, description)).items():
            readings[(name, channel, "IncSenzRes")] = pulses
            readings[(name, channel, "TorqueCoef")] = torque
    return streaming_before, readings


async def configure(name: str, link: Link, description: RobotDescription
                    ) -> dict[int, tuple[int, float]]:
    """Load the description's parameters into board ``name``, then read back each of its
    wheels' encoder resolution (pulses a turn) and torque coefficient (N·m/A), by channel;
    telemetry on last."""
    for param, channel, value in description.settings_for(name):
        loading = f"loading {param.full_name(channel)} = {value}"
        try:
            with answering(name, loading):
                await link.set_param(param.id, value, channel or None)
        except RobotError:
            raise
        except FpgalinkError as exc:
            raise RobotError(f"board {name}: {loading}: {exc}") from exc
    with answering(name, "reading back its wheels and period"):
        readings = await _read_back(name, link, description)
        # The link then knows the period its telemetry must keep (TelemetryStale).
        await link.get_param("TsTimerPeriod")
    with answering(name, "turning its telemetry on"):
        await link.set_param("GetDataPeriodical", 1)
    return readings


async def _read_back(name: str, link: Link, description: RobotDescription
                     ) -> dict[int, tuple[int, float]]:
    readings: dict[int, tuple[int, float]] = {}
    for wheel in description.wheels:
        if wheel.board == name:
            pulses = int(await link.get_param("IncSenzRes", wheel.channel))
            if pulses <= 0:  # before telemetry is on: a start that fails leaves it quiet
                raise RobotError(f"board {name}: {wheel.name}: the board reports {pulses} "
                                 "encoder pulses per turn; odometry needs a positive "
                                 "resolution")
            readings[wheel.channel] = (
                pulses, float(await link.get_param("TorqueCoef", wheel.channel)))
    return readings
