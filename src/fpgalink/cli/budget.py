"""``budget``: the static timing-budget calculator — per direction, how much of each timer
period the planned traffic takes on an 8N1 line, and whether it fits (SPEC §2, §7).

The wire arithmetic lives in :mod:`fpgalink.budget` (shared with the emulator); this module
only gathers the traffic plan from the command line and presents the result."""

from __future__ import annotations

from typing import Any

import click

from fpgalink.cli.formats import Column, emit_document, emit_rows, format_option
from fpgalink.cli.output import (
    EXIT_CODES_HELP,
    CliError,
    ExitCode,
    FiniteRange,
    echo_out,
)
from fpgalink.protocol import CRC_BYTES, DEFAULT_FRAMING, MessageId, Role
from fpgalink.protocol.wire import MAX_BAUD, MIN_BAUD, TM_CONTENT_BYTES, Flow, plan

__all__ = ["budget", "parse_message"]

_DIRECTION_WORDS = {"up": True, "to-board": True, "down": False, "to-host": False}
MAX_CONTENT = DEFAULT_FRAMING.max_content


def parse_message(text: str, crc: bool = False) -> Flow:
    """``NAME:BYTES:PER_PERIOD[:up|down]`` → a flow; BYTES is the frame content size (with
    ``crc``, the wire CRC's two bytes are added to it). A catalogued ID knows its
    direction; any other is assumed host → board."""
    parts = text.split(":")
    if len(parts) not in (3, 4):
        raise CliError(f"--message {text!r}: expected NAME:BYTES:PER_PERIOD[:up|down]",
                       ExitCode.BAD_INPUT)
    name = parts[0].strip().upper()
    try:
        content, per_period = int(parts[1]), float(parts[2])
    except ValueError:
        raise CliError(f"--message {text!r}: BYTES must be an integer and PER_PERIOD a number",
                       ExitCode.BAD_INPUT) from None
    if not 1 <= content <= MAX_CONTENT or not 0 <= per_period < float("inf"):
        raise CliError(f"--message {text!r}: BYTES must be 1..{MAX_CONTENT} (the frame content "
                       "limit) and PER_PERIOD a finite number ≥ 0", ExitCode.BAD_INPUT)
    if len(parts) == 4:
        word = parts[3].strip().lower()
        if word not in _DIRECTION_WORDS:
            raise CliError(f"--message {text!r}: direction must be up or down",
                           ExitCode.BAD_INPUT)
        to_board = _DIRECTION_WORDS[word]
    else:
        known = MessageId.lookup(name)
        to_board = known is None or known.sender is Role.HOST
    if crc:
        if content + CRC_BYTES > MAX_CONTENT:
            raise CliError(f"--message {text!r}: {content} + {CRC_BYTES} CRC bytes is over "
                           f"the {MAX_CONTENT}-byte frame content limit", ExitCode.BAD_INPUT)
        content += CRC_BYTES
    return Flow(name, content, per_period, to_board=to_board)


@click.command(epilog=EXIT_CODES_HELP)
@click.option("--baud", type=click.IntRange(MIN_BAUD, MAX_BAUD), default=1_000_000,
              show_default=True, envvar="FPGALINK_BAUD", help="Line rate, 8N1.")
@click.option("--period-ms", type=FiniteRange(min=0, min_open=True, max=60_000), default=1.0,
              show_default=True, help="Timer period (TsTimerPeriod), ms.")
@click.option("--tm-bytes", type=click.IntRange(0, MAX_CONTENT), default=TM_CONTENT_BYTES,
              show_default=True,
              help=f"TM frame content bytes ({TM_CONTENT_BYTES} in this protocol; 0: none).")
@click.option("--message", "messages", multiple=True, metavar="NAME:BYTES:PER_PERIOD",
              help="More traffic: frame content BYTES, PER_PERIOD frames each period; "
                   "direction from the ID (PS/PG/RV up, PA/PN/TM down) or a 4th field "
                   "up|down. Repeatable. The seed's case: --message BIG:200:1.")
@click.option("--crc", is_flag=True,
              help=f"The wire CRC is on (WireCrc = 1): every counted message, TM included, "
                   f"carries {CRC_BYTES} more content bytes.")
@click.option("--check", is_flag=True, help="Exit 1 when a direction does not fit.")
@format_option
def budget(baud: int, period_ms: float, tm_bytes: int, messages: tuple[str, ...],
           crc: bool, check: bool, fmt: str) -> int:
    """Static timing budget: wire bytes per period and utilisation per direction.

    One byte is 10 bit times on 8N1: at 1 MBd a 1 ms period holds 100 wire bytes per
    direction. A 200-byte frame every 1 ms (the seed's claim) needs over 2 ms.
    """
    flows = [parse_message(m, crc) for m in messages]
    if tm_bytes:
        flows.insert(0, Flow("TM", tm_bytes + (CRC_BYTES if crc else 0), 1.0, to_board=False))
    report = plan(baud, period_ms / 1000.0, flows)
    capacity = report.to_host.capacity
    rows: list[dict[str, Any]] = []
    for load in (report.to_board, report.to_host):
        for flow in load.flows:
            per_period = flow.typical_wire * flow.per_period
            rows.append({"direction": "to_board" if flow.to_board else "to_host",
                         "message": flow.name, "content_bytes": flow.content_length,
                         "wire_bytes": flow.typical_wire,
                         "worst_case_wire_bytes": flow.worst_wire,
                         "per_period": flow.per_period, "wire_bytes_per_period": per_period,
                         "share": per_period / capacity})
    if fmt == "json":
        emit_document({
            "baud": baud, "period_ms": period_ms, "crc": crc,
            "capacity_wire_bytes_per_period": capacity,
            "directions": [{"direction": key, "wire_bytes_per_period": load.typical,
                            "utilisation": load.utilisation, "fits": load.fits,
                            "worst_case_wire_bytes_per_period": load.worst,
                            "worst_case_utilisation": load.worst_utilisation,
                            "fits_worst_case": load.fits_worst_case}
                           for key, load in (("to_board", report.to_board),
                                             ("to_host", report.to_host))],
            "flows": rows, "fits": report.fits, "explanation": report.explain(),
        })
    elif fmt == "csv":
        emit_rows(fmt, FLOW_COLUMNS, rows)
    else:
        title = (f"Timing budget at {baud:,} baud, {period_ms:g} ms period "
                 f"({capacity:,.1f} wire bytes per direction per period)"
                 + (f", wire CRC on (+{CRC_BYTES} B per counted message)" if crc else ""))
        names = {"to_board": "host→board", "to_host": "board→host"}
        shown = [{**row, "direction": names[row["direction"]],
                  "per_period": f"{row['per_period']:g}",
                  "wire_bytes_per_period": f"{row['wire_bytes_per_period']:,.1f}",
                  "share": f"{row['share']:.1%}"} for row in rows]
        emit_rows(fmt, FLOW_COLUMNS, shown, title=title)
        for line in report.explain():
            echo_out(line)
    fits_all = report.fits
    return ExitCode.FAILURE if check and not fits_all else ExitCode.OK


FLOW_COLUMNS = (
    Column("direction", "direction"),
    Column("message", "message"),
    Column("content_bytes", "content B", justify="right", drop=2),
    Column("wire_bytes", "wire B", justify="right"),
    Column("worst_case_wire_bytes", "worst-case B", justify="right", drop=1),
    Column("per_period", "per period", justify="right"),
    Column("wire_bytes_per_period", "wire B/period", justify="right"),
    Column("share", "share", justify="right"),
)
