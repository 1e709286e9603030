"""``Subscription``: a bounded queue a producer never waits on, iterated by consumers that wait
on futures of their own (not ``asyncio.Event``, which asks for the running loop, a system
call, at every wait)."""

from __future__ import annotations

import asyncio

import pytest

from fpgalink.aio import Subscription

TIMEOUT = 5.0


def _subscription(maxsize: int = 4) -> Subscription[int]:
    return Subscription(maxsize, lambda _sub: None)


async def test_a_consumer_waiting_is_woken_by_a_put_and_gets_the_item() -> None:
    sub = _subscription()
    got = asyncio.ensure_future(sub.__anext__())
    while sub.waiting == 0:
        await asyncio.sleep(0)
    assert not sub.put(7)
    assert await asyncio.wait_for(got, TIMEOUT) == 7
    assert sub.waiting == 0


async def test_cancelled_waits_leave_no_waiter_behind() -> None:
    sub = _subscription()
    for _ in range(200):
        with pytest.raises(TimeoutError):
            await asyncio.wait_for(sub.__anext__(), 0)
    assert sub.waiting == 0
    sub.put(1)
    assert await asyncio.wait_for(sub.__anext__(), TIMEOUT) == 1


async def test_one_consumer_cancelled_leaves_the_other_waiting() -> None:
    sub = _subscription()
    first = asyncio.ensure_future(sub.__anext__())
    second = asyncio.ensure_future(sub.__anext__())
    while sub.waiting < 2:
        await asyncio.sleep(0)
    first.cancel()
    with pytest.raises(asyncio.CancelledError):
        await first
    assert sub.waiting == 1
    sub.put(3)
    assert await asyncio.wait_for(second, TIMEOUT) == 3


async def test_finish_ends_every_waiting_consumer_after_the_queued_items() -> None:
    sub = _subscription()
    sub.put(1)

    async def drain() -> list[int]:
        return [item async for item in sub]

    consumers = [asyncio.ensure_future(drain()) for _ in range(2)]
    while sub.waiting < 2:
        await asyncio.sleep(0)
    sub.finish()
    results = await asyncio.wait_for(asyncio.gather(*consumers), TIMEOUT)
    assert sorted(results, key=len) == [[], [1]]


async def test_a_full_subscription_drops_its_oldest_and_counts_it() -> None:
    sub = _subscription(maxsize=2)
    assert [sub.put(i) for i in range(3)] == [False, False, True]
    assert sub.dropped == 1
    sub.finish()
    assert [item async for item in sub] == [1, 2]
