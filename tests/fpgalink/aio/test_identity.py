"""``read_identity(link)`` and the identity checks: the emulated board's identity (both
firmwares: the C core answers in co-simulation with the hash its generated header carries),
a board built from another declaration refused with one line naming both hashes, a seed
board (no ``IQ``) shown as "seed protocol, identity unknown" and still working, a silent
board failing as any request would, answers to another asker's nonce ignored."""

from __future__ import annotations

import pytest

from fpgaemu.firmware import FIRMWARE_BUILD, FIRMWARE_VERSION, emulated_serial
from fpgalink import Connection, RequestTimeout
from fpgalink.aio.identity import read_identity
from fpgalink.aio.link import Link, open_link
from fpgalink.errors import LocalProtocolError
from fpgalink.events import BoardIdentified, BoardRestarted
from fpgalink.protocol import (
    DEFAULT_FRAMING,
    Event,
    ParamSet,
    Role,
    encode_frame,
    encode_message,
)
from fpgalink.protocol.catalogue import IdentityAnswer, IdentityQuery
from fpgalink.protocol.identity import (
    SEED_PROTOCOL,
    BoardIdentity,
    IdentityMatch,
    IdentityMismatch,
    IdentityProbe,
    compare_identity,
    declarations_digest,
    declarations_hash,
    require_identity,
)
from tests.support.fakeboard import ScriptedBoard, memory_pair
from tests.support.firmwares import require_c_firmware
from tests.support.waiting import wait_until

pytestmark = pytest.mark.timeout(30)

OTHER = declarations_hash() ^ 0x0123_4567_89AB_CDEF


class IdentifiedBoard(ScriptedBoard):
    """A scripted board that answers ``IQ`` with an ``IA`` of its own making."""

    def __init__(self, declarations: int, nonce_offset: int = 0) -> None:
        super().__init__()
        self.declarations = declarations
        self.nonce_offset = nonce_offset

    def _answer(self, event: Event, now: float) -> None:
        if isinstance(event, IdentityQuery):
            # A board's connection sends the typed answer as it does PA: the catalogue says
            # who sends what (it took a generic message with the same bytes before).
            self.conn.send(IdentityAnswer((event.nonce + self.nonce_offset) % 2**32,
                                          self.declarations, 2, 0, 1, 0x1A2B3C4D, 42), now)
            return
        super()._answer(event, now)


def scripted(board: ScriptedBoard) -> Link:
    return Link(Connection(request_timeout=0.05, request_tries=3), memory_pair(board))


@pytest.mark.parametrize("firmware", ["python", "c"])
async def test_the_emulated_board_says_who_it_is(firmware: str) -> None:
    if firmware == "c":
        require_c_firmware()
    async with open_link(f"emu://?seed=5&firmware={firmware}") as link:
        identity = await read_identity(link)
    assert identity == BoardIdentity(declarations_hash(), FIRMWARE_VERSION, FIRMWARE_BUILD,
                                     emulated_serial(5))
    assert identity.digest == declarations_digest()
    assert require_identity(identity) is IdentityMatch.MATCH
    assert identity.describe() == (f"protocol {declarations_digest()}, firmware 1.1.0 "
                                   f"(build not set), serial 0x{emulated_serial(5):x}")


async def test_a_board_built_from_another_declaration_is_refused_naming_both() -> None:
    async with scripted(IdentifiedBoard(OTHER)) as link:
        identity = await read_identity(link)
    assert identity is not None and identity.declarations == OTHER
    assert identity.version == "2.0.1" and identity.build == 0x1A2B3C4D
    assert compare_identity(identity) is IdentityMatch.MISMATCH
    with pytest.raises(IdentityMismatch) as caught:
        require_identity(identity, "board L")
    message = str(caught.value)
    assert "\n" not in message and message.startswith("board L: ")
    assert f"{OTHER:016x}" in message and declarations_digest() in message
    assert (caught.value.board, caught.value.host) == (OTHER, declarations_hash())


async def test_a_seed_board_is_seed_protocol_and_keeps_working() -> None:
    # The emulated board with every IQ lost on the way: it answers as a seed board does
    # (nothing), while PG and PS are answered.
    async with open_link("emu://?fault=drop-frames=IQ:1000") as link:
        identity = await read_identity(link)
        assert identity is None and compare_identity(identity) is IdentityMatch.UNKNOWN
        assert require_identity(identity) is IdentityMatch.UNKNOWN  # not refused
        assert await link.set_param("TsTimerPeriod", 5) == 5
    assert SEED_PROTOCOL == "seed protocol, identity unknown"
    board = ScriptedBoard()  # the scripted board does not know IQ either
    async with scripted(board) as link:
        assert await read_identity(link, rounds=2) is None
    asked = [e for e in board.received if isinstance(e, IdentityQuery)]
    assert len(asked) == 2 and asked[0].nonce != asked[1].nonce


async def test_an_answer_to_another_nonce_is_not_this_boards_answer() -> None:
    async with scripted(IdentifiedBoard(declarations_hash(), nonce_offset=7)) as link:
        assert await read_identity(link, rounds=2) is None


async def test_a_silent_board_fails_as_any_request_to_it() -> None:
    async with scripted(ScriptedBoard(mute=True)) as link:
        with pytest.raises(RequestTimeout):
            await read_identity(link)


def test_the_probe_takes_a_late_answer_to_an_earlier_round() -> None:
    probe = IdentityProbe(first_nonce=2**32 - 1, rounds=3)
    first, second = probe.query(), probe.query()
    assert (first.nonce, second.nonce) == (2**32 - 1, 0)  # wraps as the u32 it is
    assert not probe.fence_answered()
    assert not probe.observe(IdentityAnswer(5, 1, 1, 1, 0, 0, 0))  # never asked
    assert probe.observe(IdentityAnswer(first.nonce, 1, 1, 1, 0, 0, 9))
    assert probe.fence_answered() and probe.identity == BoardIdentity(1, (1, 1, 0), 0, 9)
    with pytest.raises(ValueError):
        IdentityProbe(rounds=0)


# --- the sendable set from the catalogue; the link asking at open and after a restart ------


def test_each_side_sends_its_catalogued_messages_as_themselves() -> None:
    # The connection's sendable set hard-coded six typed messages: IQ went out as a generic
    # message with the same bytes, and a board could not send IA typed at all.
    host, board = Connection(baud=None), Connection(role=Role.BOARD, baud=None)
    host.send(IdentityQuery(0x0A0B0C0D), 0.0)
    board.receive_data(host.data_to_send(), 0.0)
    (query,) = [e for e in board.events() if isinstance(e, IdentityQuery)]
    assert query.nonce == 0x0A0B0C0D
    board.send(IdentityAnswer(query.nonce, 1, 1, 1, 0, 0, 7), 0.0)
    host.receive_data(board.data_to_send(), 0.0)
    assert [e.serial for e in host.events() if isinstance(e, IdentityAnswer)] == [7]
    with pytest.raises(LocalProtocolError):
        host.send(IdentityAnswer(1, 1, 1, 1, 0, 0, 0), 0.0)  # a board's message
    with pytest.raises(LocalProtocolError):
        board.send(ParamSet(1, 0, 1, 1), 0.0)  # a host's


async def test_a_link_opened_to_identify_knows_the_board_before_it_returns() -> None:
    link = open_link("emu://?seed=2", identify=True)
    said: list[BoardIdentified] = []
    link.on_event(lambda e: said.append(e) if isinstance(e, BoardIdentified) else None)
    async with link:
        assert link.identification.known
        assert link.identification.identity == BoardIdentity(declarations_hash(), FIRMWARE_VERSION,
                                              FIRMWARE_BUILD, emulated_serial(2))
        (event,) = said
        assert event.match is IdentityMatch.MATCH and event.mismatch is None
        assert event.describe() == link.identification.identity.describe()
    plain = open_link("emu://")  # not asked unless asked: no extra round trip
    async with plain:
        assert not plain.identification.known and plain.stats.bytes_sent == 0


async def test_a_link_opened_to_identify_refuses_another_declaration_and_closes() -> None:
    board = IdentifiedBoard(OTHER)
    link = Link(Connection(request_timeout=0.05, request_tries=3), memory_pair(board),
                identify=True)
    with pytest.raises(IdentityMismatch) as caught:
        await link.open()
    assert f"{OTHER:016x}" in str(caught.value) and declarations_digest() in str(caught.value)
    assert link.state.value == "closed"
    allowed = Link(Connection(request_timeout=0.05, request_tries=3),
                   memory_pair(IdentifiedBoard(OTHER)), identify=True, allow_mismatch=True)
    async with allowed:
        identity = allowed.identification.identity
        assert identity is not None and identity.declarations == OTHER
        assert compare_identity(identity) is IdentityMatch.MISMATCH


async def test_a_seed_board_opens_as_seed_protocol() -> None:
    async with Link(Connection(request_timeout=0.05, request_tries=3),
                    memory_pair(ScriptedBoard()), identify=True) as link:
        assert link.identification.known and link.identification.identity is None


async def test_a_restarted_board_is_asked_again() -> None:
    # A re-flash changes who the board is: after a restart the link asks again by itself
    # and says what the board answered.
    link = open_link("emu://?seed=4&fault=restart=1.0", identify=True)
    seen: list[Event] = []
    link.on_event(seen.append)
    async with link:
        assert link.identification.known
        await link.set_param("GetDataPeriodical", 1)  # its stopping shows the restart
        await wait_until(lambda: sum(isinstance(e, BoardIdentified) for e in seen) == 2,
                         timeout=20, what="the board asked again after its restart")
        kinds = [type(e) for e in seen if isinstance(e, BoardRestarted | BoardIdentified)]
        assert kinds[:3] == [BoardIdentified, BoardRestarted, BoardIdentified]
        assert link.identification.known and link.identification.identity is not None
        assert link.identification.identity.serial == emulated_serial(4)


# --- hostile answers (docs/reliability.md, identity rows) ------------------------------------


class HostileBoard(ScriptedBoard):
    """Answers each ``IQ`` as told: ``torn`` (its ``IA`` frame one byte short, the section's
    LEN left as it was), or ``flood`` answers to nonces it was not asked before the right
    one."""

    def __init__(self, *, torn: bool = False, flood: int = 0) -> None:
        super().__init__()
        self.torn = torn
        self.flood = flood
        self._raw: list[bytes] = []

    def receive(self, data: bytes, now: float = 0.0) -> bytes:
        reply = super().receive(data, now)
        raw, self._raw = b"".join(self._raw), []
        return reply + raw

    def _answer(self, event: Event, now: float) -> None:
        if not isinstance(event, IdentityQuery):
            super()._answer(event, now)
            return
        for n in range(self.flood):
            self.conn.send(IdentityAnswer((event.nonce + 1 + n) % 2**32, OTHER, 9, 9, 9, 9,
                                          9), now)
        answer = IdentityAnswer(event.nonce, declarations_hash(), 1, 1, 0, 0, 1)
        if self.torn:
            whole = encode_message(answer, 99)
            self._raw.append(encode_frame(whole[:-2] + whole[-1:], DEFAULT_FRAMING))
            return
        self.conn.send(answer, now)


async def test_a_torn_answer_is_counted_and_never_taken_for_one() -> None:
    async with scripted(HostileBoard(torn=True)) as link:
        # unknown: nothing it said is an IA
        assert await link.identification.identify(rounds=3) is None
        assert link.stats.malformed == 3 and link.identification.known  # each counted
        assert link.identification.identity is None
        assert await link.set_param("TsTimerPeriod", 4) == 4  # and it works


async def test_a_flood_of_answers_to_other_nonces_is_read_past() -> None:
    board = HostileBoard(flood=5_000)
    async with scripted(board) as link:
        identity = await link.identification.identify()
        assert identity is not None and identity.declarations == declarations_hash()
        assert link.connection.pending_events == 0  # nothing piled up
        # Five thousand answers with another declaration's hash and nonces never asked:
        # none of them is this board's answer, none refused the board.
        assert link.stats.messages_received > 5_000
