"""``router``: one process owns the boards' ports and offers each board to several local
clients (docs/cli.md, ``router``). The daemon is :mod:`fpgalink.router`; this is its
command line: the options, the stop signals, the errors as one line and an exit code, and
each client's counts when it stops."""

from __future__ import annotations

import asyncio
import dataclasses
from pathlib import Path
from typing import Any

import click

from fpgalink.cli.formats import Column, emit_document, emit_rows, format_option
from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, echo_out, note
from fpgalink.cli.session import install_stop_signals, run
from fpgalink.ports import LinkError, LinkSpecError, LinkTaken, parse_links
from fpgalink.router import BoardRoute, serve_routes

__all__ = ["router"]


def _rows(routes: list[BoardRoute]) -> list[dict[str, Any]]:
    rows = []
    for route in routes:
        for stats in route.history:
            row = dataclasses.asdict(stats)
            row["refused_by_id"] = dict(stats.refused_by_id)
            row["to_board_by_id"] = dict(stats.to_board_by_id)
            rows.append({"board": route.name, **row})
    return rows


SUMMARY_COLUMNS = (
    Column("board", "board"), Column("client", "client", justify="right"),
    Column("role", "role"), Column("peer", "peer", drop=2),
    Column("frames_to_client", "frames to it", justify="right"),
    Column("dropped_frames", "dropped", justify="right"),
    Column("frames_to_board", "to board", justify="right"),
    Column("refused_frames", "refused", justify="right"),
    Column("line_full_frames", "line full", justify="right", drop=3),
    Column("overtaken_frames", "behind RD", justify="right", drop=3),
    Column("unsent_frames", "unsent", justify="right", drop=3),
    Column("bytes_to_client", "bytes to it", justify="right", drop=1),
)


@click.command(epilog=EXIT_CODES_HELP)
@click.option("--tcp", "first_port", type=click.IntRange(0, 65535), default=0,
              show_default=True,
              help="TCP port of the first board on 127.0.0.1, the next board's one more; 0: "
                   "any free ports (the ready lines say which).")
@click.option("--pty", "ptys", type=click.IntRange(0, 16), default=0, show_default=True,
              help="Also offer each board on this many pseudo-terminals, one client each "
                   "(a path such as /dev/pts/7, given as --port).")
@click.option("--link", "links", multiple=True, metavar="[NAME=]PATH",
              help="A pseudo-terminal for board NAME behind a stable symlink PATH (as "
                   "fpgaemu serve --link), one client at a time; repeatable, removed on "
                   "exit.")
@click.option("--reconnect/--no-reconnect", default=True, show_default=True,
              help="Reopen a board's port that goes away (unplugged) while its clients "
                   "stay connected; with --no-reconnect the router stops (exit 5).")
@click.option("--client-buffer", type=click.IntRange(4096, 1 << 30), default=1 << 20,
              show_default=True,
              help="Bytes a client may leave unread before the board's frames are dropped "
                   "for it (counted).")
@format_option
@connection_options(multi=True)
def router(first_port: int, ptys: int, links: tuple[str, ...], reconnect: bool,
           client_buffer: int, fmt: str, conn: ConnectionOptions) -> int:
    """Share each board among several local clients: one controller, observers read-only.

    Opens every board's port (--port NAME=URL, repeatable) and serves each on
    127.0.0.1 over TCP, printing "ready NAME socket://127.0.0.1:PORT" once all are served
    (and "ready NAME PATH -> /dev/pts/N" for each --link); give that URL or PATH as --port
    to any command or to open_link. Every client receives every frame its board sends.
    The first client to send is the controller; frames from the others are refused and
    counted, a refused PS or PG answered "refused by the router" (run watchers with
    --passive). What waits for a board is at most 200 ms of line time: a controller
    writing faster has the rest refused, counted. When the controller leaves, the board
    gets RD at once, ahead of its frames still waiting (dropped, counted). A board's port
    that goes away is reopened until it is back. -v says each RE and RD a client passes.
    Ctrl-C or SIGTERM stops the router and prints each client's counts (frames delivered,
    dropped for a full buffer, passed, refused).
    """
    routes = [BoardRoute(e.name, e.url, client_buffer, baud=conn.baud, verbose=conn.verbose,
                         say=note) for e in conn.endpoints]
    try:
        slots = parse_links(links, [r.name for r in routes])
    except LinkSpecError as exc:
        raise CliError(str(exc), ExitCode.BAD_INPUT) from None
    try:
        code = run(_route(routes, first_port, ptys, slots, reconnect),
                   ", ".join(r.url for r in routes))
    except LinkError as exc:  # another's (exit 2), or refused by the system
        raise CliError(str(exc), ExitCode.BAD_INPUT if isinstance(exc, LinkTaken)
                       else ExitCode.PORT) from None
    rows = _rows(routes)
    if fmt == "json":
        emit_document({"boards": [{"board": r.name, "url": r.url,
                                   "frames_from_board": r.frames_from_board,
                                   "board_framing_errors": r.board_framing_errors,
                                   "frames_cut": r.frames_cut,
                                   "disables_sent": r.disables_sent,
                                   "port_losses": r.port_losses,
                                   "reconnects": r.reconnects}
                                  for r in routes], "clients": rows})
    else:
        emit_rows(fmt, SUMMARY_COLUMNS, rows, title="Router clients")
    for route in routes:
        if route.port_losses:
            note(f"board {route.name}: its port went away {route.port_losses} time(s) and "
                 f"came back {route.reconnects} time(s)")
    return code


async def _route(routes: list[BoardRoute], first_port: int, ptys: int,
                 links: list[tuple[str, Path]], reconnect: bool) -> int:
    stop = asyncio.Event()
    install_stop_signals(stop)
    gone = await serve_routes(routes, stop, echo_out, first_port=first_port, ptys=ptys,
                              links=links, reconnect=reconnect)
    return ExitCode.PORT if gone else ExitCode.OK
