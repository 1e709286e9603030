"""``python -m fpgalink.codegen c OUTDIR``: write the C codec (see :mod:`fpgalink.codegen`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fpgalink.codegen.c import write_c


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m fpgalink.codegen",
        description="Generate the board side of the fpgalink protocol from its declarations.")
    sub = parser.add_subparsers(dest="language", required=True)
    c = sub.add_parser("c", help="freestanding C99: header, codec and a Makefile")
    c.add_argument("outdir", type=Path, help="directory to write into (created if missing)")
    args = parser.parse_args(argv)
    try:
        written = write_c(args.outdir)
    except OSError as exc:
        print(f"fpgalink.codegen: error: {args.outdir}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    for path in written:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
