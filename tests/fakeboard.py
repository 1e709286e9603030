"""A minimal scripted board on a TCP port, built from the sans-I/O Connection in board role.
For Link tests that need precise misbehaviour; end-to-end tests use the real emulator."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field

from fpgalink import (
    Alive,
    ChannelTelemetry,
    Connection,
    ParamAck,
    ParamGet,
    ParamNack,
    ParamSet,
    Role,
    Telemetry,
)


@dataclass
class FakeBoard:
    drop_first_ps: int = 0
    nack: int | None = None
    silent: bool = False
    alive_period: float = 0.05
    values: dict[tuple[int, int], int | float] = field(default_factory=dict)
    received: list[object] = field(default_factory=list)
    # Appended for the CLI tests: stream TM every tm_period while GetDataPeriodical (2) = 1,
    # and a mute board that answers nothing at all (no PA, no PN, no E).
    tm_period: float = 0.005
    mute: bool = False

    def __post_init__(self) -> None:
        self.server: asyncio.Server | None = None
        self.writers: list[asyncio.StreamWriter] = []
        self.port = 0
        self.conn = Connection(role=Role.BOARD)
        self._stream: asyncio.Task[None] | None = None

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

    def broadcast(self, data: bytes) -> None:
        for w in self.writers:
            w.write(data)

    def send_tm(self, t: int) -> None:
        ch = ChannelTelemetry(t, float(t), 0.0, 0, 0.0, 1)
        self.broadcast(self.conn.send(Telemetry(t, ch, ch)))

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.writers.append(writer)
        alive = asyncio.ensure_future(self._alive(writer))
        try:
            while data := await reader.read(4096):
                self.conn.receive_data(data)
                for event in self.conn.events():
                    self.received.append(event)
                    self._answer(event, writer)
        except (ConnectionError, OSError, asyncio.CancelledError):
            pass
        finally:
            alive.cancel()
            if writer in self.writers:  # a departed host gets no more telemetry
                self.writers.remove(writer)

    def _answer(self, event: object, writer: asyncio.StreamWriter) -> None:
        if self.mute:
            return
        if isinstance(event, ParamSet):
            if self.drop_first_ps > 0:
                self.drop_first_ps -= 1
                return
            if self.nack is not None:
                writer.write(self.conn.send(ParamNack(event.param_id, event.channel, self.nack)))
                return
            self.values[(event.param_id, event.channel)] = event.value
            if (event.param_id, event.channel) == (2, 0):
                self._set_streaming(event.value == 1)
            writer.write(self.conn.send(
                ParamAck(event.param_id, event.channel, event.value_type, event.value)
            ))
        elif isinstance(event, ParamGet):
            value = self.values.get((event.param_id, event.channel), 1)
            kind = 2 if isinstance(value, float) else 1
            writer.write(self.conn.send(ParamAck(event.param_id, event.channel, kind, value)))

    def _set_streaming(self, on: bool) -> None:
        if on and self._stream is None:
            self._stream = asyncio.ensure_future(self._telemetry())
        elif not on and self._stream is not None:
            self._stream.cancel()
            self._stream = None

    async def _telemetry(self) -> None:
        t_us = 0
        while True:
            self.send_tm(t_us)
            t_us += int(self.tm_period * 1e6)
            await asyncio.sleep(self.tm_period)

    async def _alive(self, writer: asyncio.StreamWriter) -> None:
        while True:
            if not self.silent and not self.mute:
                writer.write(self.conn.send(Alive()))
            await asyncio.sleep(self.alive_period)
