"""``--foxglove [HOST:]PORT``: a command's live view for Foxglove (:mod:`fpgalink.live`).
The option checks its address and that foxglove-sdk is there before anything runs; the view
is opened once the boards are, says its URL on stderr, and what it did when it closes."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable
from typing import TYPE_CHECKING, TypeVar

import click

from fpgalink.cli.output import CliError, ExitCode, note

if TYPE_CHECKING:
    from fpgalink.aio.link import Link
    from fpgalink.connection import LinkStats
    from fpgalink.live import LiveAddress, LiveView

__all__ = ["add_live_boards", "foxglove_option", "opened_live"]

T = TypeVar("T")


def _address(ctx: click.Context, param: click.Parameter, value: str | None
             ) -> LiveAddress | None:
    if value is None:
        return None
    from fpgalink.live import parse_address, require_sdk
    from fpgalink.protocol.exitcodes import NotInstalled

    try:
        address = parse_address(value)
    except ValueError as exc:
        raise click.BadParameter(str(exc), ctx, param) from None
    try:
        require_sdk()
    except NotInstalled as exc:
        raise CliError(str(exc), ExitCode.NOT_INSTALLED) from None
    return address


def foxglove_option(func: Callable[..., T]) -> Callable[..., T]:
    """``--foxglove [HOST:]PORT``; the command receives ``foxglove`` (a LiveAddress or
    None)."""
    return click.option(
        "--foxglove", "foxglove", metavar="[HOST:]PORT", callback=_address,
        help="Live view for Foxglove: a WebSocket server on PORT (loopback; give HOST to "
             "serve another interface; 0 a free port) streaming telemetry, parameters, "
             "link events, the robot's pose, path and truth, its URDF and supervision. "
             "Needs the foxglove extra.")(func)


@contextlib.asynccontextmanager
async def opened_live(address: LiveAddress | None, name: str
                      ) -> AsyncIterator[LiveView | None]:
    """The live view at ``address`` while the block runs (``None`` when not asked for)."""
    if address is None:
        yield None
        return
    from fpgalink.live import LiveView

    view = LiveView(address, name, say=note)
    try:
        view.start()
    except OSError as exc:
        raise CliError(f"--foxglove {address.host}:{address.port}: cannot listen: {exc}",
                       ExitCode.PORT) from None
    where = "" if address.loopback else " (every host that can reach it may watch)"
    note(f"live view for Foxglove on {view.url}{where} (in Foxglove: Open connection, "
         "Foxglove WebSocket)")
    try:
        yield view
    finally:
        await view.close()
        stats = view.stats
        dropped = (f"; {stats.dropped_clients} let go for not reading"
                   if stats.dropped_clients else "")
        note(f"live view: {stats.clients_seen} client(s), {stats.published:,} messages "
             f"sent{dropped}")


def add_live_boards(view: LiveView | None, links: dict[str, Link]) -> None:
    """Each board of a command that has no robot (``monitor``, ``step``): its own link."""
    if view is None:
        return
    from fpgalink.live import BoardTap

    for name, link in links.items():
        def on_event(callback: Callable[[str, str], None], link: Link = link
                     ) -> Callable[[], None]:
            return link.on_event(lambda event: callback(event.name, event.describe()))

        def stats(link: Link = link) -> LinkStats:
            return link.stats

        view.add_board(name, BoardTap(
            add_listener=link.add_listener, stamped_telemetry=link.stamped_telemetry,
            stats=stats, held=link.held, on_event=on_event))
