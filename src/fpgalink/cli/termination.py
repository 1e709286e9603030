"""SIGTERM as an exception raised where the program waits: a long command (a campaign) ends
its workers and says so, instead of dying where the signal landed.

    previous = signal.signal(signal.SIGTERM, on_sigterm)
    try:
        ...
    except Terminated:
        ...  # one line, exit 143
"""

from __future__ import annotations

import asyncio

__all__ = ["Terminated", "on_sigterm"]


class Terminated(SystemExit):
    """SIGTERM, raised where the command waits. Not an Exception: a campaign's scenario
    running in this process (``--jobs 1``) reports the exceptions it meets as its failure,
    and this must end the campaign instead, as Ctrl-C does. A SystemExit, because a scenario
    spends most of its time in the event loop's callbacks (the emulator's, the link's), and
    asyncio lets only SystemExit and KeyboardInterrupt out of a callback: any other
    exception is logged and the loop runs on (a SIGTERM was taken for a callback's error
    and the campaign went on)."""


def on_sigterm(signum: int, frame: object) -> None:
    """The SIGTERM handler: :class:`Terminated` at once, or, while an event loop runs in
    this thread, from a callback of the loop's own."""
    try:
        loop = asyncio.get_running_loop()
    except RuntimeError:
        raise Terminated from None
    # Raised between two callbacks, not wherever the signal landed. Landing inside the
    # loop's own bookkeeping (a future set, the wakeup of the task awaiting it not yet
    # scheduled) it left that task asleep for ever, and the loop ran the scenario on instead
    # of ending (1 SIGTERM in about 40).
    loop.call_soon_threadsafe(_raise_terminated)


def _raise_terminated() -> None:
    raise Terminated
