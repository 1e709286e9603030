"""Scripted boards with chosen misbehaviour, built from the sans-I/O ``Connection`` in board
role: :class:`ScriptedBoard` answers bytes with bytes (use it behind a
:class:`~fpgalink.testing.MemoryTransport`), :class:`FakeBoard` serves one on a TCP port for
tests that need a real socket (the CLI). End-to-end tests use the real emulator instead."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass, field

from fpgalink import Connection, Role, UnknownParameter
from fpgalink.protocol import (
    Alive,
    ChannelTelemetry,
    Event,
    Message,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    Telemetry,
    lookup,
)
from fpgalink.testing import MemoryTransport

__all__ = ["FakeBoard", "ScriptedBoard", "memory_pair"]

#: Turns a ``PS`` into the ``PA`` a misbehaving board answers with.
Echo = Callable[[ParamSet], ParamAck]


@dataclass
class ScriptedBoard:
    """Answers ``PS``/``PG`` from a value table (``PA``), or refuses them all (``nack``), or
    loses the first few ``PS`` (``drop_first_ps``), or applies the next few and loses their
    ``PA`` (``drop_first_pa``), or answers every ``PS`` through ``echo`` (a wrong value,
    another type code …), or says nothing at all (``mute``)."""

    drop_first_ps: int = 0
    drop_first_pa: int = 0
    nack: int | None = None
    mute: bool = False
    echo: Echo | None = None
    values: dict[tuple[int, int], int | float] = field(default_factory=dict)
    #: the speed every TM reports (default: t_us as a float); NaN to test non-finite data
    speed: float | None = None
    received: list[Event] = field(default_factory=list)
    conn: Connection = field(default_factory=lambda: Connection(role=Role.BOARD, baud=None))

    def receive(self, data: bytes, now: float = 0.0) -> bytes:
        """Bytes from the host → the bytes the board answers with."""
        self.conn.receive_data(data, now)
        for event in self.conn.events():
            self.received.append(event)
            self._answer(event, now)
        return self.conn.data_to_send()

    def send(self, message: Message | Alive, now: float = 0.0) -> bytes:
        self.conn.send(message, now)
        return self.conn.data_to_send()

    def telemetry(self, t_us: int) -> bytes:
        speed = float(t_us) if self.speed is None else self.speed
        ch = ChannelTelemetry(t_us, speed, 0.0, 0, 0.0, 1)
        return self.send(Telemetry(t_us, ch, ch))

    def alive(self) -> bytes:
        return b"" if self.mute else self.send(Alive())

    def _answer(self, event: Event, now: float) -> None:
        if self.mute:
            return
        if isinstance(event, ParamSet):
            if self.drop_first_ps > 0:
                self.drop_first_ps -= 1
                return
            if self.nack is not None:
                self.conn.send(ParamNack(event.param_id, event.channel, self.nack), now)
                return
            if self.echo is not None:
                self.conn.send(self.echo(event), now)
                return
            self.values[(event.param_id, event.channel)] = event.value
            if self.drop_first_pa > 0:
                self.drop_first_pa -= 1
                return
            self.conn.send(
                ParamAck(event.param_id, event.channel, event.value_type, event.value), now
            )
        elif isinstance(event, ParamGet):
            if self.nack is not None:
                self.conn.send(ParamNack(event.param_id, event.channel, self.nack), now)
                return
            try:
                param = lookup(event.param_id)
            except UnknownParameter:
                self.conn.send(ParamNack(event.param_id, event.channel, 1), now)
                return
            value = self.values.get((event.param_id, event.channel), param.default)
            self.conn.send(ParamAck(event.param_id, event.channel, int(param.type), value), now)


def memory_pair(board: ScriptedBoard) -> MemoryTransport:
    """A transport whose far end is ``board``: what the link writes is answered on the next
    loop iteration, as a real port's reply would arrive later."""
    transport = MemoryTransport()

    def on_write(data: bytes) -> None:
        reply = board.receive(data)
        if reply:
            asyncio.get_running_loop().call_soon(transport.feed, reply)

    transport.on_write = on_write
    return transport


@dataclass
class FakeBoard:
    """A :class:`ScriptedBoard` on a TCP port, with an ``E`` heartbeat and, while
    ``GetDataPeriodical`` is 1, ``TM`` every ``tm_period``. ``silent`` stops the heartbeat
    (the board still answers), ``mute`` stops everything."""

    script: ScriptedBoard = field(default_factory=ScriptedBoard)
    silent: bool = False
    alive_period: float = 0.05
    tm_period: float = 0.005

    def __post_init__(self) -> None:
        self.server: asyncio.Server | None = None
        self.writers: list[asyncio.StreamWriter] = []
        self.port = 0
        self._stream: asyncio.Task[None] | None = None

    @property
    def received(self) -> list[Event]:
        return self.script.received

    async def start(self, port: int = 0) -> str:
        self.server = await asyncio.start_server(self._client, "127.0.0.1", port)
        self.port = self.server.sockets[0].getsockname()[1]
        return f"socket://127.0.0.1:{self.port}"

    async def stop(self) -> None:
        if self._stream is not None:
            self._stream.cancel()
            self._stream = None
        if self.server is not None:
            self.server.close()
            for w in self.writers:
                w.transport.abort()
            await self.server.wait_closed()
            self.server = None
        self.writers.clear()

    async def vanish(self) -> None:
        """Fall silent as a board that lost power with the port still open: no heartbeat,
        no telemetry, no answers."""
        self.silent = True
        self.script.mute = True
        self._set_streaming(False)

    def broadcast(self, data: bytes) -> None:
        for w in self.writers:
            w.write(data)

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.writers.append(writer)
        alive = asyncio.ensure_future(self._alive(writer))
        try:
            while data := await reader.read(4096):
                reply = self.script.receive(data)
                if reply:
                    writer.write(reply)
                streaming = self.script.values.get((2, 0)) == 1
                self._set_streaming(streaming and not self.script.mute)
        except (ConnectionError, OSError, asyncio.CancelledError):
            pass
        finally:
            alive.cancel()
            if writer in self.writers:  # a departed host gets no more telemetry
                self.writers.remove(writer)

    def _set_streaming(self, on: bool) -> None:
        if on and self._stream is None:
            self._stream = asyncio.ensure_future(self._telemetry())
        elif not on and self._stream is not None:
            self._stream.cancel()
            self._stream = None

    async def _telemetry(self) -> None:
        t_us = 0
        while True:
            self.broadcast(self.script.telemetry(t_us))
            t_us += int(self.tm_period * 1e6)
            await asyncio.sleep(self.tm_period)

    async def _alive(self, writer: asyncio.StreamWriter) -> None:
        while True:
            if not self.silent:
                writer.write(self.script.alive())
            await asyncio.sleep(self.alive_period)
