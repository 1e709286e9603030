"""Message throughput of the whole stack, side by side with pymavlink (issue 7).

A thin wrapper: the measuring code lives in ``fpgalink._bench`` so that ``fpgalink-cli bench``
runs exactly the same thing. ``python benchmarks/throughput.py [--quick] [--reps N]
[--window S] [--output PATH]``; results go to ``benchmarks/results/throughput.json``.
See ``fpgalink-cli bench --help`` for the options.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from fpgalink.cli.bench import bench

RESULTS = Path(__file__).resolve().parent / "results" / "throughput.json"


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not any(a == "--output" or a.startswith("--output=") for a in args):
        # Wherever it is run from, the script's results land beside the other benchmarks'.
        args += ["--output", str(RESULTS)]
    bench.main(args=args, prog_name="throughput.py", standalone_mode=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
