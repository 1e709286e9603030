"""Serving emulated boards as devices, paced to a clock (docs/emulator.md §17). One concern
per module:

* :mod:`.pacing` — a board's (or a robot's) time following the clock, host bytes onto the
  line at the cycle they arrived, backpressure (:class:`~.pacing.PacedBoard`,
  :class:`~.pacing.PacedRobot`, :class:`~.pacing.RxFlow`);
* :mod:`.loop` — the event loop serve runs on, and the :class:`~.loop.Pacer` that wakes a
  board at its deadlines;
* :mod:`.pty`, :mod:`.tcp` — a board behind a pseudo-terminal or a TCP port;
* :mod:`.listening` — TCP listening shared by the boards' and the truth's endpoints;
* :mod:`.truth`, :mod:`.record` — the robot's truth stream;
* :mod:`.inprocess` — ``emu://`` in the host's own event loop.

:mod:`fpgaemu.serve` gathers the public names.
"""
