"""Code for the board's side, generated from the one declaration of the protocol.

``python -m fpgalink.codegen c OUTDIR`` (also ``fpgalink-cli codegen c OUTDIR``) writes a
freestanding C99 codec — the message IDs, the parameter table, the packed little-endian
layouts of ``PS PG PA PN RV TM``, framing, a byte-at-a-time deframer with the hardware's
semantics, the encoders and decoders of every message and the optional wire CRC — from
:mod:`fpgalink.protocol`, the same declarations the Python codec runs on. See
``docs/firmware.md``.

This is a tool of ``fpgalink``: it imports ``fpgalink.protocol`` and nothing else of the
library; the emulator uses its output as a program's output, never by import.
"""

from __future__ import annotations

from fpgalink.codegen.c import GeneratedFile, declarations_digest, generate_c, write_c

__all__ = ["GeneratedFile", "declarations_digest", "generate_c", "write_c"]
