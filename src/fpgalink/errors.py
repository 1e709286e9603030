"""Exception types. Bad input *from the peer* never raises: it becomes a counted event
(see :mod:`fpgalink.connection`). These are for what the caller asked for and did not get."""

from __future__ import annotations

__all__ = [
    "BoardLost",
    "FpgalinkError",
    "LinkClosed",
    "LocalProtocolError",
    "ParameterError",
    "ParameterRefused",
    "PortError",
    "RequestTimeout",
    "UnknownParameter",
]


class FpgalinkError(Exception):
    """Base of every error this package raises."""


class LocalProtocolError(FpgalinkError, ValueError):
    """We were asked to send something the protocol cannot carry (too long, bad ID, ...)."""


class ParameterError(FpgalinkError, ValueError):
    """A parameter name, channel, type or value rejected on the host before anything is sent."""


class UnknownParameter(ParameterError, KeyError):
    """No parameter has this name or id."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class ParameterRefused(FpgalinkError):
    """The board answered ``PN``: the refusal is final, resending would not help."""

    def __init__(self, name: str, channel: int, reason: str, code: int) -> None:
        self.name = name
        self.channel = channel
        self.reason = reason
        self.code = code
        label = {1: "A", 2: "B"}.get(channel, str(channel))
        where = "" if channel == 0 else f" on channel {label}"
        super().__init__(f"board refused {name}{where}: {reason} (PN error {code})")


class RequestTimeout(FpgalinkError, TimeoutError):
    """No matching answer after every allowed try."""

    def __init__(self, what: str, tries: int, timeout_s: float) -> None:
        self.what = what
        self.tries = tries
        self.timeout_s = timeout_s
        super().__init__(f"{what}: no answer after {tries} tries ({timeout_s:g} s each)")


class LinkClosed(FpgalinkError, ConnectionError):
    """The link was closed (by us) while the request was pending."""


class BoardLost(FpgalinkError, ConnectionError):
    """The board stopped answering (no ``E`` heartbeat) or its port vanished."""


class PortError(FpgalinkError, OSError):
    """The serial port or socket could not be opened or failed."""
