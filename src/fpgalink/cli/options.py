"""The connection options every board command takes — ``--port``, ``--board``, ``--baud``,
``--timeout``, ``--retries``, ``--wire-crc``, ``--allow-mismatch``, ``-v``, ``--config`` —
accepted before the command (the usual place: ``fpgalink-cli --port /dev/ttyUSB0 param get
…``) and after it, and the links they open. Values resolve as :mod:`fpgalink.cli.settings`
describes.

Every link a command opens asks the board who it is first (docs/protocol.md §8): a board
whose firmware was built from another protocol declaration is refused with one line naming
both hashes (exit 10) unless ``--allow-mismatch``; a seed board goes on as "seed protocol,
identity unknown". ``send`` and the passive watchers ask nothing (:meth:`ConnectionOptions.
link`'s ``identify``)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

import click

from fpgalink.cli.output import CliError, ExitCode, FiniteRange, note
from fpgalink.cli.settings import (
    DEFAULT,
    EMULATOR_URL,
    Endpoint,
    Settings,
    parse_ports,
    resolve_settings,
)
from fpgalink.protocol.wire import MAX_BAUD, MIN_BAUD

if TYPE_CHECKING:  # the asyncio layer loads when a command first opens a link
    from click.shell_completion import CompletionItem

    from fpgalink.aio.link import Link
    from fpgalink.events import StatusEvent

__all__ = [
    "CONNECTION_OPTION_NAMES",
    "EMULATOR_URL",
    "ConnectionOptions",
    "Endpoint",
    "announce_emulator",
    "connection_options",
    "global_connection_options",
    "parse_ports",
]

T = TypeVar("T")

CONNECTION_OPTION_NAMES = ("ports", "board", "baud", "timeout", "retries", "wire_crc",
                           "allow_mismatch", "verbose", "config")


def _board_names(ctx: click.Context, param: click.Parameter, incomplete: str) -> list[str]:
    """Shell completion for --board: the names the configuration knows."""
    try:
        settings = resolve_settings({}, {})
    except CliError:
        return []
    return [e.name for e in settings.endpoints if e.name.startswith(incomplete)]


def _port_urls(ctx: click.Context, param: click.Parameter, incomplete: str
               ) -> list[CompletionItem]:
    """Shell completion for --port: the serial ports ``ports`` would list (their stable
    paths first), ``emu://`` for the built-in emulator, and paths (a pty, a device)."""
    from click.shell_completion import CompletionItem

    from fpgalink.cli.ports import scan_ports

    urls = ["emu://", "socket://127.0.0.1:"]
    try:
        from serial.tools import list_ports

        for report in scan_ports(list_ports.comports()):
            if report.usb_id is not None:
                urls += [u for u in (report.by_id, report.device) if u]
    except (OSError, ImportError):
        pass
    items = [CompletionItem(u) for u in dict.fromkeys(urls) if u.startswith(incomplete)]
    return [*items, CompletionItem(incomplete, type="file")]


def _options(multi: bool) -> list[Callable[[Callable[..., Any]], Callable[..., Any]]]:
    port_help = (
        "Board port: a device path (/dev/serial/by-id/… stays the same across boots), "
        "socket://HOST:PORT or emu://. "
        + ("Repeat as NAME=URL for several boards (--port L=… --port R=…). " if multi else "")
        + "Env FPGALINK_PORT, or the config file. Default: the built-in emulator."
    )
    return [
        click.option("--port", "ports", multiple=True, metavar="[NAME=]URL", help=port_help,
                     shell_complete=_port_urls),
        click.option("--board", metavar="NAME", shell_complete=_board_names,
                     help="Which board, when several are configured (env FPGALINK_BOARD)."),
        click.option("--baud", type=click.IntRange(MIN_BAUD, MAX_BAUD),
                     help="Line rate (env FPGALINK_BAUD)  [default: 1000000]"),
        click.option("--timeout", type=FiniteRange(min=0, min_open=True, max=60),
                     help="Per-try request timeout, s  [default: 0.05]"),
        click.option("--retries", type=click.IntRange(1, 1000),
                     help="Tries per request, resends included  [default: 8]"),
        click.option("--wire-crc/--no-wire-crc", default=None,
                     help="Connect with the wire CRC on, for a board left with WireCrc = 1 "
                          "(env FPGALINK_WIRE_CRC=1)  [default: off]"),
        click.option("--allow-mismatch", is_flag=True, default=None,
                     help="Go on with a board whose firmware was built from another protocol "
                          "declaration (its identity hash differs from this host's; refused "
                          "otherwise, exit 10)."),
        click.option("-v", "--verbose", count=True,
                     help="Each message a board sends, as it arrives, with its bytes, on "
                          "stderr; -vv telemetry too."),
        click.option("--config", metavar="FILE",
                     help="Config file (env FPGALINK_CONFIG; default fpgalink.toml here, "
                          "then ~/.config/fpgalink/fpgalink.toml)."),
    ]


def global_connection_options(func: Callable[..., T]) -> Callable[..., T]:
    """The same options on the group, so they may come before the command."""
    for option in reversed(_options(multi=True)):
        func = option(func)
    return func


@dataclass(frozen=True, slots=True)
class ConnectionOptions:
    settings: Settings

    @property
    def endpoints(self) -> tuple[Endpoint, ...]:
        return self.settings.endpoints

    @property
    def baud(self) -> int:
        return self.settings.baud

    @property
    def timeout(self) -> float:
        return self.settings.timeout

    @property
    def retries(self) -> int:
        return self.settings.retries

    @property
    def wire_crc(self) -> bool:
        return self.settings.wire_crc

    @property
    def verbose(self) -> int:
        return self.settings.verbose

    @property
    def allow_mismatch(self) -> bool:
        return self.settings.allow_mismatch

    @property
    def single(self) -> Endpoint:
        """The one board a one-board command talks to (``--board`` picks among several)."""
        endpoints, board = self.endpoints, self.settings.board
        if board is not None:
            for endpoint in endpoints:
                if endpoint.name == board:
                    return endpoint
            names = ", ".join(e.name for e in endpoints)
            raise CliError(f"--board {board}: no such board (configured: {names})",
                           ExitCode.BAD_INPUT)
        if len(endpoints) == 1:
            return endpoints[0]
        names = ", ".join(e.name for e in endpoints)
        where = self.settings.sources.get("port", "")
        raise CliError(f"this command talks to one board and {len(endpoints)} are configured "
                       f"({names}, from {where}): pick one with --board NAME",
                       ExitCode.BAD_INPUT)

    @property
    def selected(self) -> tuple[Endpoint, ...]:
        """The boards a command that can show several talks to: the one ``--board`` names
        (or the only one), else every board configured."""
        if self.settings.board is not None or len(self.endpoints) == 1:
            return (self.single,)
        return self.endpoints

    def link(self, endpoint: Endpoint, *, reconnect: bool = False,
             liveness_timeout: float | None = None, identify: bool = True,
             listen_only: bool = False) -> Link:
        """A link to ``endpoint`` (not open yet). By default a silent board must surface as
        "no answer after N tries", not as the shorter liveness timeout failing the request
        first, so liveness waits for every try. ``identify``: opening it asks the board who
        it is and refuses a mismatch unless ``--allow-mismatch`` (said on stderr when
        allowed). ``listen_only``: the link sends nothing of its own (``--passive``)."""
        from fpgalink.aio.link import open_link
        from fpgalink.cli.wirelog import log_wire

        if liveness_timeout is None:
            liveness_timeout = max(0.7, self.timeout * self.retries + 0.2)
        link = open_link(
            endpoint.url, self.baud, name=endpoint.name, request_timeout=self.timeout,
            request_tries=self.retries, liveness_timeout=liveness_timeout,
            reconnect=reconnect, wire_crc=self.wire_crc, identify=identify,
            allow_mismatch=self.allow_mismatch, listen_only=listen_only,
        )
        log_wire(endpoint.name, link, self.verbose)
        if identify and self.allow_mismatch:
            # An unnamed port (called 0, 1 …) is said by its URL.
            label = endpoint.url if endpoint.name.isdigit() else f"board {endpoint.name}"
            link.on_event(functools.partial(_say_mismatch, label))
        return link

    def note_ephemeral(self) -> None:
        """Say that an in-process board (emu://) forgets what this command changes."""
        if any(e.url.startswith(EMULATOR_URL) for e in self.endpoints):
            note("note: the built-in emulator lives only for this command; to keep a board "
                 "between commands, serve one (fpgaemu serve --pty --link /tmp/fpga) and give "
                 "--port /tmp/fpga")


def _say_mismatch(board: str, event: StatusEvent) -> None:
    """A mismatch let through by ``--allow-mismatch`` is still said, each time it is seen."""
    from fpgalink.events import BoardIdentified

    if isinstance(event, BoardIdentified) and event.mismatch is not None:
        note(f"{board}: {event.mismatch}; going on (--allow-mismatch)")


def announce_emulator(conn: ConnectionOptions) -> None:
    """Say on stderr when no port is configured and the built-in emulator stands in."""
    if conn.settings.sources["port"] == DEFAULT:
        note(f"no --port given (nor FPGALINK_PORT or a config file): using the built-in "
             f"emulator {EMULATOR_URL}")


def connection_options(*, multi: bool = False, announce: bool = True
                       ) -> Callable[[Callable[..., T]], Callable[..., T]]:
    """Add the connection options to a command; it receives ``conn``. Options given before
    the command (on the group) apply unless given again after it. ``announce``: say on
    stderr when no port is configured and the built-in emulator stands in."""

    def decorate(func: Callable[..., T]) -> Callable[..., T]:
        @functools.wraps(func)
        def wrapper(*args: Any, **kwargs: Any) -> T:
            given = {name: kwargs.pop(name) for name in CONNECTION_OPTION_NAMES}
            root = click.get_current_context().find_root()
            before = root.obj if isinstance(root.obj, dict) else {}
            settings = resolve_settings(given, before)
            conn = ConnectionOptions(settings)
            if announce:
                announce_emulator(conn)
            if not multi:
                conn.single  # noqa: B018 - validates: one board only
            return func(*args, conn=conn, **kwargs)

        for option in reversed(_options(multi)):
            wrapper = option(wrapper)
        return wrapper

    return decorate
