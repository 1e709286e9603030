"""What the CLI shows and how it fails: exit codes, one-line errors, consoles, values and
messages as text."""

from __future__ import annotations

import math
import os
import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import fields
from typing import TYPE_CHECKING, Any

import click

from fpgalink.protocol.exitcodes import ExitCode, exit_codes_help

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
    "console",
    "describe",
    "echo_out",
    "format_value",
    "message_fields",
    "message_id",
    "note",
    "number",
    "quiet_stdout",
    "stdout_errors",
    "table_console",
    "wire_crc_advice",
    "write_out",
]


#: A word that is a number (``-0.3``, ``-1e-3``, ``-inf``), never an option.
_NUMBER = re.compile(r"^-(\d|\.\d|inf|nan)", re.IGNORECASE)


#: Every console script's exit codes, declared once (fpgalink.protocol.exitcodes).
EXIT_CODES_HELP = exit_codes_help()


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
    """Library error → the CLI's message and exit code (:func:`fpgalink.errors.exit_code`;
    a recording's errors name their file); a request unanswered while the board's frames came
    in the other wire-CRC mode says how to connect."""
    from fpgalink.errors import ParameterRefused, WireCrcMismatchError, exit_code
    from fpgalink.protocol import NackReason
    from fpgalink.recording import OutputBusy, OutputRefused, RecordingError

    if isinstance(exc, RecordingError):  # its message names the file: no prefix
        if isinstance(exc, OutputRefused):
            return CliError(f"{exc}; --force replaces it" if exc.exists else str(exc),
                            ExitCode.BAD_INPUT)
        return CliError(str(exc), ExitCode.PORT if isinstance(exc, OutputBusy)
                        else ExitCode.FAILURE)
    code = exit_code(exc)
    prefix = f"{where}: " if where else ""
    if isinstance(exc, WireCrcMismatchError):
        return CliError(f"{prefix}{wire_crc_advice(exc.board_crc)} ({exc.what}: no answer)",
                        code)
    if code is ExitCode.NO_ANSWER:
        return CliError(f"{prefix}board not answering: {exc}", code)
    if code in (ExitCode.REFUSED, ExitCode.FAILURE):
        hint = ("; run it after that client, or watch with --passive"
                if isinstance(exc, ParameterRefused) and exc.code == NackReason.NOT_CONTROLLER
                else "")
        return CliError(f"{prefix}{exc}{hint}", code)
    return CliError(str(exc), code)


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


@contextmanager
def stdout_errors() -> Iterator[None]:
    """Around a write to stdout, the one rule for its errors: a write error (a full disk
    behind a redirect) is one line and exit 1; a reader that went away (``| head``) goes up
    as BrokenPipeError, which the entry point ends quietly."""
    try:
        yield
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise CliError(f"cannot write to stdout: {exc.strerror or exc}", ExitCode.FAILURE
                       ) from None


def write_out(text: str) -> None:
    """``text`` on stdout, flushed (pipes see it at once), under :func:`stdout_errors`."""
    with stdout_errors():
        sys.stdout.write(text)
        sys.stdout.flush()


def echo_out(text: str = "") -> None:
    """A line on stdout (:func:`write_out`)."""
    write_out(text + "\n")


def quiet_stdout() -> None:
    """The reader of our stdout went away (``| head``): send the rest to /dev/null so the
    interpreter's final flush does not print a traceback."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def console(*, stderr: bool = False, **options: Any) -> Console:
    """A rich console that prints text as it is: no markup, no emoji codes, no highlighting.
    Everything the CLI shows may hold what a user or a dependency wrote (a file name, a
    scenario's name, an error's hint such as ``pip install 'fpgalink[physics]'``), and rich
    would take ``[physics]`` for a style and drop it. Every console the CLI prints through
    is made here. A reader that goes away (``| head -1``) is a BrokenPipeError, which the
    entry point ends with a quiet exit 0, as for every other write (rich's own console
    would exit 1)."""
    from rich.console import Console

    class PipeConsole(Console):
        def on_broken_pipe(self) -> None:
            raise BrokenPipeError

    return PipeConsole(stderr=stderr, markup=False, emoji=False, highlight=False, **options)


def table_console() -> Console:
    """stdout for tables: a terminal's width, or wide enough not to cut names in a pipe."""
    return console(soft_wrap=False) if sys.stdout.isatty() else console(width=200)
