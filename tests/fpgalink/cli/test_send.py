"""``send`` end to end: counted messages, catalogued bodies, direct commands, replies."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from fpgalink.protocol import CountedMessage, Disable, ParamGet, Text
from tests.support.cli import Board, BoardThread, run_cli

pytestmark = pytest.mark.timeout(60)


def test_counted_message_items_in_command_line_order(
    fake_board: Callable[..., BoardThread], tmp_path: Path
) -> None:
    fake = fake_board()
    blob = tmp_path / "blob.bin"
    blob.write_bytes(b"\x00SP\\")  # framing bytes inside: escaped on the wire
    done = run_cli("send", "zz", "--text", "hi", "--hex", "01:02", "--text", "yo",
                   "--bin-file", str(blob), "-v", "--port", fake.url)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0].startswith("sent ZZ #00000 text 'hi' bin[2] 01 02 text 'yo' bin[4]")
    wire = bytes.fromhex(lines[1].removeprefix("wire "))
    assert wire.startswith(b"SZZ00000hi{\x02\x01\x02}yo{\x04\x00\\S\\P\\\\}P")
    received = [m for m in fake.board.received if isinstance(m, CountedMessage)]
    assert received and received[0].msg_id == "ZZ"
    assert received[0].items[0] == Text(b"hi")


def test_catalogued_body_is_decoded_and_reply_printed(board: Board) -> None:
    done = run_cli("send", "PG", "--hex", "0100", "--reply", "PA", "--wait", "2",
                   "--port", board.url)
    assert done.returncode == 0, done.stderr
    sent, reply = done.stdout.splitlines()
    assert "param_id=1 channel=0" in sent
    assert reply.startswith("reply PA #") and "param_id=1" in reply
    if board.fake is not None:
        assert any(isinstance(m, ParamGet) for m in board.fake.received)


def test_direct_command(fake_board: Callable[..., BoardThread]) -> None:
    fake = fake_board()
    done = run_cli("send", "RD", "-v", "--port", fake.url)
    assert done.returncode == 0, done.stderr
    assert "wire 53 52 44 50" in done.stdout  # SRDP
    assert any(isinstance(m, Disable) for m in fake.board.received)
