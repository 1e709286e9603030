"""One board or robot in a process of its own, on the build that process was started with
(compiled, or pure Python with ``FPGALINK_PURE=1``), driven from a test over a pipe: the
compiled-vs-pure comparisons run the same scenario on a :class:`Twin` of each build and
compare what they return — wire bytes with their cycles, and whole states
(:mod:`tests.support.boardstate`).

``python -m tests.support.twin`` is the worker: it reads pickled ``(command, args)`` from
stdin and writes a pickled ``(ok, result)`` for each to stdout.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
from pathlib import Path
from typing import IO, Any

ROOT = Path(__file__).resolve().parents[2]


class _Worker:
    """The worker's side: one board or robot at a time."""

    def __init__(self) -> None:
        self.target: Any = None

    def board(self, name: str | None) -> Any:
        return self.target if name is None else self.target.boards[name]

    def run(self, command: str, args: tuple[Any, ...]) -> Any:
        handler = getattr(self, "do_" + command)
        return handler(*args)

    def do_build(self) -> str:
        from fpgalink.buildinfo import BUILD

        return BUILD

    def do_new_board(self, options: dict[str, Any]) -> None:
        from fpgaemu import build_board

        self.target = build_board(**options)

    def do_new_robot(self, options: dict[str, Any]) -> None:
        from fpgaemu.robot import EmulatedRobot

        self.target = EmulatedRobot(**options)

    def do_host_write(self, name: str | None, data: bytes, cycle: int | None) -> int:
        done: int = self.board(name).host_write(data, cycle)
        return done

    def do_run_until(self, cycle: int) -> None:
        self.target.run_until(cycle)

    def do_now(self) -> int:
        now: int = self.target.now
        return now

    def do_read(self, name: str | None) -> list[tuple[int, int]]:
        read: list[tuple[int, int]] = self.board(name).read_host_bytes_timed()
        return read

    def do_global_enable(self, name: str | None) -> bool:
        return bool(self.board(name).global_enable)

    def do_state(self, name: str | None) -> dict[str, object]:
        from tests.support.boardstate import board_state

        return board_state(self.board(name))

    def do_truth(self) -> str:
        return repr(self.target.truth())

    def do_host(self, script: list[tuple[Any, ...]]) -> list[object]:
        """A fresh sans-I/O ``Connection`` (the host) through ``script``: after each step,
        what it reported (every event's repr, in order), the bytes it would write and its
        next timer; at the end its stats."""
        from dataclasses import asdict

        from fpgalink import Connection
        from fpgalink.protocol import References, resolve

        host = Connection(baud=1_000_000)
        out: list[object] = []
        for kind, now, *args in script:
            if kind == "start":
                host.start(now)
            elif kind == "receive":
                host.receive_data(args[0], now)
            elif kind == "timer":
                host.handle_timer(now)
            elif kind == "enable":
                host.enable(now)
            elif kind == "references":
                host.send(References(*args), now)
            elif kind == "set":
                param, channel = resolve(args[0])
                host.set_param(param, channel, param.coerce(args[1]), now)
            out.append(([repr(event) for event in host.events()], host.data_to_send(),
                        host.get_timer()))
        out.append(asdict(host.stats))
        return out

    def do_golden(self, firmware: str) -> tuple[str, dict[str, object]]:
        from fpgaemu import build_board
        from tests.fpgaemu.test_golden_trace import digest, trace
        from tests.support.boardstate import board_state

        board = build_board(firmware=firmware)
        return digest(trace(board)), board_state(board)


def main() -> None:
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    worker = _Worker()
    while True:
        try:
            command, args = pickle.load(stdin)
        except EOFError:
            return
        try:
            reply: tuple[bool, Any] = (True, worker.run(command, args))
        except Exception as exc:  # the test side raises it, with the worker's message
            reply = (False, f"{type(exc).__name__}: {exc}")
        pickle.dump(reply, stdout)
        stdout.flush()


class TwinError(RuntimeError):
    """A command failed in the worker."""


class Twin:
    """A worker process on one build: ``pure`` sets ``FPGALINK_PURE=1`` for it, else it is
    unset (the compiled build, where there is one); ``src`` is where its packages come from
    (default: this checkout's)."""

    def __init__(self, *, pure: bool, src: Path | None = None) -> None:
        env = dict(os.environ)
        env.pop("FPGALINK_PURE", None)
        if pure:
            env["FPGALINK_PURE"] = "1"
        env["PYTHONPATH"] = os.pathsep.join([str(src or ROOT / "src"), str(ROOT)])
        self.process = subprocess.Popen([sys.executable, "-m", "tests.support.twin"],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        env=env, cwd=ROOT)
        assert self.process.stdin is not None and self.process.stdout is not None
        self._stdin: IO[bytes] = self.process.stdin
        self._stdout: IO[bytes] = self.process.stdout
        self.build: str = self.call("build")

    def call(self, command: str, *args: Any) -> Any:
        pickle.dump((command, args), self._stdin)
        self._stdin.flush()
        try:
            ok, result = pickle.load(self._stdout)
        except EOFError:
            raise TwinError(f"the {command} worker died (exit {self.process.wait()})") from None
        if not ok:
            raise TwinError(result)
        return result

    def close(self) -> None:
        self._stdin.close()
        self.process.wait(timeout=30)
        self._stdout.close()


if __name__ == "__main__":
    main()
