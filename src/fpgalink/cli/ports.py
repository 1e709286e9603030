"""``ports``: every serial port the machine has, with what is needed to pick the board's and
to keep picking it: the stable ``/dev/serial/by-id/…`` path (``ttyUSB`` numbers change
between boots and plug orders), USB vendor:product, description and serial number.

The CmodA7 carries an FTDI FT2232: interface 0 is the FPGA's JTAG, interface 1 its UART.
For FTDI ports the driver's ``latency_timer`` (sysfs) decides how long the chip holds
received bytes before sending a USB packet when fewer than 62 are waiting: the default
16 ms turns 1 kHz telemetry into 16 ms bursts. Above 1 ms we warn and say how to fix it.

``--identify`` also asks the board on each likely board port, and on every port configured
(``--port``, ``FPGALINK_PORT``, the config file), who it is (docs/protocol.md §8): its
protocol declaration, firmware and serial, or "seed protocol, identity unknown". It opens
the ports, so it is asked for: a port another program has open is said to be busy, and
nothing else is sent to a board than the question and a parameter read."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import click

from fpgalink.cli.formats import Column, emit_rows, format_option
from fpgalink.cli.options import ConnectionOptions, Endpoint, connection_options
from fpgalink.cli.output import EXIT_CODES_HELP, CliError, ExitCode, echo_out
from fpgalink.cli.settings import DEFAULT

__all__ = ["PortReport", "ports", "scan_ports"]

FTDI_VID = 0x0403
FT2232_PID = 0x6010  #: FT2232C/D/H: the CmodA7's USB bridge (JTAG + UART)
BOARD_UART_INTERFACE = 1  #: FT2232 channel B, the CmodA7's UART (channel A is JTAG)
GOOD_LATENCY_MS = 1
UDEV_RULE = ('ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", '
             'ATTR{latency_timer}="1"')


@dataclass(frozen=True, slots=True)
class PortReport:
    device: str
    by_id: str | None  #: the stable path to give as --port, when udev made one
    usb_id: str | None  #: VID:PID in hex
    description: str
    serial_number: str | None
    interface: int | None  #: USB interface number of a multi-interface chip
    verdict: str  #: what this port is likely to be, for the board's purposes
    latency_timer_ms: int | None  #: FTDI only
    latency_path: str | None
    #: who the board on it said it is (``--identify``; ``None``: not asked)
    identity: str | None = None
    protocol: str | None = None  #: its declaration hash, when it answered

    @property
    def likely_board(self) -> bool:
        return self.verdict.startswith("board UART")

    @property
    def slow_latency(self) -> bool:
        return self.latency_timer_ms is not None and self.latency_timer_ms > GOOD_LATENCY_MS

    def fix_command(self) -> str:
        return f"echo {GOOD_LATENCY_MS} | sudo tee {self.latency_path}"


def _by_id_links(by_id_dir: Path) -> dict[str, str]:
    """Real device path → its by-id symlink."""
    links: dict[str, str] = {}
    try:
        entries = sorted(by_id_dir.iterdir())
    except OSError:
        return links
    for entry in entries:
        try:
            links.setdefault(os.path.realpath(entry), str(entry))
        except OSError:
            continue
    return links


def _interface_number(info: Any, by_id: str | None) -> int | None:
    # pyserial's location ends ":<config>.<interface>"; by-id names end "-ifNN-portN".
    location = getattr(info, "location", None) or ""
    if ":" in location:
        try:
            return int(location.rsplit(":", 1)[1].split(".")[-1])
        except ValueError:
            pass
    if by_id and "-if" in by_id:
        digits = by_id.rsplit("-if", 1)[1][:2]
        if digits.isdigit():
            return int(digits)
    return None


def _verdict(vid: int | None, pid: int | None, interface: int | None) -> str:
    if vid == FTDI_VID and pid == FT2232_PID:
        if interface == BOARD_UART_INTERFACE:
            return "board UART (FT2232 channel B, as on the CmodA7)"
        if interface == 0:
            return "FT2232 channel A: JTAG on the CmodA7, not its UART"
        return "FT2232: channel B (interface 1) is the CmodA7's UART"
    if vid == FTDI_VID:
        return "FTDI USB-UART"
    if vid is not None:
        return "USB serial"
    return "not USB"


def _latency(sysfs: Path, name: str) -> tuple[int | None, str | None]:
    path = sysfs / "bus" / "usb-serial" / "devices" / name / "latency_timer"
    try:
        return int(path.read_text().strip()), str(path)
    except (OSError, ValueError):
        return None, None


def scan_ports(infos: Iterable[Any], sysfs: Path = Path("/sys"),
               by_id_dir: Path = Path("/dev/serial/by-id")) -> list[PortReport]:
    """Reports for pyserial's port list (``serial.tools.list_ports.comports()``)."""
    links = _by_id_links(by_id_dir)
    reports = []
    for info in infos:
        device = str(info.device)
        by_id = links.get(os.path.realpath(device))
        vid, pid = info.vid, info.pid
        interface = _interface_number(info, by_id)
        latency, latency_path = (_latency(sysfs, Path(device).name) if vid == FTDI_VID
                                 else (None, None))
        description = info.description if info.description not in (None, "n/a") else ""
        reports.append(PortReport(
            device=device, by_id=by_id,
            usb_id=f"{vid:04x}:{pid:04x}" if vid is not None and pid is not None else None,
            description=description or "", serial_number=info.serial_number,
            interface=interface, verdict=_verdict(vid, pid, interface),
            latency_timer_ms=latency, latency_path=latency_path,
        ))
    # The likely board first, then USB ports, then the rest (legacy ttyS* last).
    return sorted(reports, key=lambda r: (not r.likely_board, r.usb_id is None, r.device))


def set_low_latency(report: PortReport) -> None:
    """Write 1 ms into the port's ``latency_timer`` (needs root or a udev rule)."""
    assert report.latency_path is not None
    try:
        Path(report.latency_path).write_text(f"{GOOD_LATENCY_MS}\n")
    except PermissionError:
        raise CliError(f"{report.device}: not permitted to set the latency timer; run: "
                       f"{report.fix_command()}", ExitCode.FAILURE) from None
    except OSError as exc:
        raise CliError(f"{report.latency_path}: cannot write: {exc.strerror or exc}",
                       ExitCode.FAILURE) from None


@click.command(epilog=EXIT_CODES_HELP)
@click.option("--all", "show_all", is_flag=True,
              help="Also list ports that are not USB (legacy ttyS*, most of them absent).")
@format_option
@click.option("--fix-latency", is_flag=True,
              help=f"Set every FTDI port's latency timer to {GOOD_LATENCY_MS} ms (needs "
                   "permission to write sysfs; lasts until the device is replugged).")
@click.option("--identify", is_flag=True,
              help="Ask the board on each likely board port and on every configured port "
                   "(--port, FPGALINK_PORT, the config file) who it is: protocol, firmware, "
                   "serial (opens those ports).")
@connection_options(multi=True, announce=False)
def ports(show_all: bool, fmt: str, fix_latency: bool, identify: bool,
          conn: ConnectionOptions) -> int:
    """List serial ports, mark the board's USB-UART, check its latency timer.

    Give the by-id path as --port (or in fpgalink.toml): it names the same board after a
    reboot or replug, where /dev/ttyUSB numbers do not. With --identify, each board found
    or configured is asked who it is.
    """
    from serial.tools import list_ports

    reports = [r for r in scan_ports(list_ports.comports())
               if show_all or r.usb_id is not None]
    if fix_latency:
        for report in reports:
            if report.slow_latency:
                set_low_latency(report)
                click.echo(f"fpgalink-cli: {report.device}: latency timer "
                           f"{report.latency_timer_ms} → {GOOD_LATENCY_MS} ms", err=True)
        reports = [r for r in scan_ports(list_ports.comports())
                   if show_all or r.usb_id is not None]
    if identify:
        reports = identified(reports, conn)
    if fmt != "table":
        columns = PORT_COLUMNS + (IDENTITY_COLUMNS if identify else ())
        emit_rows(fmt, columns, [asdict(r) for r in reports])
        return ExitCode.OK
    if not reports:
        echo_out("no USB serial ports found" + ("" if show_all else
                                               " (--all lists the others)"))
        return ExitCode.OK
    _print_table(reports)
    for report in reports:
        if report.slow_latency:
            click.echo(
                f"warning: {report.device}: FTDI latency timer is {report.latency_timer_ms} ms: "
                f"1 kHz telemetry arrives in {report.latency_timer_ms} ms bursts. Fix now: "
                f"{report.fix_command()} (or fpgalink-cli ports --fix-latency); for every "
                f"plug-in, a udev rule: {UDEV_RULE}", err=True)
    return ExitCode.OK


#: Every field of a report; the table leaves out, first to last, what matters least for
#: picking the port when the terminal is narrow. The stable path is never cut short.
PORT_COLUMNS = (
    Column("device", "port"),
    Column("by_id", "stable path (give as --port)"),
    Column("usb_id", "VID:PID", drop=3),
    Column("description", "description", drop=4),
    Column("serial_number", "serial", drop=2),
    Column("interface", "interface", drop=6),
    Column("verdict", "what it is", drop=1),
    Column("latency_timer_ms", "latency ms", justify="right"),
    Column("latency_path", "latency_timer file", drop=7),
)


#: ``--identify``'s columns.
IDENTITY_COLUMNS = (Column("identity", "identity (protocol, firmware, serial)"),
                    Column("protocol", "protocol", drop=8))


def identified(reports: list[PortReport], conn: ConnectionOptions) -> list[PortReport]:
    """``reports`` with each likely board port and every configured port asked who its
    board is; a configured port that is not among them (a pty, a TCP board) is added."""
    from fpgalink.cli.session import run

    known = {os.path.realpath(r.device): r for r in reports}
    endpoints: dict[str, Endpoint] = {
        r.device: Endpoint(r.device, r.by_id or r.device) for r in reports if r.likely_board}
    if conn.settings.sources["port"] != DEFAULT:
        for endpoint in conn.endpoints:
            device = os.path.realpath(endpoint.url) if "://" not in endpoint.url \
                else endpoint.url
            report = known.get(device)
            if report is None:
                report = PortReport(endpoint.url, None, None, f"configured as {endpoint.name}",
                                    None, None, "configured port", None, None)
                reports.append(report)
                known[device] = report
            endpoints[report.device] = endpoint
    answers = run(_ask_all(conn, endpoints))
    return [dataclasses.replace(r, identity=answers[r.device][0], protocol=answers[r.device][1])
            if r.device in answers else r for r in reports]


async def _ask_all(conn: ConnectionOptions, endpoints: dict[str, Endpoint]
                   ) -> dict[str, tuple[str, str | None]]:
    import asyncio

    found = await asyncio.gather(*(_ask(conn, e) for e in endpoints.values()))
    return dict(zip(endpoints, found, strict=True))


async def _ask(conn: ConnectionOptions, endpoint: Endpoint) -> tuple[str, str | None]:
    """(one line, its declaration hash or ``None``) for the board on ``endpoint``: who it
    said it is, or why it could not be asked (busy, not answering, …)."""
    from fpgalink.cli.output import classify
    from fpgalink.errors import FpgalinkError
    from fpgalink.protocol import describe_identity

    try:
        async with conn.link(endpoint, identify=False) as link:
            identity = await link.identification.identify(allow_mismatch=True)
    except FpgalinkError as exc:
        return f"not asked: {classify(exc).message}", None
    return describe_identity(identity), None if identity is None else identity.digest


def _print_table(reports: list[PortReport]) -> None:
    rows = []
    for r in reports:
        latency = "" if r.latency_timer_ms is None else f"{r.latency_timer_ms}"
        if r.slow_latency:
            latency = f"{latency} (slow)"
        rows.append({**asdict(r), "by_id": r.by_id or "-", "usb_id": r.usb_id or "-",
                     "description": r.description or "-", "serial_number":
                     r.serial_number or "-", "latency_timer_ms": latency or "-",
                     "verdict": r.verdict})
    columns = [c for c in PORT_COLUMNS if c.key not in ("interface", "latency_path")]
    if any(r.identity is not None for r in reports):
        columns.append(IDENTITY_COLUMNS[0])
        for row in rows:
            row["identity"] = row["identity"] or "-"
    emit_rows("table", columns, rows, title="Serial ports")
