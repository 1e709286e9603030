"""Both firmwares for the emulator's tests: the Python model (:mod:`fpgaemu.firmware`) and the
C core (``firmware/``, through :mod:`fpgaemu.cfirmware`).

Without a C compiler or cffi the C runs are skipped, saying why — unless
``FPGALINK_REQUIRE_CC=1`` (set by ``make test``), where that is a failure."""

from __future__ import annotations

import functools
import os
from collections.abc import Iterator

import pytest

import tests.support.emulated as emulated

FIRMWARES = ("python", "c")


@functools.cache
def c_firmware_unavailable() -> str | None:
    """Why the C firmware cannot run here, or ``None`` when it can (built on first ask)."""
    from fpgaemu.cbuild import CBuildError
    from fpgaemu.cfirmware import load_firmware

    try:
        load_firmware()
    except CBuildError as exc:
        return str(exc)
    return None


def require_c_firmware() -> None:
    """Skip (or, under ``FPGALINK_REQUIRE_CC=1``, fail) when the C firmware cannot run."""
    reason = c_firmware_unavailable()
    if reason is None:
        return
    if os.environ.get("FPGALINK_REQUIRE_CC") == "1":
        pytest.fail(f"the C firmware must run here (FPGALINK_REQUIRE_CC=1): {reason}")
    pytest.skip(f"C firmware unavailable: {reason}")


@pytest.fixture(params=FIRMWARES)
def firmware_kind(request: pytest.FixtureRequest) -> str:
    kind: str = request.param
    if kind == "c":
        require_c_firmware()
    return kind


@pytest.fixture
def each_firmware(firmware_kind: str) -> Iterator[str]:
    """Every ``Cable.make()`` in the test builds a board with this firmware."""
    before = emulated.DEFAULT_FIRMWARE
    emulated.DEFAULT_FIRMWARE = firmware_kind
    try:
        yield firmware_kind
    finally:
        emulated.DEFAULT_FIRMWARE = before
