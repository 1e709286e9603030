"""The router: one process owns the boards' ports and offers each board to several local
clients, as mavlink-router does for a MAVLink vehicle, so ``monitor --passive`` or
``record --passive`` can watch while ``drive`` or ``step`` commands
(``fpgalink-cli router``, docs/cli.md).

Each board gets a TCP port on loopback (``socket://127.0.0.1:PORT``, which ``open_link``
and every command take as ``--port``), and pty slots, one client each (a client is
connected while it has the pty open), some behind a stable symlink. The arbitration:

* every client receives every whole frame the board sends, in order;
* the first client to send a frame is the board's **controller**: its frames go to the
  board; the others are **observers**: every frame they send is refused (not passed on) and
  counted, and the router says so the first time; a refused ``PS`` or ``PG`` is answered
  ``PN`` 5 (another client controls the board), which the client's link raises as
  ``ParameterRefused``; an observer's ``IQ`` (who is the board?) is the one frame passed
  on: it changes nothing, and its ``IA`` reaches every client. When the controller leaves,
  the router sends ``RD`` at once, ahead of whatever of its frames still waits for the line
  (dropped, counted), so a motor is never left driven by a client that went away; the next
  client to send becomes the controller;
* what waits for the board is bounded by line time: the controller's frames are handed to
  the port at the line's pace (:class:`LineQueue`), at most :data:`BOARD_QUEUE_S` of line
  time waiting; a frame beyond that is refused and counted, and said;
* a client that does not read falls behind alone: once its socket's buffer holds more than
  the route's ``client_buffer`` bytes, the board's frames are dropped for it (whole frames,
  counted), never for the others and never by stalling the board's line.

Every count is exact per client (:class:`ClientStats`). Noise and broken frames on the
board's line are counted and not passed on; clients' links see only whole frames. A
board's port that goes away (a USB-UART pulled out, a TCP board gone) is reopened with
backoff while the clients stay connected: to them it is a silence, which their links judge
by what the board sends when it is heard again (back or restarted), as on a cable cut.

One concern a module: :mod:`.linequeue` (what waits for a line, sans-I/O), :mod:`.stats`
(a client's accounting), :mod:`.arbitration` (who controls the board, sans-I/O),
:mod:`.clients` (TCP and pty clients), :mod:`.route` (one board's port among its clients),
:mod:`.daemon` (serving them all until stopped). It stands on :mod:`fpgalink.aio`'s
transports, the protocol and :mod:`fpgalink.ports`; the CLI's ``router`` command is a
click command on it."""

from __future__ import annotations

from fpgalink.router.arbitration import Arbitration
from fpgalink.router.clients import CLIENT_READ_SIZE, PtyClient, TcpClient
from fpgalink.router.daemon import HOST, serve_routes
from fpgalink.router.linequeue import BOARD_QUEUE_S, LINE_LEAD_S, LineQueue
from fpgalink.router.route import DISABLE, REOPEN_BACKOFF, BoardRoute
from fpgalink.router.stats import Client, ClientStats

__all__ = [
    "BOARD_QUEUE_S",
    "CLIENT_READ_SIZE",
    "DISABLE",
    "HOST",
    "LINE_LEAD_S",
    "REOPEN_BACKOFF",
    "Arbitration",
    "BoardRoute",
    "Client",
    "ClientStats",
    "LineQueue",
    "PtyClient",
    "TcpClient",
    "serve_routes",
]
