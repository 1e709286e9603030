"""The connection options every board command takes (``--port``, ``--baud``, ``--timeout``,
``--retries``, ``-v``), and the links they open."""

from __future__ import annotations

import functools
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import click

from fpgalink.aio.link import Link, open_link
from fpgalink.cli.output import CliError, ExitCode, err_console

__all__ = [
    "EMULATOR_URL",
    "ConnectionOptions",
    "Endpoint",
    "connection_options",
    "parse_ports",
]

T = TypeVar("T")

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

    def link(self, endpoint: Endpoint, *, reconnect: bool = False,
             liveness_timeout: float | None = None) -> Link:
        """A link to ``endpoint`` (not open yet). By default a silent board must surface as
        "no answer after N tries", not as the shorter liveness timeout failing the request
        first, so liveness waits for every try."""
        if liveness_timeout is None:
            liveness_timeout = max(0.7, self.timeout * self.retries + 0.2)
        return open_link(
            endpoint.url, self.baud, name=endpoint.name, request_timeout=self.timeout,
            request_tries=self.retries, liveness_timeout=liveness_timeout,
            reconnect=reconnect,
        )


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
            click.option("--baud", type=click.IntRange(50, 20_000_000), default=1_000_000,
                         envvar="FPGALINK_BAUD", show_default=True,
                         help="Line rate (env FPGALINK_BAUD)."),
            click.option("--timeout", type=click.FloatRange(min=0, min_open=True, max=60),
                         default=0.05, show_default=True, help="Per-try request timeout, s."),
            click.option("--retries", type=click.IntRange(1, 1000), default=8,
                         show_default=True, help="Tries per request (resends included)."),
            click.option("-v", "--verbose", count=True, help="More detail (wire bytes)."),
        ]
        for option in reversed(options):
            wrapper = option(wrapper)
        return wrapper

    return decorate
