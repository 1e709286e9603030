"""``-v``, the same for every command that talks to a board: each message a board sends
this host, as it arrives, on stderr — its name, what it says and its content bytes
(``fpgalink-cli: L < PA #00003 param_id=2 channel=0 value_type=1 value=1  [50 41 …]``);
``-vv`` adds its telemetry (1,000 lines a second per board). ``send`` also prints the
bytes it sends, and ``router`` each ``RE``/``RD`` a client passes (docs/cli.md)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import click

from fpgalink.cli.output import describe
from fpgalink.cli.session import on_messages

if TYPE_CHECKING:
    from collections.abc import Callable

    from fpgalink.aio.link import Link
    from fpgalink.events import Event
    from fpgalink.protocol import Parsed

__all__ = ["content_bytes", "log_wire"]


def content_bytes(message: Parsed) -> bytes:
    """The frame content a received message came in (what the board put between START and
    STOP, escapes undone)."""
    from fpgalink.protocol import CountedMessage, DirectCommand, Malformed, encode_message

    if isinstance(message, DirectCommand | Malformed):
        return bytes(message.content)
    assert isinstance(message, CountedMessage) or hasattr(message, "counter")
    return encode_message(message, message.counter or 0)


def log_wire(name: str, link: Link | Callable[[Callable[[Event], None]], Callable[[], None]],
             verbose: int) -> None:
    """At ``-v`` (``verbose`` ≥ 1) say each message ``link`` (or a robot board's
    ``add_listener``) receives; telemetry at ``-vv``."""
    if verbose < 1:
        return
    from fpgalink.protocol import Telemetry

    def say(message: Parsed) -> None:
        if isinstance(message, Telemetry) and verbose < 2:
            return
        click.echo(f"fpgalink-cli: {name} < {describe(message)}  "
                   f"[{content_bytes(message).hex(' ')}]", err=True)

    on_messages(link, say)
