"""Exception types. Bad input *from the peer* never raises: it becomes a counted event
(see :mod:`fpgalink.events`). These are for what the caller asked for and did not get."""

from __future__ import annotations

from fpgalink.protocol.catalogue import NackReason
from fpgalink.protocol.errors import (
    FpgalinkError,
    LocalProtocolError,
    ParameterError,
    UnknownParameter,
)
from fpgalink.protocol.exitcodes import ExitCode, NotInstalled
from fpgalink.protocol.identity import IdentityMismatch

__all__ = [
    "BoardLost",
    "FpgalinkError",
    "IdentityMismatch",
    "LineBusy",
    "LinkClosed",
    "LocalProtocolError",
    "ParameterError",
    "ParameterRefused",
    "PortError",
    "RequestTimeout",
    "UnknownParameter",
    "ValueMismatch",
    "WireCrcMismatchError",
    "exit_code",
]


def _channel_label(channel: int) -> str:
    return {1: "A", 2: "B"}.get(channel, str(channel))


class ParameterRefused(FpgalinkError):
    """The board answered ``PN``: the refusal is final, resending would not help."""

    def __init__(self, name: str, channel: int, reason: str, code: int) -> None:
        self.name = name
        self.channel = channel
        self.reason = reason
        self.code = code
        where = "" if channel == 0 else f" on channel {_channel_label(channel)}"
        if code == NackReason.NOT_CONTROLLER:  # fpgalink-cli router's, not the board's
            super().__init__(f"{name}{where} refused by the router: {reason} (PN error "
                             f"{code})")
            return
        super().__init__(f"board refused {name}{where}: {reason} (PN error {code})")


class RequestTimeout(FpgalinkError, TimeoutError):
    """No answer at all after every allowed try (``why``: what the link knows of it)."""

    def __init__(self, what: str, tries: int, timeout_s: float, why: str = "") -> None:
        self.what = what
        self.tries = tries
        self.timeout_s = timeout_s
        super().__init__(f"{what}: no answer after {tries} tries ({timeout_s:g} s each)"
                         + (f": {why}" if why else ""))


class WireCrcMismatchError(RequestTimeout):
    """No answer, and the board's frames arrive in the other wire-CRC mode than this host's
    (:class:`~fpgalink.events.WireCrcMismatch`): the board drops this host's requests (its
    CRC on, ``board_crc``) or this host its answers (the reverse). Connect in its mode."""

    def __init__(self, what: str, tries: int, timeout_s: float, board_crc: bool) -> None:
        self.board_crc = board_crc
        why = ("the board sends CRC-16 frames and this host has the wire CRC off" if board_crc
               else "the board sends frames without the wire CRC and this host has it on")
        super().__init__(what, tries, timeout_s, why)


class ValueMismatch(FpgalinkError):
    """The board kept answering, but with another value (or value type) than the one sent:
    nothing was confirmed. ``answered`` is the last value it reported in force."""

    def __init__(self, what: str, tries: int, asked: int | float | None,
                 answered: int | float, answered_type: int) -> None:
        self.what = what
        self.tries = tries
        self.asked = asked  #: ``None`` for a get (the answer had the wrong type code)
        self.answered = answered
        self.answered_type = answered_type
        kind = {1: "integer", 2: "float"}.get(answered_type, f"type code {answered_type}")
        wanted = f"asked {asked!r}, " if asked is not None else ""
        super().__init__(
            f"{what}: the board answered with another value after {tries} tries: "
            f"{wanted}the board reports {answered!r} ({kind})"
        )


class LineBusy(FpgalinkError):
    """Not sent: the line to the board is backed up (more is waiting to be written than it
    carries in a few hundred milliseconds). Nothing was queued; try again when it drains."""


class LinkClosed(FpgalinkError, ConnectionError):
    """The link was closed (by us) while the request was pending."""


class BoardLost(FpgalinkError, ConnectionError):
    """The board stopped answering (no ``E`` heartbeat) or its port vanished."""


class PortError(FpgalinkError, OSError):
    """The serial port or socket could not be opened or failed."""


def exit_code(exc: BaseException) -> ExitCode:
    """The exit code of every console script for a library error (the CLI, the ROS 2 node):
    the one table of :mod:`fpgalink.protocol.exitcodes`."""
    if isinstance(exc, ParameterError | LocalProtocolError):
        return ExitCode.BAD_INPUT
    if isinstance(exc, ParameterRefused | ValueMismatch):
        return ExitCode.REFUSED
    if isinstance(exc, IdentityMismatch):
        return ExitCode.MISMATCH
    if isinstance(exc, RequestTimeout | BoardLost):
        return ExitCode.NO_ANSWER
    if isinstance(exc, PortError):
        # What the opener said: a part it needs is not installed (cffi for
        # emu://?firmware=c), or the URL's content is not its scheme's (emu://bogus: the
        # opener's ValueError); otherwise the port itself is missing, busy or failed.
        if isinstance(exc.__cause__, NotInstalled):
            return ExitCode.NOT_INSTALLED
        if isinstance(exc.__cause__, ValueError | TypeError):
            return ExitCode.BAD_INPUT
        return ExitCode.PORT
    return ExitCode.FAILURE
