"""Property tests: the asyncio Link fed arbitrary bytes through an in-memory transport never
raises, hands every decoded telemetry sample to subscribers, and settles a pending request
exactly as the request table says for the answers it decoded — never a wrong value
confirmed."""

from __future__ import annotations

import asyncio

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgalink import Connection, Telemetry, ValueMismatch
from fpgalink.aio.link import Link
from fpgalink.errors import FpgalinkError, RequestTimeout
from fpgalink.protocol import Event, ParamAck, encode_frame, encode_message
from fpgalink.testing import MemoryTransport

pytestmark = pytest.mark.timeout(120)

TRIES = 2
ASKED = 1000


def ack_frames() -> st.SearchStrategy[bytes]:
    value = st.one_of(st.just(ASKED), st.integers(0, 32760))
    type_code = st.sampled_from([1, 1, 1, 2, 3])
    ack = st.builds(lambda c, t, v: encode_frame(encode_message(ParamAck(5, 1, t, v), c)),
                    st.integers(0, 99_999), type_code, value)
    direct = st.sampled_from([b"SEP", b"SREP", b"SRDP"])
    return st.one_of(ack, direct)


stream = st.lists(st.one_of(st.binary(max_size=80), ack_frames()), max_size=30)


def expected_outcome(events: list[Event]) -> int | type[FpgalinkError]:
    """What the request table makes of the PA answers for MaxControlSignalA, in order: the
    exact value confirms; another value costs a try; out of tries (or time) after another
    value is a mismatch, after silence a timeout."""
    others = 0
    for ack in events:
        if not (isinstance(ack, ParamAck) and (ack.param_id, ack.channel) == (5, 1)):
            continue
        if ack.value_type == 1 and ack.value == ASKED:
            return ASKED
        others += 1
        if others == TRIES:
            break
    return ValueMismatch if others else RequestTimeout


def run_link(chunks: list[bytes]) -> None:
    async def main() -> None:
        transport = MemoryTransport()
        link = Link(Connection(request_timeout=0.01, request_tries=TRIES), transport)
        await link.open()
        seen: list[Event] = []
        link.add_listener(seen.append)
        sub = link.telemetry(maxsize=10_000)
        request = asyncio.ensure_future(link.set_param("MaxControlSignal", ASKED, channel="A"))
        await asyncio.sleep(0)  # let the request reach the transport
        for chunk in chunks:
            transport.feed(chunk)  # all in one go: no request timer fires in between
        expected = expected_outcome(seen)
        if isinstance(expected, int):
            assert await asyncio.wait_for(request, 1.0) == expected
        else:
            with pytest.raises(expected):
                await asyncio.wait_for(request, 1.0)
        telemetry = [e for e in seen if type(e) is Telemetry]
        assert len(sub) == len(telemetry) == link.stats.telemetry_received
        await link.close()
        assert transport.is_closing()

    asyncio.run(main())


@given(stream)
def test_link_survives_arbitrary_input_and_settles_requests_by_the_table(chunks: list[bytes]
                                                                          ) -> None:
    run_link(chunks)


def test_link_confirms_on_the_matching_echo() -> None:
    # This one can fail: the helper no longer swallows errors, so no echo means no pass.
    run_link([encode_frame(encode_message(ParamAck(5, 1, 1, ASKED), 0))])


def test_link_reports_another_value_after_the_tries() -> None:
    wrong = [encode_frame(encode_message(ParamAck(5, 1, 1, 7), c)) for c in range(TRIES)]
    run_link(wrong)
