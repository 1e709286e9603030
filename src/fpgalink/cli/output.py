"""What the CLI shows and how it fails: exit codes, one-line errors, consoles, values and
messages as text."""

from __future__ import annotations

import math
import os
import re
import sys
from dataclasses import fields
from enum import IntEnum
from typing import TYPE_CHECKING, Any

import click

if TYPE_CHECKING:  # the library and rich load with the first command that needs them
    from rich.console import Console

    from fpgalink.errors import FpgalinkError
    from fpgalink.protocol import ParamType, Parsed

__all__ = [
    "EXIT_CODES_HELP",
    "CliError",
    "ExitCode",
    "FiniteRange",
    "SignedNumbers",
    "classify",
    "describe",
    "echo_out",
    "format_value",
    "message_fields",
    "message_id",
    "note",
    "number",
    "quiet_stdout",
    "table_console",
    "wire_crc_advice",
    "write_out",
]


#: A word that is a number (``-0.3``, ``-1e-3``, ``-inf``), never an option.
_NUMBER = re.compile(r"^-(\d|\.\d|inf|nan)", re.IGNORECASE)


class ExitCode(IntEnum):
    OK = 0
    FAILURE = 1  #: anything not covered below
    BAD_INPUT = 2  #: usage, unknown parameter, value out of range or of the wrong type
    REFUSED = 3  #: the board answered PN (or another value than the one sent)
    NO_ANSWER = 4  #: the board did not answer after the configured tries, or went silent
    PORT = 5  #: the port is missing, busy or failed
    TIMEOUT = 6  #: a goal was not reached in time (goto); the robot was stopped
    #: a fault stopped the robot or the step: a board went silent, restarted, disabled itself
    #: (its watchdog: this host stalled) or its telemetry stopped; or the deadman lapsed
    STOPPED = 7
    INTERRUPTED = 130  #: Ctrl-C (128 + SIGINT), after a clean stop


EXIT_CODES_HELP = (
    "Exit codes: 0 ok; 1 other failure; 2 bad input (usage, unknown parameter, value out of "
    "range or of the wrong type; nothing sent); 3 board refused (PN) or confirmed another "
    "value; 4 board not answering; 5 port missing or busy; 6 goal not reached in time; 7 "
    "stopped by a fault (a board silent, restarted, disabled by its watchdog, its telemetry "
    "stopped; the deadman); 130 interrupted (Ctrl-C), 143 terminated (SIGTERM), each "
    "after a clean stop."
)


class FiniteRange(click.FloatRange):
    """A float option that is a real number in range: click's ``FloatRange`` lets ``nan``
    through (every comparison with it is false) and ``inf`` when no maximum is set."""

    name = "float range"

    def convert(self, value: Any, param: click.Parameter | None,
                ctx: click.Context | None) -> Any:
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


def note(text: str) -> None:
    """One line of information on stderr, so stdout stays clean for pipes."""
    click.echo(f"fpgalink-cli: {text}", err=True)


class CliError(click.ClickException):
    """A user-facing failure: one line on stderr, a documented exit code, no traceback."""

    def __init__(self, message: str, code: ExitCode = ExitCode.FAILURE) -> None:
        # One line, whatever the library message looked like.
        super().__init__(" ".join(message.split()))
        # click declares exit_code on the class; each error carries its own.
        setattr(self, "exit_code", int(code))  # noqa: B010

    def show(self, file: Any = None) -> None:
        click.echo(f"fpgalink-cli: error: {self.format_message()}", err=True)


def classify(exc: FpgalinkError, where: str = "") -> CliError:
    """Library error → the CLI's message and exit code."""
    from fpgalink.errors import (
        BoardLost,
        LocalProtocolError,
        ParameterError,
        ParameterRefused,
        PortError,
        RequestTimeout,
        ValueMismatch,
        WireCrcMismatchError,
    )

    prefix = f"{where}: " if where else ""
    if isinstance(exc, WireCrcMismatchError):
        return CliError(f"{prefix}{wire_crc_advice(exc.board_crc)} ({exc.what}: no answer)",
                        ExitCode.NO_ANSWER)
    if isinstance(exc, ParameterError | LocalProtocolError):
        return CliError(str(exc), ExitCode.BAD_INPUT)
    if isinstance(exc, ParameterRefused | ValueMismatch):
        return CliError(f"{prefix}{exc}", ExitCode.REFUSED)
    if isinstance(exc, RequestTimeout | BoardLost):
        return CliError(f"{prefix}board not answering: {exc}", ExitCode.NO_ANSWER)
    if isinstance(exc, PortError):
        return CliError(str(exc), ExitCode.PORT)
    return CliError(f"{prefix}{exc}", ExitCode.FAILURE)


def wire_crc_advice(board_crc: bool) -> str:
    """What to do about a board whose frames come in the other wire-CRC mode."""
    if board_crc:
        return ("the board sends CRC-16 frames; connect with the CRC on (--wire-crc, or "
                "FPGALINK_WIRE_CRC=1), or switch the board's off (param set WireCrc 0)")
    return ("the board sends frames without the wire CRC; connect with the CRC off (leave "
            "out --wire-crc)")


def format_value(value: int | float, kind: ParamType | None = None) -> str:
    """A parameter value as the shortest text that means the stored value."""
    from fpgalink.protocol.paramfile import format_value as shortest

    return shortest(value, kind)


def number(value: int | float, kind: ParamType | None = None) -> int | float:
    """A value for JSON: an int as it is; a float as the shortest decimal that means the
    stored value (a float32 0.2 is 0.2, not 0.20000000298023224)."""
    if isinstance(value, int):  # bool is an int too
        return value
    if not math.isfinite(value):
        return value
    return float(format_value(value, kind))


class SignedNumbers(click.Command):
    """A command whose arguments and option values may be negative numbers as written
    (``goto -0.3 0``, ``param set IncSenzCountDirectionA -1``): a word that reads as a
    number is never taken for an option, while a misspelt option is still an error."""

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        known = {name for param in self.get_params(ctx) if isinstance(param, click.Option)
                 for name in (*param.opts, *param.secondary_opts)}
        shorts = {name[1:] for name in known if len(name) == 2 and name[0] == "-"}
        for word in args:
            if word == "--":
                break
            if _NUMBER.match(word) or not word.startswith("-") or word == "-":
                continue
            name = word.split("=", 1)[0]
            if name in known or (not word.startswith("--") and word[1] in shorts):
                continue
            raise click.NoSuchOption(name, possibilities=sorted(known), ctx=ctx)
        ctx.ignore_unknown_options = True
        return super().parse_args(ctx, args)


def message_id(message: Parsed) -> str:
    """The two-letter ID of a received message (``E`` for the heartbeat)."""
    from fpgalink.protocol import Malformed

    if isinstance(message, Malformed):
        return message.content[:2].decode("ascii", "replace")
    msg_id = message.msg_id
    return msg_id if isinstance(msg_id, str) else msg_id.decode("ascii", "replace")


def message_fields(message: Parsed) -> dict[str, Any]:
    """A message as JSON has it: ``id``, ``counter`` (``null`` for a direct command) and
    its fields by name (a generic counted message's body as ``items``)."""
    from fpgalink.protocol import CountedMessage, DirectCommand, Malformed, Text

    counter = getattr(message, "counter", None)
    document: dict[str, Any] = {"id": message_id(message), "counter": counter}
    if isinstance(message, DirectCommand):
        document["id"] = message.content.decode("ascii", "replace")
    elif isinstance(message, Malformed):
        document["fields"] = {"reason": message.reason.value, "content_hex": message.content.hex()}
    elif isinstance(message, CountedMessage):
        document["fields"] = {"items": [
            {"text": item.data.decode("utf-8", "backslashreplace")} if isinstance(item, Text)
            else {"hex": item.data.hex()} for item in message.items]}
    else:
        document["fields"] = {f.name: getattr(message, f.name) for f in fields(message)
                              if f.name != "counter"}
    return document


def describe(message: Parsed) -> str:
    """One line for a received (or about-to-be-sent) message."""
    from fpgalink.protocol import CountedMessage, DirectCommand, Malformed, Text

    if isinstance(message, DirectCommand):
        return message.content.decode("ascii", "replace")
    if isinstance(message, Malformed):
        return f"malformed ({message.reason.value}): {message.content!r}"
    counter = message.counter
    head = f"{message_id(message)} #{counter:05d}" if counter is not None else message_id(message)
    if isinstance(message, CountedMessage):
        parts = [
            f"text {item.data.decode('utf-8', 'backslashreplace')!r}" if isinstance(item, Text)
            else f"bin[{len(item.data)}] {item.data.hex(' ')}"
            for item in message.items
        ]
        return " ".join([head, *parts])
    shown = [
        f"{f.name}={getattr(message, f.name)!r}" for f in fields(message) if f.name != "counter"
    ]
    return " ".join([head, *shown])


def write_out(text: str) -> None:
    """``text`` on stdout, flushed (pipes see it at once). A write error (a full disk
    behind a redirect) is one line and exit 1; a reader that went away (``| head``) goes up
    as BrokenPipeError, which the entry point ends quietly."""
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise CliError(f"cannot write to stdout: {exc.strerror or exc}", ExitCode.FAILURE
                       ) from None


def echo_out(text: str = "") -> None:
    """A line on stdout (:func:`write_out`)."""
    write_out(text + "\n")


def quiet_stdout() -> None:
    """The reader of our stdout went away (``| head``): send the rest to /dev/null so the
    interpreter's final flush does not print a traceback."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def table_console() -> Console:
    """stdout for tables: a terminal's width, or wide enough not to cut names in a pipe."""
    from rich.console import Console

    return Console(soft_wrap=False) if sys.stdout.isatty() else Console(width=200)
