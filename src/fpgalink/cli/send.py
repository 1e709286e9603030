"""``send``: one counted message (or a direct command), optionally waiting for a reply."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path
from typing import Any

import click

from fpgalink.cli.formats import Column, emit_document, emit_rows, format_option
from fpgalink.cli.options import ConnectionOptions, connection_options
from fpgalink.cli.output import (
    EXIT_CODES_HELP,
    CliError,
    ExitCode,
    FiniteRange,
    describe,
    echo_out,
    message_fields,
    message_id,
)
from fpgalink.cli.session import on_messages, run
from fpgalink.errors import LocalProtocolError
from fpgalink.protocol import (
    Binary,
    CountedMessage,
    DirectCommand,
    Disable,
    Enable,
    Malformed,
    MessageId,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    Parsed,
    References,
    Role,
    Text,
    encode_message,
    parse_content,
)
from fpgalink.protocol.messages import BodyItem

__all__ = ["send"]

_ITEM_OPTIONS = ("text", "hex_items", "bin_files")
_ORDER_KEY = "fpgalink.send.item_order"


class _OrderedItems(click.Command):
    """Remembers the order in which --text/--hex/--bin-file were given, so body items go on
    the wire in command-line order (click groups repeated options by name)."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        try:
            _, _, order = self.make_parser(ctx).parse_args(args=list(args))
        except click.UsageError:
            order = []  # the real parse below reports it
        ctx.meta[_ORDER_KEY] = [p.name for p in order if p.name in _ITEM_OPTIONS]
        return super().parse_args(ctx, args)


def _parse_hex(text: str) -> bytes:
    cleaned = text.replace(":", "").replace(" ", "").replace("_", "")
    if cleaned.lower().startswith("0x"):
        cleaned = cleaned[2:]
    try:
        return bytes.fromhex(cleaned)
    except ValueError:
        raise CliError(f"--hex {text!r}: not hexadecimal bytes (e.g. 0a1b or 0a:1b)",
                       ExitCode.BAD_INPUT) from None


def build_items(ctx: click.Context, texts: tuple[str, ...], hexes: tuple[str, ...],
                files: tuple[Path, ...]) -> tuple[BodyItem, ...]:
    queues: dict[str, list[Any]] = {
        "text": list(texts), "hex_items": list(hexes), "bin_files": list(files)
    }
    order: list[str] = ctx.meta.get(_ORDER_KEY) or [
        name for name in _ITEM_OPTIONS for _ in queues[name]
    ]
    items: list[BodyItem] = []
    for name in order:
        value = queues[name].pop(0)
        if name == "text":
            items.append(Text(value.encode("utf-8")))
        elif name == "hex_items":
            items.append(Binary(_parse_hex(value)))
        else:
            try:
                items.append(Binary(Path(value).read_bytes()))
            except OSError as exc:
                raise CliError(f"--bin-file {value}: {exc.strerror}", ExitCode.BAD_INPUT) from None
    return tuple(items)


@click.command(cls=_OrderedItems, epilog=EXIT_CODES_HELP)
@click.argument("msg_id", metavar="ID")
@click.option("--text", multiple=True, metavar="T", help="A text body item (repeatable).")
@click.option("--hex", "hex_items", multiple=True, metavar="HEX",
              help="A binary section from hex bytes, e.g. 0a1b2c (repeatable).")
@click.option("--bin-file", "bin_files", multiple=True, metavar="F",
              type=click.Path(dir_okay=False, path_type=Path),
              help="A binary section from a file's bytes (repeatable).")
@click.option("--reply", "reply_id", metavar="ID2",
              help="Wait for the reply and print it: for PS/PG the board's PA or PN about "
                   "that parameter (a PN exits 3), else the first message with ID2.")
@click.option("--wait", type=FiniteRange(min=0, min_open=True, max=3600), default=1.0,
              show_default=True, help="How long to wait for --reply, s.")
@format_option
@click.option("--force", is_flag=True,
              help="Send even what the library would refuse: a body that does not match a "
                   "catalogued layout, or references that are not finite numbers.")
@connection_options()
@click.pass_context
def send(ctx: click.Context, msg_id: str, text: tuple[str, ...], hex_items: tuple[str, ...],
         bin_files: tuple[Path, ...], reply_id: str | None, wait: float, fmt: str, force: bool,
         conn: ConnectionOptions) -> int:
    """Send one message with ID and print it; with --reply, wait for the reply.

    ID is a counted message (two characters A-Z0-9; body items from --text/--hex/--bin-file
    in command-line order) or a direct command: RE (enable once) or RD (disable). A body that
    fits a catalogued ID (PS, PG, RV …) is shown decoded.

    \b
    Examples:
      fpgalink-cli send ZZ --text hello --hex 0102
      fpgalink-cli send PG --hex 0200 --reply PA      # read GetDataPeriodical
      fpgalink-cli send RD
    """
    msg_id = msg_id.strip().upper()
    items = build_items(ctx, text, hex_items, bin_files)
    message: CountedMessage | DirectCommand
    known = MessageId.lookup(msg_id)
    request: ParamSet | ParamGet | None = None
    if known is not None and known.direct:
        if known.sender is not Role.HOST:
            raise CliError(f"{msg_id} is what a board sends, not a host", ExitCode.BAD_INPUT)
        if items:
            raise CliError(f"{msg_id} is a direct command: it carries no body", ExitCode.BAD_INPUT)
        message = Enable() if known is MessageId.RE else Disable()
        shown = msg_id
    else:
        message = CountedMessage(msg_id, items)
        # Validate (ID, lengths) and see how the board will read it, before opening the port.
        try:
            content = encode_message(message, 0)
        except LocalProtocolError as exc:  # the encoder says what does not fit
            raise CliError(f"cannot send {msg_id!r}: {exc}", ExitCode.BAD_INPUT) from None
        parsed = parse_content(content)
        if isinstance(parsed, Malformed) and not force:
            raise CliError(f"{msg_id}: {parsed.detail or parsed.reason.value} "
                           "(--force sends it anyway)", ExitCode.BAD_INPUT)
        if isinstance(parsed, References) and not force and not (
                math.isfinite(parsed.ref_a) and math.isfinite(parsed.ref_b)):
            raise CliError(f"RV with references ({parsed.ref_a}, {parsed.ref_b}): not finite "
                           "numbers; a board must never get one (--force sends it anyway)",
                           ExitCode.BAD_INPUT)
        if isinstance(parsed, ParamSet | ParamGet):
            request = parsed
        shown = describe(parsed)
    reply = reply_id.strip().upper() if reply_id else None
    if request is not None and isinstance(request, ParamSet):
        conn.note_ephemeral()
    return run(_send(conn, message, shown, reply, request, wait, fmt), conn.single.url)


async def _send(conn: ConnectionOptions, message: CountedMessage | DirectCommand, shown: str,
                reply_id: str | None, request: ParamSet | ParamGet | None, wait: float,
                fmt: str) -> int:
    endpoint = conn.single
    # send puts on the wire only what it is given (a board's handling of any message,
    # another declaration's included, is what it is for): it does not ask the identity.
    async with conn.link(endpoint, identify=False) as link:
        loop = asyncio.get_running_loop()
        replied: asyncio.Future[Parsed] = loop.create_future()
        others: list[str] = []

        def answers(received: Parsed) -> bool:
            if request is not None and isinstance(received, ParamAck | ParamNack):
                return (received.param_id, received.channel) == (request.param_id,
                                                                 request.channel)
            return message_id(received) == reply_id

        def on_message(received: Parsed) -> None:
            if replied.done():
                return
            if answers(received):
                replied.set_result(received)
            else:
                others.append(message_id(received))

        if reply_id is not None:
            on_messages(link, on_message)  # before sending: a fast reply must not be missed
        counter = link.connection.next_counter
        wire = link.send(message)
        sent: Parsed = message
        if isinstance(message, CountedMessage):
            sent = parse_content(encode_message(message, counter))
            shown = describe(sent)
        records = [{"kind": "sent", **message_fields(sent), "text": shown,
                    "wire_bytes": len(wire), "wire_hex": wire.hex(" ")}]
        if fmt == "table":
            echo_out(f"sent {shown}  ({len(wire)} bytes on the wire)")
            if conn.verbose:
                echo_out(f"wire {wire.hex(' ')}")
        if reply_id is None:
            _emit(fmt, records)
            return ExitCode.OK
        try:
            received = await asyncio.wait_for(replied, wait)
        except TimeoutError:
            _emit(fmt, records)
            heard = (", ".join(f"{n}×{others.count(n)}" for n in sorted(set(others)))
                     or "nothing")
            raise CliError(f"{endpoint.url}: board not answering: no reply to {shown.split()[0]} "
                           f"within {wait:g} s (heard: {heard})", ExitCode.NO_ANSWER) from None
        records.append({"kind": "reply", **message_fields(received), "text": describe(received),
                        "wire_bytes": None, "wire_hex": None})
        if fmt == "table":
            echo_out(f"reply {describe(received)}")
        _emit(fmt, records)
        if isinstance(received, ParamNack):
            raise CliError(f"{endpoint.url}: the board refused: {received.reason} (PN error "
                           f"{received.error})", ExitCode.REFUSED)
        return ExitCode.OK


SEND_COLUMNS = (Column("kind", "kind"), Column("id", "id"), Column("counter", "counter"),
                Column("text", "text"), Column("wire_bytes", "wire bytes"),
                Column("wire_hex", "wire"))


def _emit(fmt: str, records: list[dict[str, Any]]) -> None:
    """JSON: ``{"sent": {...}, "reply": {...} or null}``; CSV: a line per message."""
    if fmt == "json":
        reply = records[1] if len(records) > 1 else None
        emit_document({"sent": records[0], "reply": reply})
    elif fmt == "csv":
        emit_rows(fmt, SEND_COLUMNS, records)
