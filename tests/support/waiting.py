"""Waiting on a condition, never on the clock alone: poll until ``predicate()`` holds, fail
with ``what`` when ``timeout`` passes first. One implementation for async and sync tests."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

__all__ = ["wait_until", "wait_until_sync"]

#: How often a condition is polled. Short enough to add little latency, long enough that a
#: busy poll does not compete with what it waits for.
POLL_S = 0.005


async def wait_until(predicate: Callable[[], object], timeout: float = 10.0,
                     what: str = "condition") -> None:
    """Return once ``predicate()`` is true; ``AssertionError`` naming ``what`` after
    ``timeout`` seconds."""
    deadline = asyncio.get_running_loop().time() + timeout
    while not predicate():
        if asyncio.get_running_loop().time() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        await asyncio.sleep(POLL_S)


def wait_until_sync(predicate: Callable[[], object], timeout: float = 10.0,
                    what: str = "condition") -> None:
    """:func:`wait_until` for code outside an event loop (threads, subprocesses)."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(POLL_S)
