"""Board identity end to end: ``fpgaemu serve --pty`` (the Python firmware model, and the C
core in co-simulation) asked over its pty with ``fpgalink-cli send IQ`` and with the
library's ``read_identity``; the hash the board answers is this host's. A board that does
not answer ``IQ`` (every one lost on the way: what a seed board answers) is "seed
protocol, identity unknown" and keeps working."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest

from fpgaemu.firmware import FIRMWARE_VERSION, emulated_serial
from fpgalink.aio.identity import read_identity
from fpgalink.aio.link import open_link
from fpgalink.protocol.identity import BoardIdentity, declarations_hash
from tests.support.cli import run_cli
from tests.support.firmwares import require_c_firmware
from tests.support.serving import served

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(params=["python", "c"])
def board(request: pytest.FixtureRequest) -> Iterator[str]:
    if request.param == "c":
        require_c_firmware()
    with served("--pty", "--firmware", request.param, "--seed", "3") as server:
        yield server.url


def test_the_served_board_answers_iq_with_this_hosts_hash(board: str) -> None:
    done = run_cli("send", "IQ", "--hex", "0d0c0b0a", "--reply", "IA", "--format", "json",
                   "--port", board)
    assert done.returncode == 0, done.stderr
    reply = json.loads(done.stdout)["reply"]
    assert reply["id"] == "IA"
    fields = reply["fields"]
    assert fields["nonce"] == 0x0A0B0C0D
    assert fields["declarations"] == declarations_hash()
    assert (fields["firmware_major"], fields["firmware_minor"], fields["firmware_patch"]) == \
        FIRMWARE_VERSION
    assert fields["serial"] == emulated_serial(3)


async def test_read_identity_over_the_pty(board: str) -> None:
    async with open_link(board) as link:
        identity = await read_identity(link)
    assert identity == BoardIdentity(declarations_hash(), FIRMWARE_VERSION, 0,
                                     emulated_serial(3))


async def test_a_board_without_iq_is_seed_protocol_and_still_works() -> None:
    with served("--pty", "--fault", "drop-frames=IQ:1000") as server:
        path = server.url
        unanswered = run_cli("send", "IQ", "--hex", "01000000", "--reply", "IA", "--wait",
                             "0.5", "--port", path)
        assert unanswered.returncode == 4 and "no reply to IQ" in unanswered.stderr
        got = run_cli("param", "get", "TsTimerPeriod", "--port", path)
        assert (got.returncode, got.stdout.strip()) == (0, "1"), got.stderr
        async with open_link(path) as link:
            assert await read_identity(link) is None  # SEED_PROTOCOL
            assert await link.set_param("TsTimerPeriod", 2) == 2
