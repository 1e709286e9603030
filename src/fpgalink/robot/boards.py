"""The robot's boards over their links (asyncio): what the robot writes to them (references,
enable, disable), and what its readers may ask of each board (its telemetry, its
connection's reports, its parameters, its statistics) without reaching into the links: the
robot owns them, and everything that drives the wheels goes through its arbiter."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

from fpgalink.aio.link import Link, Stamped, Subscription, open_link
from fpgalink.connection import LinkStats
from fpgalink.errors import FpgalinkError
from fpgalink.events import Event
from fpgalink.protocol import BoardIdentity, Telemetry
from fpgalink.robot.health import Status, WireUse, board_status

__all__ = ["TRUTH_EXTRA", "UNANSWERED_ROUNDS", "Boards", "open_links"]

#: What an emulated robot's transport offers for its true pose (see fpgaemu.serve).
TRUTH_EXTRA = "fpgaemu.truth"
#: A request a board that is heard leaves unanswered after its tries (8 × 50 ms) is asked
#: again at once this many more times (Settings.unanswered_rounds): on a loaded machine an
#: answer comes later than the tries, and a robot must not give up at start for it.
UNANSWERED_ROUNDS = 4


def open_links(ports: Mapping[str, str], *, baud: int = 1_000_000, stale_periods: int = 50,
               wire_crc: bool = False, identity_seed: int | None = None,
               read_latency: float | None = None) -> dict[str, Link]:
    """A robot's links to ``ports`` (board name → URL). ``stale_periods``: timer periods
    without a board's telemetry that stop the robot (:class:`~fpgalink.Connection`);
    ``wire_crc``: the boards' frames carry the wire CRC (docs/protocol.md §7);
    ``identity_seed``: the identity queries' nonces drawn from it (with the board's name), so
    that a run is repeated byte for byte (a campaign's scenario), else from the system;
    ``read_latency``: the links read in batches under it (:meth:`Link.set_read_latency`)."""
    links = {name: open_link(url, baud, name=name, stale_periods=stale_periods,
                             unanswered_rounds=UNANSWERED_ROUNDS, wire_crc=wire_crc,
                             read_latency=read_latency)
             for name, url in ports.items()}
    if identity_seed is not None:
        for name, link in links.items():
            link.identification.nonces.seed(f"{identity_seed}/{name}")
    return links


class Boards:
    """Board name → link, as the robot's description names them."""

    def __init__(self, links: Mapping[str, Link]) -> None:
        self.links = dict(links)
        self._wire = {name: WireUse(link.connection.baud) for name, link in self.links.items()}

    # --- what the robot writes --------------------------------------------------------------

    def send(self, references: Mapping[str, tuple[float, float]]) -> None:
        """``RV`` to each board: (A, B), deg/s in its own sign (N·m in torque control)."""
        for board, (ref_a, ref_b) in references.items():
            self.links[board].set_references(ref_a, ref_b)

    def send_each(self, references: Mapping[str, tuple[float, float]]) -> None:
        """As :meth:`send`, each board whatever another's link says (one whose port is
        gone is said by its link; the others still get theirs)."""
        for board, (ref_a, ref_b) in references.items():
            with contextlib.suppress(FpgalinkError):
                self.links[board].set_references(ref_a, ref_b)

    def enable_all(self) -> tuple[str, FpgalinkError] | None:
        """``RV 0`` then ``RE`` to every board; the first board whose link refuses (and
        why), the boards after it not asked."""
        for name, link in self.links.items():
            try:
                # Zero first. This project's board clears its references when enable falls
                # (SPEC §4); the seed's firmware gated only the PWM output (its §3.2) and
                # kept its references in memory, so such a board would drive off with the
                # last ones when enabled again.
                link.set_references(0.0, 0.0)
                link.enable()
            except FpgalinkError as exc:
                return name, exc
        return None

    def disable_all(self) -> None:
        """``RD`` and zero references to every board. A link that cannot send them is
        closed (it sent RD as it closed) or its port is gone (the board's watchdog
        disables it in 300 ms)."""
        for link in self.links.values():
            with contextlib.suppress(FpgalinkError):
                link.disable()
                link.set_references(0.0, 0.0)

    def disable_at_once(self) -> None:
        """``RD`` to every board, whatever goes wrong on the way (a robot task failed)."""
        for link in self.links.values():
            with contextlib.suppress(Exception):
                link.disable()

    async def restore(self, streaming_before: Mapping[str, int | float]) -> None:
        """Each board's telemetry setting as it was found (the robot turned it on)."""
        for name, link in self.links.items():
            before = streaming_before.get(name)
            if before is not None and before != 1 and link.board_alive:
                with contextlib.suppress(FpgalinkError):
                    await link.set_param("GetDataPeriodical", before)

    async def open(self) -> None:
        await asyncio.gather(*(link.open() for link in self.links.values()))

    async def close(self) -> None:
        await asyncio.gather(*(link.close() for link in self.links.values()),
                             return_exceptions=True)

    # --- what a reader may ask --------------------------------------------------------------

    def telemetry(self, board: str, maxsize: int = 256) -> Subscription[Telemetry]:
        """Board ``board``'s telemetry, every sample, as an async iterator."""
        return self.links[board].telemetry(maxsize)

    def stamped_telemetry(self, board: str, maxsize: int = 256) -> Subscription[Stamped]:
        """As :meth:`telemetry`, each sample with when it arrived (the loop's clock)."""
        return self.links[board].stamped_telemetry(maxsize)

    def add_listener(self, board: str, listener: Callable[[Event], None]
                     ) -> Callable[[], None]:
        """Everything board ``board``'s connection reports, in order (messages, requests'
        outcomes…); returns a remover."""
        return self.links[board].add_listener(listener)

    def stats(self, board: str) -> LinkStats:
        return self.links[board].stats

    def alive(self, board: str) -> bool:
        return self.links[board].board_alive

    def held(self, board: str) -> dict[str, int | float]:
        """The parameters this host holds for board ``board`` (set again after a restart),
        by name."""
        return self.links[board].held

    def url(self, board: str) -> str:
        return self.links[board].url

    def identity(self, board: str) -> tuple[BoardIdentity | None, bool]:
        """Who board ``board`` said it is (``None``: a seed board), and whether that is
        known: asked at start, and again after each restart (docs/protocol.md §8)."""
        link = self.links[board]
        return link.identification.identity, link.identification.known

    async def read_parameters(self, board: str, *, hold: bool = False
                              ) -> dict[tuple[int, int], int | float]:
        """Every parameter of board ``board`` as it has it, by (id, channel); ``hold``:
        each becomes what its link sets again after a restart."""
        return await self.links[board].read_params(hold=hold)

    async def set_parameter(self, board: str, param: int | str, value: float,
                            channel: int | None = None) -> int | float:
        """Set one parameter on board ``board`` and return the value its echo confirmed
        (held by its link: set again after a restart)."""
        return await self.links[board].set_param(param, value, channel)

    def set_stale_periods(self, periods: int) -> None:
        """A board's telemetry missing for this many of its timer periods is a fault."""
        for link in self.links.values():
            link.connection.settings = dataclasses.replace(link.connection.settings,
                                                           stale_periods=periods)

    def status(self, name: str, now: float, latest: Telemetry | None, fault: str | None
               ) -> Status:
        """Board ``name``'s health (``latest``: its latest sample, which says whether it is
        enabled); wire use since the last call (``now``, the loop's clock)."""
        link = self.links[name]
        stats = link.stats
        return board_status(name, link.url, alive=link.board_alive,
                            enabled=bool(latest is not None and latest.a.enabled),
                            stats=stats,
                            wire=self._wire[name].update(now, stats.bytes_received,
                                                         stats.bytes_sent),
                            fault=fault, identity=self.identity(name))

    def truth(self) -> dict[str, Any] | None:
        """The true pose when the robot is emulated (``None`` on hardware)."""
        for link in self.links.values():
            source = link.get_extra_info(TRUTH_EXTRA)
            if source is not None:
                record: dict[str, Any] = source()
                return record
        return None
