"""A robot command's recordings at its end: every sample the host had received when the
command stopped is in the ``--record`` file, whether or not its writer had got to it (the
writers were cancelled, and a writer one turn behind lost what it had not yet read)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from mcap.reader import make_reader

from fpgalink.cli.options import ConnectionOptions
from fpgalink.cli.robotsession import RobotRun
from fpgalink.cli.settings import resolve_settings

PORTS = ("L=emu://robot/L?surface=ideal", "R=emu://robot/R?surface=ideal")


def recorded_counters(record: Path, board: str) -> list[int]:
    with record.open("rb") as f:
        return [json.loads(message.data)["counter"]
                for _, channel, message in make_reader(f).iter_messages()
                if channel.topic == f"/board/{board}/telemetry"]


async def test_samples_received_before_the_end_are_all_recorded(tmp_path: Path) -> None:
    record = tmp_path / "run.mcap"
    run = RobotRun(ConnectionOptions(resolve_settings({"ports": PORTS}, {})), None, "ideal",
                   None, None, record)
    seen: list[int] = []
    async with run.opened() as robot:
        mine = robot.boards.stamped_telemetry("L", maxsize=65536)
        # Each turn of the loop this test runs before the one that read the port: it sees
        # a sample in the same turn the recording's writer was woken for it, and ends the
        # command before that writer ran.
        while len(seen) < 200:
            await asyncio.sleep(0)
            while len(mine):
                _, sample = await anext(mine)
                assert sample.counter is not None
                seen.append(sample.counter)
        mine.close()
    assert record in run.recorded
    written = recorded_counters(record, "L")
    assert written[-len(seen):] == seen, (seen[-3:], written[-3:])
