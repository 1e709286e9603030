"""The router running: each board's port opened and served to its clients over TCP on
loopback and on pty slots, the ready lines said once every board is served, the ports kept
open until the router is stopped (:func:`serve_routes`)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fpgalink.errors import PortError
from fpgalink.ports import ready_line, usable_url
from fpgalink.router.clients import PtyClient, TcpClient
from fpgalink.router.route import BoardRoute

__all__ = ["HOST", "serve_routes"]

#: Loopback only: the router is for the clients on this machine (a remote client would
#: reach a motor controller over the network without any authentication).
HOST = "127.0.0.1"


@dataclass
class _Served:
    """Where one board is offered: its TCP server and its pty slots."""

    route: BoardRoute
    server: asyncio.Server | None = None
    ptys: list[PtyClient] = field(default_factory=list)


async def serve_routes(routes: Sequence[BoardRoute], stop: asyncio.Event,
                       ready: Callable[[str], None], *, first_port: int = 0, ptys: int = 0,
                       links: Sequence[tuple[str, Path]] = (), reconnect: bool = True
                       ) -> list[BoardRoute]:
    """Open each board's port and offer it over TCP on :data:`HOST` (``first_port`` for the
    first board, the next one more; 0: free ports), on ``ptys`` pty slots a board and on a
    slot behind each of ``links`` (``(board name, path)``); then hand each ready line to
    ``ready`` and serve until ``stop`` is set. Returns the routes whose port went away for
    good (with ``reconnect`` off), which stops the router too; everything is closed on the
    way out, an ``RD`` sent for each controller still connected.

    :class:`~fpgalink.errors.PortError` when a port cannot be opened, listened on or a pty
    made; :class:`~fpgalink.ports.LinkError` when a link cannot be made."""
    served = [_Served(route) for route in routes]
    try:
        for index, entry in enumerate(served):
            await _offer(entry, first_port + index if first_port else 0, ptys, links)
        for entry in served:
            assert entry.server is not None
            port = entry.server.sockets[0].getsockname()[1]
            ready(ready_line(entry.route.name, usable_url(HOST, port)))
            for slot in entry.ptys:
                ready(ready_line(entry.route.name, slot.shown))
                slot.start()
        kept = [asyncio.ensure_future(route.keep_open(reconnect)) for route in routes]
        waited: list[asyncio.Future[Any]] = [asyncio.ensure_future(stop.wait()), *kept]
        done, _ = await asyncio.wait(waited, return_when=asyncio.FIRST_COMPLETED)
        for future in waited:
            future.cancel()
        gone = [r for r, f in zip(routes, kept, strict=True) if f in done]
        for route in gone:
            route.say(f"board {route.name}: its port {route.url} closed: the router stops "
                      "(--no-reconnect)")
        return gone
    finally:
        await _close(served)


async def _offer(entry: _Served, port: int, ptys: int,
                 links: Sequence[tuple[str, Path]]) -> None:
    route = entry.route
    await route.open()
    try:
        entry.server = await asyncio.get_running_loop().create_server(
            lambda: TcpClient(route), HOST, port)
    except OSError as exc:
        raise PortError(f"board {route.name}: cannot listen on {HOST}:{port}: "
                        f"{exc.strerror or exc}") from None
    try:
        for _ in range(ptys):
            entry.ptys.append(PtyClient(route))
        for name, path in links:
            if name == route.name:
                entry.ptys.append(PtyClient(route, path))
    except OSError as exc:
        raise PortError(f"board {route.name}: cannot make a pty: {exc.strerror or exc}"
                        ) from None


async def _close(served: list[_Served]) -> None:
    for entry in served:
        if entry.server is not None:
            entry.server.close()
        entry.route.close()
        for client in list(entry.route.clients):
            if isinstance(client, TcpClient):
                client.close()
        for slot in entry.ptys:
            slot.close()
    for entry in served:
        if entry.route.board is not None:
            entry.route.board.close()
        if entry.server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(entry.server.wait_closed(), 1.0)
