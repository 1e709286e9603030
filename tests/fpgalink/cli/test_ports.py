"""``ports``: the port listing with stable paths, the board's FT2232 marked, and the FTDI
latency-timer check, against a made-up sysfs and by-id directory."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from fpgalink.cli.output import CliError
from fpgalink.cli.ports import scan_ports, set_low_latency
from tests.support.cli import run_cli


def _info(device: str, vid: int | None = None, pid: int | None = None,
          location: str | None = None, serial: str | None = None,
          description: str = "n/a") -> SimpleNamespace:
    return SimpleNamespace(device=device, vid=vid, pid=pid, location=location,
                           serial_number=serial, description=description)


@pytest.fixture
def machine(tmp_path: Path) -> tuple[Path, Path, Path]:
    """A /dev with two FT2232 interfaces and a CP210x, by-id links, and sysfs."""
    dev, by_id, sysfs = tmp_path / "dev", tmp_path / "by-id", tmp_path / "sys"
    dev.mkdir()
    by_id.mkdir()
    for name, link, latency in (
        ("ttyUSB0", "usb-Digilent_Digilent_USB_Device_210328B0-if00-port0", 16),
        ("ttyUSB1", "usb-Digilent_Digilent_USB_Device_210328B0-if01-port0", 16),
        ("ttyUSB2", "usb-Silicon_Labs_CP2102-if00-port0", None),
    ):
        (dev / name).touch()
        (by_id / link).symlink_to(dev / name)
        if latency is not None:
            node = sysfs / "bus" / "usb-serial" / "devices" / name
            node.mkdir(parents=True)
            (node / "latency_timer").write_text(f"{latency}\n")
    return dev, by_id, sysfs


def test_the_boards_uart_comes_first_with_its_stable_path(
    machine: tuple[Path, Path, Path]
) -> None:
    dev, by_id, sysfs = machine
    infos = [
        _info(str(dev / "ttyUSB2"), 0x10C4, 0xEA60, "1-2:1.0", "0001", "CP2102"),
        _info(str(dev / "ttyUSB0"), 0x0403, 0x6010, "1-1:1.0", "210328B0", "Digilent USB"),
        _info(str(dev / "ttyUSB1"), 0x0403, 0x6010, "1-1:1.1", "210328B0", "Digilent USB"),
        _info("/dev/ttyS0"),
    ]
    reports = scan_ports(infos, sysfs=sysfs, by_id_dir=by_id)
    first = reports[0]
    assert first.device.endswith("ttyUSB1") and first.likely_board
    assert first.by_id is not None and first.by_id.endswith("-if01-port0")
    assert first.usb_id == "0403:6010" and first.interface == 1
    assert first.latency_timer_ms == 16 and first.slow_latency
    assert "tee" in first.fix_command() and first.fix_command().endswith("latency_timer")
    jtag = next(r for r in reports if r.device.endswith("ttyUSB0"))
    assert "JTAG" in jtag.verdict and not jtag.likely_board
    cp = next(r for r in reports if r.device.endswith("ttyUSB2"))
    assert cp.latency_timer_ms is None and cp.verdict == "USB serial"
    assert reports[-1].device == "/dev/ttyS0" and reports[-1].verdict == "not USB"


def test_interface_from_the_by_id_name_when_location_is_missing(
    machine: tuple[Path, Path, Path]
) -> None:
    dev, by_id, sysfs = machine
    (report,) = scan_ports([_info(str(dev / "ttyUSB1"), 0x0403, 0x6010)], sysfs, by_id)
    assert report.interface == 1 and report.likely_board


def test_fixing_the_latency_writes_one_millisecond(machine: tuple[Path, Path, Path]) -> None:
    dev, by_id, sysfs = machine
    (report,) = scan_ports([_info(str(dev / "ttyUSB1"), 0x0403, 0x6010, "1-1:1.1")],
                           sysfs, by_id)
    set_low_latency(report)
    (again,) = scan_ports([_info(str(dev / "ttyUSB1"), 0x0403, 0x6010, "1-1:1.1")],
                          sysfs, by_id)
    assert again.latency_timer_ms == 1 and not again.slow_latency


def test_fixing_without_permission_says_the_command(machine: tuple[Path, Path, Path]) -> None:
    dev, by_id, sysfs = machine
    (report,) = scan_ports([_info(str(dev / "ttyUSB1"), 0x0403, 0x6010, "1-1:1.1")],
                           sysfs, by_id)
    assert report.latency_path is not None
    Path(report.latency_path).unlink()
    Path(report.latency_path).mkdir()  # unwritable as a file, whoever we are
    with pytest.raises(CliError, match="cannot write"):
        set_low_latency(report)


def test_the_command_lists_what_this_machine_has() -> None:
    done = run_cli("ports", "--all", "--format", "json")
    assert done.returncode == 0, done.stderr
    reports = json.loads(done.stdout)  # one document: a list, [] when there is none
    assert isinstance(reports, list)
    for report in reports:
        assert {"device", "by_id", "usb_id", "verdict", "latency_timer_ms"} <= set(report)
    done = run_cli("ports")
    assert done.returncode == 0, done.stderr
    assert "Serial ports" in done.stdout or "no USB serial ports found" in done.stdout
