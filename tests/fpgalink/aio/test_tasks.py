"""``cancel_and_wait``: a task this layer started is cancelled and waited for; its own
cancellation and failure are the caller's to judge, a cancellation of the caller is never
lost with them."""

from __future__ import annotations

import asyncio

import pytest

from fpgalink.aio.tasks import cancel_and_wait

TIMEOUT = 5.0


async def test_the_tasks_cancellation_is_swallowed() -> None:
    task = asyncio.ensure_future(asyncio.sleep(60))
    await asyncio.sleep(0)
    assert await cancel_and_wait(task) is None
    assert task.cancelled()


async def test_the_tasks_failure_is_returned_not_raised() -> None:
    async def fails_when_cancelled() -> None:
        try:
            await asyncio.sleep(60)
        except asyncio.CancelledError:
            raise ValueError("cleanup failed") from None

    task = asyncio.ensure_future(fails_when_cancelled())
    await asyncio.sleep(0)
    failed = await cancel_and_wait(task)
    assert isinstance(failed, ValueError)


async def test_a_cancellation_of_the_caller_while_it_waits_is_not_lost() -> None:
    """The task takes a while to end once cancelled; the caller is cancelled meanwhile (a
    Ctrl-C asyncio turns into a cancel): the caller ends cancelled, not running on, as it
    did with ``suppress(CancelledError)``."""
    ending = asyncio.Event()

    async def slow_to_end() -> None:
        try:
            await asyncio.sleep(60)
        except asyncio.CancelledError:
            await ending.wait()

    child = asyncio.ensure_future(slow_to_end())
    ran_on = False

    async def caller() -> None:
        nonlocal ran_on
        await cancel_and_wait(child)
        ran_on = True

    outer = asyncio.ensure_future(caller())
    await asyncio.sleep(0)
    await asyncio.sleep(0)
    outer.cancel()
    await asyncio.sleep(0)
    ending.set()
    with pytest.raises(asyncio.CancelledError):
        await asyncio.wait_for(outer, TIMEOUT)
    assert not ran_on
