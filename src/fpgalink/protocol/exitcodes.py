"""The exit codes of every console script — ``fpgalink-cli``, ``fpgaemu`` and
``fpgalink-ros2`` — declared once, so a shell script or a launch file reads each program's
code alike (docs/cli.md, "Exit codes"). Here, beside the wire, because it is the one package
both fpgalink and the emulator import."""

from __future__ import annotations

from enum import IntEnum

__all__ = ["ExitCode", "NotInstalled", "exit_codes_help", "exit_codes_table"]


class ExitCode(IntEnum):
    OK = 0  #: done; a server (``fpgaemu serve``, ``router``, the node) stopped by a signal
    FAILURE = 1  #: anything not covered below (stdout unwritable, a full disk while recording)
    BAD_INPUT = 2  #: usage, a bad value, file, name or URL; nothing was sent
    REFUSED = 3  #: the board answered PN (or confirmed another value than the one sent)
    #: the board did not answer after the configured tries, or went silent; or nothing
    #: usable came from it (its frames in the other wire-CRC mode)
    NO_ANSWER = 4
    #: a port is missing, busy or failed (or could not be served); or a file or directory
    #: to write is being written by another process now
    PORT = 5
    TIMEOUT = 6  #: a goal was not reached in time (goto); the robot was stopped
    #: a fault stopped the robot or the step: a board went silent, restarted, disabled itself
    #: (its watchdog: this host stalled) or its telemetry stopped; or the deadman lapsed
    STOPPED = 7
    NOT_INSTALLED = 8  #: an optional part is not installed; the message gives the pip command
    #: a recording read back is damaged: what is intact was used, each damaged part named
    DAMAGED = 9
    #: the board's firmware was built from another protocol declaration than this host's
    #: (its identity, docs/protocol.md §8): refused, both hashes named; --allow-mismatch
    #: goes on
    MISMATCH = 10
    INTERRUPTED = 130  #: a command stopped by Ctrl-C (128 + SIGINT), after a clean stop
    TERMINATED = 143  #: a command stopped by SIGTERM (128 + SIGTERM), handled as Ctrl-C


#: Each code in a few words, for the programs' help.
_SHORT = {
    ExitCode.OK: "ok",
    ExitCode.FAILURE: "other failure",
    ExitCode.BAD_INPUT: "bad input (usage, a value out of range or of the wrong type, a bad "
                        "file, name or URL; nothing sent)",
    ExitCode.REFUSED: "board refused (PN) or confirmed another value",
    ExitCode.NO_ANSWER: "board not answering (or nothing usable came: its frames in the "
                        "other wire-CRC mode)",
    ExitCode.PORT: "port missing, busy or failed (or a file another process is writing "
                   "now)",
    ExitCode.TIMEOUT: "goal not reached in time",
    ExitCode.STOPPED: "stopped by a fault (a board silent, restarted, disabled by its "
                      "watchdog, its telemetry stopped; the deadman)",
    ExitCode.NOT_INSTALLED: "an optional part not installed (the message gives the pip "
                            "command)",
    ExitCode.DAMAGED: "a recording read is damaged (the rest was used)",
    ExitCode.MISMATCH: "the board's firmware speaks another protocol declaration (both "
                       "hashes named; --allow-mismatch goes on)",
    ExitCode.INTERRUPTED: "interrupted (Ctrl-C)",
    ExitCode.TERMINATED: "terminated (SIGTERM)",
}


class NotInstalled(ImportError):
    """An optional part (an extra: cffi, ROS 2, matplotlib, foxglove-sdk …) is not
    installed; the message gives the pip command. Exit :attr:`ExitCode.NOT_INSTALLED`."""


def exit_codes_help(codes: tuple[ExitCode, ...] = tuple(ExitCode)) -> str:
    """One paragraph for a program's ``--help``: the codes it can end with."""
    parts = [f"{int(code)} {_SHORT[code]}" for code in codes]
    return ("Exit codes (the same for fpgalink-cli, fpgaemu and fpgalink-ros2): "
            + "; ".join(parts) + ".")


def exit_codes_table() -> list[tuple[int, str, str]]:
    """(code, name, meaning) of every code, for the docs' table."""
    return [(int(code), code.name, _SHORT[code]) for code in ExitCode]
