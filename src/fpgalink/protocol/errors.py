"""Errors the protocol itself raises: for what the *caller* asked and the protocol cannot
carry. Bad input from the peer never raises; it becomes an event (see :mod:`.framing`,
:mod:`.messages`)."""

from __future__ import annotations

__all__ = ["FpgalinkError", "LocalProtocolError", "ParameterError", "UnknownParameter"]


class FpgalinkError(Exception):
    """Base of every error this package raises."""


class LocalProtocolError(FpgalinkError, ValueError):
    """We were asked to send something the protocol cannot carry (too long, bad ID, a
    non-finite reference …)."""


class ParameterError(FpgalinkError, ValueError):
    """A parameter name, channel, type or value rejected on the host before anything is sent."""


class UnknownParameter(ParameterError, KeyError):
    """No parameter has this name or id."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""
