"""Ending a task this layer started: cancelled, waited for, and its end told apart from the
caller's own cancellation.

``task.cancel()`` then ``with suppress(CancelledError): await task`` swallows more than the
task's cancellation: a cancellation of the caller that arrives while it waits (a Ctrl-C
asyncio turns into one, a ``wait_for`` that ran out) is the same exception, and is lost with
it, leaving the caller running on. :func:`cancel_and_wait` swallows the task's and
re-raises the caller's (``Task.cancelling()``)."""

from __future__ import annotations

import asyncio
from typing import Any

__all__ = ["cancel_and_wait"]


async def cancel_and_wait(task: asyncio.Future[Any]) -> BaseException | None:
    """Cancel ``task`` and wait until it has ended. Returns the exception it failed with
    (``None``: it ended or was cancelled); raises ``CancelledError`` only when the caller
    itself is cancelled meanwhile."""
    task.cancel()
    try:
        await task
    except asyncio.CancelledError:
        caller = asyncio.current_task()
        if caller is not None and caller.cancelling():
            raise
        return None
    except Exception as exc:  # the task's failure, the caller's to judge
        return exc
    return None
