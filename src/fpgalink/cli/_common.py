"""What every command shares: exit codes, the connection options, error mapping, the
asyncio runner, a link that lets the CLI observe every received message, value formatting."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import re
import signal
import sys
from collections.abc import Awaitable, Callable, Coroutine
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, TypeVar

import click
from rich.console import Console

from fpgalink._messages import CountedMessage, DirectCommand, Malformed
from fpgalink.aio.link import Link
from fpgalink.catalogue import (
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    Parsed,
    References,
    Telemetry,
)
from fpgalink.errors import (
    BoardLost,
    FpgalinkError,
    LocalProtocolError,
    ParameterError,
    ParameterRefused,
    PortError,
    RequestTimeout,
)
from fpgalink.params import ParamType, float32

__all__ = [
    "EXIT_CODES_HELP",
    "CliError",
    "ConnectionOptions",
    "Endpoint",
    "ExitCode",
    "TappedLink",
    "connection_options",
    "err_console",
    "format_value",
    "install_stop_signals",
    "run",
]

T = TypeVar("T")


class ExitCode(IntEnum):
    OK = 0
    FAILURE = 1  #: anything not covered below
    BAD_INPUT = 2  #: usage, unknown parameter, value out of range or of the wrong type
    REFUSED = 3  #: the board answered PN
    NO_ANSWER = 4  #: the board did not answer after the configured tries, or went silent
    PORT = 5  #: the port is missing, busy or failed
    INTERRUPTED = 130  #: Ctrl-C (128 + SIGINT), after a clean stop


EXIT_CODES_HELP = (
    "Exit codes: 0 ok; 1 other failure; 2 bad input (usage, unknown parameter, value out of "
    "range or of the wrong type; nothing sent); 3 board refused (PN); 4 board not answering; "
    "5 port missing or busy; 130 interrupted (Ctrl-C)."
)

#: Diagnostics go to stderr so stdout stays clean for pipes.
err_console = Console(stderr=True, highlight=False)


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
    prefix = f"{where}: " if where else ""
    if isinstance(exc, ParameterError | LocalProtocolError):
        return CliError(str(exc), ExitCode.BAD_INPUT)
    if isinstance(exc, ParameterRefused):
        return CliError(f"{prefix}{exc}", ExitCode.REFUSED)
    if isinstance(exc, RequestTimeout):
        return CliError(f"{prefix}board not answering: {exc}", ExitCode.NO_ANSWER)
    if isinstance(exc, BoardLost):
        return CliError(f"{prefix}board not answering: {exc}", ExitCode.NO_ANSWER)
    if isinstance(exc, PortError):
        return CliError(str(exc), ExitCode.PORT)
    return CliError(f"{prefix}{exc}", ExitCode.FAILURE)


# --- ports ------------------------------------------------------------------------------------

_NAMED = re.compile(r"^([A-Za-z][A-Za-z0-9_-]*)=(.+)$")
EMULATOR_URL = "emu://"


@dataclass(frozen=True, slots=True)
class Endpoint:
    name: str  #: ``L``/``R`` when given as ``--port L=URL``; ``0``, ``1``… otherwise
    url: str


def parse_ports(values: tuple[str, ...]) -> tuple[Endpoint, ...]:
    """``--port URL`` or ``--port NAME=URL`` (repeatable). A name is letters, digits, ``_`` and
    ``-`` before the first ``=`` — so ``emu://?seed=3`` is a URL, not a name."""
    endpoints: list[Endpoint] = []
    for index, value in enumerate(values):
        match = _NAMED.match(value)
        name, url = (match.group(1), match.group(2)) if match else (str(index), value)
        if not url.strip():
            raise CliError(f"--port {value!r}: empty port", ExitCode.BAD_INPUT)
        endpoints.append(Endpoint(name, url.strip()))
    names = [e.name for e in endpoints]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise CliError(f"--port: board name {duplicates[0]!r} given twice", ExitCode.BAD_INPUT)
    return tuple(endpoints)


@dataclass(frozen=True, slots=True)
class ConnectionOptions:
    endpoints: tuple[Endpoint, ...]
    baud: int
    timeout: float  #: per-try request timeout, s
    retries: int  #: request tries
    verbose: int

    @property
    def single(self) -> Endpoint:
        if len(self.endpoints) != 1:
            raise CliError(
                "this command talks to one board; give --port once", ExitCode.BAD_INPUT
            )
        return self.endpoints[0]

    def link(self, endpoint: Endpoint, **options: Any) -> TappedLink:
        # A silent board must surface as "no answer after N tries", not as the shorter
        # liveness timeout failing the request first, so liveness waits for every try.
        liveness = max(0.7, self.timeout * self.retries + 0.2)
        settings: dict[str, Any] = {
            "baud": self.baud,
            "request_timeout": self.timeout,
            "request_tries": self.retries,
            "liveness_timeout": liveness,
            "reconnect": False,
            "name": endpoint.url,
        }
        settings.update(options)
        return TappedLink(endpoint.url, **settings)


def connection_options(*, multi: bool = False) -> Callable[[Callable[..., T]], Callable[..., T]]:
    """Add --port/--baud/--timeout/--retries/-v to a command; it receives ``conn``."""
    port_help = (
        "Board port: a device path, socket://HOST:PORT or emu://. "
        + ("Repeat as NAME=URL for several boards (--port L=... --port R=...). " if multi else "")
        + "Env FPGALINK_PORT. Default: the built-in emulator."
    )

    def decorate(func: Callable[..., T]) -> Callable[..., T]:
        @functools.wraps(func)
        def wrapper(
            *args: Any, ports: tuple[str, ...], baud: int, timeout: float, retries: int,
            verbose: int, **kwargs: Any,
        ) -> T:
            endpoints = parse_ports(ports)
            if not endpoints:
                err_console.print(
                    f"fpgalink-cli: no --port given (nor FPGALINK_PORT): using the built-in "
                    f"emulator {EMULATOR_URL}", soft_wrap=True,
                )
                endpoints = (Endpoint("0", EMULATOR_URL),)
            conn = ConnectionOptions(endpoints, baud, timeout, retries, verbose)
            if not multi:
                conn.single  # noqa: B018 - validates: one board only
            return func(*args, conn=conn, **kwargs)

        options = [
            click.option("--port", "ports", multiple=True, envvar="FPGALINK_PORT",
                         metavar="[NAME=]URL" if multi else "URL", help=port_help),
            click.option("--baud", type=click.IntRange(min=1), default=1_000_000,
                         envvar="FPGALINK_BAUD", show_default=True,
                         help="Line rate (env FPGALINK_BAUD)."),
            click.option("--timeout", type=click.FloatRange(min=0, min_open=True), default=0.05,
                         show_default=True, help="Per-try request timeout, s."),
            click.option("--retries", type=click.IntRange(1, 1000), default=8,
                         show_default=True, help="Tries per request (resends included)."),
            click.option("-v", "--verbose", count=True, help="More detail (wire bytes)."),
        ]
        for option in reversed(options):
            wrapper = option(wrapper)
        return wrapper

    return decorate


# --- running ----------------------------------------------------------------------------------


def run(coro: Coroutine[Any, Any, T], where: str = "") -> T:
    """Run one command's coroutine; library errors become :class:`CliError`."""
    try:
        return asyncio.run(coro)
    except FpgalinkError as exc:
        raise classify(exc, where) from None


def install_stop_signals(stop: asyncio.Event) -> list[signal.Signals]:
    """SIGINT/SIGTERM set ``stop`` so a long command can close its files and say goodbye;
    returns the signals that were hooked (and will report which one fired via ``stop``)."""
    loop = asyncio.get_running_loop()
    hooked: list[signal.Signals] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, functools.partial(_on_signal, stop, sig))
            hooked.append(sig)
        except (NotImplementedError, RuntimeError):  # pragma: no cover - not on Unix
            pass
    return hooked


def _on_signal(stop: asyncio.Event, sig: signal.Signals) -> None:
    stop.signal = sig  # type: ignore[attr-defined]
    stop.set()


def stop_exit_code(stop: asyncio.Event) -> ExitCode | int:
    sig = getattr(stop, "signal", None)
    if sig is None:
        return ExitCode.OK
    return 128 + int(sig)


async def wait_or_stop(stop: asyncio.Event, timeout: float | None) -> None:
    """Wait for ``stop`` or ``timeout`` seconds, whichever first (``None``: only ``stop``)."""
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(stop.wait(), timeout)


# --- observing every received message ---------------------------------------------------------

Tap = Callable[[Parsed], None]


class TappedLink(Link):
    """A :class:`Link` that also hands every received message to observers (``send --reply``
    and ``record`` need ``PA`` echoes, unknown IDs and ``E``, not only telemetry), through
    the link's public listener hook."""

    def __init__(self, url: str, **options: Any) -> None:
        super().__init__(url, **options)
        self._taps: list[Tap] = []
        self.add_listener(self._tap)

    def add_tap(self, tap: Tap) -> None:
        self._taps.append(tap)

    def remove_tap(self, tap: Tap) -> None:
        self._taps.remove(tap)

    def _tap(self, event: Any) -> None:
        if self._taps and isinstance(event, _RECEIVED_MESSAGES):
            for tap in list(self._taps):
                tap(event)


_RECEIVED_MESSAGES = (ParamSet, ParamGet, ParamAck, ParamNack, References, Telemetry,
                      CountedMessage, DirectCommand, Malformed)


def message_id(message: Parsed) -> str:
    """The two-letter ID of a received message (``E`` for the heartbeat)."""
    msg_id = getattr(message, "msg_id", None)
    if isinstance(msg_id, bytes):
        return msg_id.decode("ascii", "replace")
    if isinstance(msg_id, str):
        return msg_id
    content = getattr(message, "content", b"")
    return content.decode("ascii", "replace") if isinstance(content, bytes) else "?"


# --- values -----------------------------------------------------------------------------------


def format_value(value: int | float, kind: ParamType | None = None) -> str:
    """A parameter value as the shortest text that means the same stored value: floats are
    float32 on the board, so ``7.11`` prints as ``7.11``, not ``7.110000133514404``."""
    if isinstance(value, bool):
        return str(int(value))
    if isinstance(value, int) and kind is not ParamType.FLOAT:
        return str(value)
    number = float(value)
    if number != number or number in (float("inf"), float("-inf")):
        return str(number)
    if kind is ParamType.INT and number.is_integer():
        return str(int(number))
    stored = float32(number)
    for digits in range(1, 10):
        text = f"{stored:.{digits}g}"
        if float32(float(text)) == stored:
            break
    # repr() of the same decimal gives fixed notation where Python would (520.0, not
    # 5.2e+02) and keeps it a float to the eye and to TOML (7 → 7.0).
    return repr(float(text))


async def gather_all(*aws: Awaitable[T]) -> list[T]:
    """``asyncio.gather`` that cancels the siblings when one fails."""
    tasks = [asyncio.ensure_future(a) for a in aws]
    try:
        return list(await asyncio.gather(*tasks))
    except BaseException:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        raise


def echo_out(text: str = "") -> None:
    """A line on stdout, flushed (pipes see it at once)."""
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def quiet_stdout() -> None:
    """The reader of our stdout went away (``| head``): send the rest to /dev/null so the
    interpreter's final flush does not print a traceback."""
    import os

    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def table_console() -> Console:
    """stdout for tables: a terminal's width, or wide enough not to cut names in a pipe."""
    return Console(soft_wrap=False) if sys.stdout.isatty() else Console(width=200)
