"""Block RAM: little-endian byte/word packing, bounds."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fpgaemu.bram import BlockRam


def test_bytes_pack_little_endian_into_words() -> None:
    ram = BlockRam()
    assert ram.size == 400 and ram.words == 100
    ram.write_bytes(4, b"\x01\x02\x03\x04")
    assert ram.read_word(1) == 0x04030201
    ram.write_word(2, 0xAABBCCDD)
    assert ram.read_bytes(8, 4) == b"\xdd\xcc\xbb\xaa"
    ram.write_byte(9, 0x11)
    assert ram.read_word(2) == 0xAABB11DD


def test_bounds() -> None:
    ram = BlockRam()
    with pytest.raises(IndexError):
        ram.read_word(100)
    with pytest.raises(IndexError):
        ram.write_bytes(398, b"abc")
    with pytest.raises(ValueError):
        ram.write_word(0, 1 << 32)
    with pytest.raises(ValueError):
        BlockRam(10)


ops = st.one_of(
    st.tuples(st.just("byte"), st.integers(0, 399), st.integers(0, 255)),
    st.tuples(st.just("word"), st.integers(0, 99), st.integers(0, 2**32 - 1)),
)


@given(st.lists(ops, max_size=60))
def test_against_a_dict_of_bytes(sequence: list[tuple[str, int, int]]) -> None:
    ram = BlockRam()
    ref = dict.fromkeys(range(400), 0)
    for kind, where, value in sequence:
        if kind == "byte":
            ram.write_byte(where, value)
            ref[where] = value
        else:
            ram.write_word(where, value)
            for j in range(4):
                ref[4 * where + j] = (value >> (8 * j)) & 0xFF
    for k in range(100):
        assert ram.read_word(k) == sum(ref[4 * k + j] << (8 * j) for j in range(4))
