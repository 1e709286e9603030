"""The generated C codec, built with the test harness and loaded with cffi, for the tests that
hold it to the Python codec (tests/fpgalink/codegen). Generated straight from the
declarations into the build cache; skipped (or failed, under ``FPGALINK_REQUIRE_CC=1``)
where no C compiler is found."""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path
from typing import Any

from fpgaemu.cbuild import CBuildError, build_shared, cache_dir, load
from fpgalink.codegen import declarations_digest, write_c

HERE = Path(__file__).resolve().parent


@functools.cache
def c_codec() -> tuple[Any, Any]:
    """``(ffi, lib)``: the generated codec and the harness. Raises ``CBuildError``."""
    target = cache_dir() / f"codec-test-{declarations_digest()}"
    target.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as scratch:
        work = Path(scratch)
        write_c(work)
        generated = [p for p in work.iterdir() if p.name.startswith("fpgalink_protocol")]
        for path in generated:  # compared by text, so the build key stays put
            kept = target / path.name
            if not kept.exists() or kept.read_bytes() != path.read_bytes():
                kept.write_bytes(path.read_bytes())
    shared = build_shared("codectest",
                          [target / "fpgalink_protocol.c", HERE / "ccodec_harness.c"],
                          [HERE / "ccodec_harness.h"], [target, HERE])
    return load(shared)


@functools.cache
def why_unavailable() -> str | None:
    try:
        c_codec()
    except CBuildError as exc:
        return str(exc)
    return None
