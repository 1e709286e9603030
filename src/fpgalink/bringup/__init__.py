"""Bring-up: identify a wheel's plant, design its speed PID from the model, calibrate the
robot's odometry against a reference (issue 40; docs/hardware.md's checklist).

Sans-I/O, numpy only: :mod:`.plant` (the seed's model form fitted by least squares),
:mod:`.excitation` (what drives the wheel while it is identified), :mod:`.design` (PID
gains from the model, the closed loop predicted), :mod:`.calibration` (χ and the wheel
radius from a reference), :mod:`.robotfile` (writing what was found into a robot file or
a parameter set). The asyncio side that runs them on boards is :mod:`.session`; the
commands are ``fpgalink-cli identify``, ``autotune`` and ``calibrate``.
"""

from __future__ import annotations

__all__: list[str] = []
