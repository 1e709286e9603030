"""Property tests: the asyncio Link fed arbitrary bytes through a fake transport never raises,
hands every decoded telemetry sample to subscribers, and resolves a pending request only
with the board's matching answer or an error."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

import fpgalink.aio.link as link_module
from fpgalink import Telemetry, open_link
from fpgalink._framing import encode_frame
from fpgalink.catalogue import ParamAck, encode_message
from fpgalink.errors import FpgalinkError

pytestmark = pytest.mark.timeout(120)


class FakeTransport(asyncio.Transport):
    def __init__(self) -> None:
        super().__init__()
        self.written = bytearray()
        self.closed = False
        self.protocol: Any = None

    def write(self, data: bytes | bytearray | memoryview) -> None:
        self.written += data

    def is_closing(self) -> bool:
        return self.closed

    def close(self) -> None:
        # As every asyncio transport does: the protocol hears connection_lost soon after.
        if not self.closed and self.protocol is not None:
            asyncio.get_running_loop().call_soon(self.protocol.connection_lost, None)
        self.closed = True


def valid_frames() -> st.SearchStrategy[bytes]:
    ack = st.builds(lambda c, v: encode_frame(encode_message(ParamAck(5, 1, 1, v), c)),
                    st.integers(0, 99_999), st.integers(0, 32760))
    direct = st.sampled_from([b"SEP", b"SREP", b"SRDP"])
    return st.one_of(ack, direct)


stream = st.lists(st.one_of(st.binary(max_size=80), valid_frames()), max_size=30)


def run_link(chunks: list[bytes]) -> None:
    async def main() -> None:
        transport = FakeTransport()
        protocols: list[Any] = []

        async def fake_connect(url: str, baud: int, factory: Any) -> Any:
            protocol = factory()
            protocols.append(protocol)
            transport.protocol = protocol
            return transport, protocol

        original = link_module.connect
        link_module.connect = fake_connect
        try:
            link = open_link("fake://", request_timeout=0.001, request_tries=2)
            await link.open()
        finally:
            link_module.connect = original
        seen: list[Any] = []
        link.add_listener(seen.append)
        sub = link.telemetry(maxsize=10_000)
        request = asyncio.ensure_future(link.set_param("MaxControlSignal", 1000, channel="A"))
        await asyncio.sleep(0)  # let the request reach the transport
        for chunk in chunks:
            protocols[0].data_received(chunk)
        try:
            value = await asyncio.wait_for(request, 1.0)
            # Confirmed only by an echo of exactly the requested value.
            assert value == 1000
        except FpgalinkError:
            pass
        telemetry = [e for e in seen if type(e) is Telemetry]
        assert len(sub) == len(telemetry) == link.stats.telemetry_received
        await link.close()
        assert transport.closed

    asyncio.run(main())


@given(stream)
def test_link_survives_arbitrary_input(chunks: list[bytes]) -> None:
    run_link(chunks)


def test_link_confirms_on_the_matching_echo() -> None:
    run_link([encode_frame(encode_message(ParamAck(5, 1, 1, 1000), 0))])
