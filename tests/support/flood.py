"""A host that floods a served board, and the board's own account of what arrived: shared by
the backpressure tests (tests/e2e/test_e2e_backpressure.py) and the flood benchmark
(benchmarks/flood.py).

``fpgaemu serve`` prints, per board on exit (and on SIGUSR1), how many bytes the host put on
the RX line and how the board's frame decoder took them; :func:`board_counts` reads that
line back."""

from __future__ import annotations

import os
import re
import select
import socket
import time
import tty
from dataclasses import dataclass

import numpy as np

from fpgalink.protocol import ParamAck
from tests.support.wire import received

__all__ = ["BAUD", "KERNEL_SLACK", "BoardCounts", "RawHost", "board_counts", "noise",
           "rss_kb"]

BAUD = 1_000_000
#: What a host can have in flight beyond serve's own backlog: the kernel's buffers between
#: the writer and serve (a pty's, or two sockets'), generously.
KERNEL_SLACK = 128 * 1024
#: Bytes that are never part of a frame (no START, STOP or escape), so the board's decoder
#: counts every one as noise between frames.
NOISE_ALPHABET = bytes(b for b in range(256) if b not in b"SP\\")
#: The counts serve prints per board on exit.
COUNTS = re.compile(
    r"^(?P<board>\w+): host → board (?P<written>[\d,]+) bytes \((?P<received>[\d,]+) "
    r"received: (?P<noise>[\d,]+) noise between frames, (?P<frames>[\d,]+) frames; held "
    r"back (?P<held>[\d,]+) times; (?P<discarded>[\d,]+) discarded when a host left\)",
    re.MULTILINE)


def noise(size: int, seed: int = 24) -> bytes:
    """``size`` random bytes of :data:`NOISE_ALPHABET` (numpy: 50 MB in a second)."""
    alphabet = np.frombuffer(NOISE_ALPHABET, dtype=np.uint8)
    return bytes(np.random.default_rng(seed).choice(alphabet, size).tobytes())


def rss_kb(pid: int) -> int:
    """Resident memory of a running process, in KiB. Raises :class:`ProcessLookupError` once it
    has exited: a process that has exited but is not yet reaped still has a status file, with
    no memory lines in it."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as status:
            line = next((x for x in status if x.startswith("VmRSS:")), None)
    except FileNotFoundError:
        line = None
    if line is None:
        raise ProcessLookupError(f"process {pid} has exited")
    return int(line.split()[1])


@dataclass
class BoardCounts:
    written: int  #: bytes the host put on the RX line
    received: int  #: bytes that reached the board's frame decoder
    noise: int  #: of them, noise between frames
    frames: int
    held: int  #: times serve held the host back
    discarded: int  #: bytes discarded because their host left


def board_counts(stderr: str, board: str = "L") -> BoardCounts:
    for match in COUNTS.finditer(stderr):
        if match["board"] == board:
            values = {k: int(v.replace(",", "")) for k, v in match.groupdict().items()
                      if k != "board"}
            return BoardCounts(**values)
    raise AssertionError(f"no counts for board {board} in serve's stderr: {stderr!r}")


class RawHost:
    """A host that writes with blocking system calls, as a program with a serial port does:
    on a pty (raw mode) or a TCP socket."""

    def __init__(self, url: str) -> None:
        self.sock: socket.socket | None = None
        self.fd: int | None = None
        if url.startswith("socket://"):
            host, port = url.removeprefix("socket://").rsplit(":", 1)
            self.sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
            # A fixed, small send buffer (as a serial driver's): the kernel would otherwise
            # grow it to megabytes and absorb the whole flood, which is allowed but hides
            # whether serve held the writer back.
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 16 * 1024)
            self.sock.settimeout(30)
            self.sock.connect((host.strip("[]"), int(port)))
        else:
            self.fd = os.open(url, os.O_RDWR | os.O_NOCTTY)
            tty.setraw(self.fd)

    def write_all(self, data: bytes) -> None:
        if self.sock is not None:
            self.sock.settimeout(None)  # a timeout would bound the whole sendall
            self.sock.sendall(data)
            return
        assert self.fd is not None
        view = memoryview(data)
        while view:
            view = view[os.write(self.fd, view):]

    def read_some(self, timeout: float) -> bytes:
        if self.sock is not None:
            self.sock.settimeout(timeout)
            try:
                return self.sock.recv(65536)
            except TimeoutError:
                return b""
        assert self.fd is not None
        ready, _, _ = select.select([self.fd], [], [], timeout)
        return os.read(self.fd, 65536) if ready else b""

    def await_answer(self, param_id: int, timeout: float) -> None:
        """Until the board's ``PA`` for ``param_id`` arrives."""
        deadline = time.monotonic() + timeout
        wire = b""
        while time.monotonic() < deadline:
            wire += self.read_some(0.05)
            if any(isinstance(e, ParamAck) and e.param_id == param_id for e in received(wire)):
                return
        raise AssertionError(f"no PA for parameter {param_id} within {timeout:g} s")

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
        if self.fd is not None:
            os.close(self.fd)


