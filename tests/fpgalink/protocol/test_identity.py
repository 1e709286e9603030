"""The identity pair in the catalogue and the declaration hash: ``IQ``/``IA`` encode and parse
back exactly (any field values, any counter) and through the construct layout; a wrong
shape is malformed, never a crash; the hash covers what it says (a layout, a parameter's
range, a code) and is the one the generated C carries."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgalink.codegen import generate_c
from fpgalink.protocol import LocalProtocolError, Malformed, MessageId, encode_message
from fpgalink.protocol import identity as identity_module
from fpgalink.protocol import params as params_module
from fpgalink.protocol.catalogue import (
    BODIES,
    IdentityAnswer,
    IdentityQuery,
    content_length,
    layout,
)
from fpgalink.protocol.codec import parse_content
from fpgalink.protocol.identity import BoardIdentity, declarations_digest, declarations_hash
from fpgalink.protocol.messages import Role

u16, u32, u64 = (st.integers(0, 2**bits - 1) for bits in (16, 32, 64))
answers = st.builds(IdentityAnswer, u32, u64, u16, u16, u16, u32, u64)


@given(st.one_of(st.builds(IdentityQuery, u32), answers), st.integers(0, 99_999))
def test_the_pair_encodes_and_parses_back(message: IdentityQuery | IdentityAnswer,
                                          counter: int) -> None:
    content = encode_message(message, counter)
    assert len(content) == content_length(message.msg_id)
    assert parse_content(content) == dataclasses.replace(message, counter=counter)
    # the construct description reads the same fields
    parsed = layout(message.msg_id).parse(content[9:-1])
    assert {k: v for k, v in parsed.items() if not k.startswith("_")} == {
        f.name: getattr(message, f.name) for f in dataclasses.fields(message)
        if f.name != "counter"}


def test_the_pair_is_declared_with_its_senders() -> None:
    assert MessageId.IQ.sender is Role.HOST and MessageId.IA.sender is Role.BOARD
    assert content_length(MessageId.IQ) == 14 and content_length(MessageId.IA) == 40
    with pytest.raises(LocalProtocolError):
        encode_message(IdentityAnswer(0, 2**64, 0, 0, 0, 0, 0), 0)  # does not fit a u64


@pytest.mark.parametrize("content", [b"IA00001{\x04\x01\x02\x03\x04}", b"IQ00001", b"IQ00001{"])
def test_a_wrong_shape_is_malformed(content: bytes) -> None:
    assert isinstance(parse_content(content), Malformed)


def test_the_generated_c_carries_the_same_hash() -> None:
    header = next(f.text for f in generate_c() if f.name.endswith(".h"))
    assert f"#define FL_DECLARATIONS_HASH UINT64_C(0x{declarations_digest()})" in header
    assert declarations_hash() == int(declarations_digest(), 16) < 2**64
    from fpgalink.codegen import declarations_digest as codegen_digest

    assert codegen_digest() == declarations_digest()


@pytest.fixture
def fresh_hash() -> object:
    identity_module.declarations_digest.cache_clear()
    yield
    identity_module.declarations_digest.cache_clear()


@pytest.mark.usefixtures("fresh_hash")
def test_the_hash_changes_with_a_layout(monkeypatch: pytest.MonkeyPatch) -> None:
    before = declarations_digest()
    identity_module.declarations_digest.cache_clear()
    monkeypatch.setitem(BODIES, MessageId.IQ, (("nonce", "H", "a narrower nonce"),))
    assert declarations_digest() != before


@pytest.mark.usefixtures("fresh_hash")
def test_the_hash_changes_with_a_parameters_range(monkeypatch: pytest.MonkeyPatch) -> None:
    before = declarations_digest()
    identity_module.declarations_digest.cache_clear()
    changed = tuple(dataclasses.replace(p, maximum=500) if p.name == "TsTimerPeriod" else p
                    for p in params_module.PARAMETERS)
    monkeypatch.setattr(identity_module, "PARAMETERS", changed)
    assert declarations_digest() != before


def test_a_board_identity_reads_its_answer() -> None:
    answer = IdentityAnswer(9, 0xABC, 1, 2, 3, 0x1A2B3C4D, 0x1234)
    identity = BoardIdentity.from_answer(answer)
    assert identity == BoardIdentity(0xABC, (1, 2, 3), 0x1A2B3C4D, 0x1234)
    assert identity.describe() == ("protocol 0000000000000abc, firmware 1.2.3 "
                                   "(build 1a2b3c4d), serial 0x1234")
