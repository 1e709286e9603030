"""Fixtures for the CLI tests: ``board`` is parametrized over transports (see
tests/support/cli.py)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

from tests.support.cli import Board, BoardThread
from tests.support.serving import served


@pytest.fixture(params=["fake", "emu", "pty"])
def board(request: pytest.FixtureRequest) -> Iterator[Board]:
    kind = request.param
    if kind == "fake":
        thread = BoardThread()
        yield Board("fake", thread.url, fake=thread.board)
        thread.close()
    elif kind == "emu":
        yield Board("emu", "emu://", has_dynamics=True, persistent=False)
    else:
        with served("--pty") as server:
            yield Board("pty", server.url, has_dynamics=True, served=server)


@pytest.fixture
def fake_board() -> Iterator[Callable[..., BoardThread]]:
    """A factory for scripted boards with chosen misbehaviour (``nack=3``, ``mute=True``)."""
    made: list[BoardThread] = []

    def make(**options: Any) -> BoardThread:
        thread = BoardThread(**options)
        made.append(thread)
        return thread

    yield make
    for thread in made:
        thread.close()
