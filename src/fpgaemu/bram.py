"""``blk_mem_gen``: the 32-bit-wide block RAM between the UART logic and the MicroBlaze.

The fabric side (``uartcommand``, ``uartsend``) moves bytes; the processor side sees 32-bit
words over AXI. Bytes pack into words little-endian (byte address 4·k + j is bits 8·j..8·j+7
of word k), as on the little-endian MicroBlaze, so a word read of what the hardware wrote
byte by byte gives what the firmware expects. Storage is one ``bytearray`` in byte-address
order, which *is* that packing, so byte and word accesses need no conversion table.
"""

from __future__ import annotations

from typing import Final

__all__ = ["BRAM_BYTES", "BlockRam"]

#: Both message RAMs of the seed's design: two 200-byte halves.
BRAM_BYTES: Final = 400


class BlockRam:
    """A 32-bit block RAM of ``size`` bytes (a multiple of 4)."""

    __slots__ = ("_mem", "name", "size")

    def __init__(self, size: int = BRAM_BYTES, name: str = "blk_mem_gen") -> None:
        if size <= 0 or size % 4:
            raise ValueError(f"block RAM size must be a positive multiple of 4, got {size}")
        self.size = size
        self.name = name
        self._mem = bytearray(size)

    @property
    def words(self) -> int:
        return self.size // 4

    # --- processor side: 32-bit words over AXI ---------------------------------------------

    def read_word(self, index: int) -> int:
        self._check(4 * index, 4)
        return int.from_bytes(self._mem[4 * index : 4 * index + 4], "little")

    def write_word(self, index: int, value: int) -> None:
        self._check(4 * index, 4)
        if not 0 <= value <= 0xFFFF_FFFF:
            raise ValueError(f"{value!r} is not a 32-bit word")
        self._mem[4 * index : 4 * index + 4] = value.to_bytes(4, "little")

    # --- fabric side: bytes -----------------------------------------------------------------

    def write_byte(self, address: int, value: int) -> None:
        self._check(address, 1)
        self._mem[address] = value

    def write_bytes(self, address: int, data: bytes | bytearray | memoryview) -> None:
        """A run of consecutive byte writes, done in one step (the result is the same)."""
        end = address + len(data)
        if address < 0 or end > self.size:  # _check, written out: a few calls every ms
            self._check(address, len(data))
        self._mem[address:end] = data

    def read_bytes(self, address: int, length: int) -> bytes:
        end = address + length
        if address < 0 or length < 0 or end > self.size:
            self._check(address, length)
        return bytes(self._mem[address:end])

    def _check(self, address: int, length: int) -> None:
        if address < 0 or length < 0 or address + length > self.size:
            raise IndexError(
                f"{self.name}: access of {length} bytes at {address} is outside 0..{self.size}"
            )

    def __repr__(self) -> str:
        return f"<BlockRam {self.name} {self.size} bytes>"
