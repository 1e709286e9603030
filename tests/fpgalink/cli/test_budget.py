"""``budget``: the static calculator over fpgalink.protocol.wire."""

from __future__ import annotations

import pytest

from tests.support.cli import run_cli

pytestmark = pytest.mark.timeout(30)


def test_seed_case_does_not_fit_and_tm_alone_does() -> None:
    done = run_cli("budget", "--period-ms", "1", "--message", "BIG:200:1:down", "--check")
    assert done.returncode == 1, done.stderr
    assert "board→host" in done.stdout and "DOES NOT FIT" in done.stdout
    ok = run_cli("budget", "--period-ms", "1", "--check")
    assert ok.returncode == 0, ok.stderr
    assert "100.0 wire bytes" in ok.stdout


def test_bad_message_spec_exits_2() -> None:
    done = run_cli("budget", "--message", "RV:eight:1")
    assert done.returncode == 2
    assert "RV:eight:1" in done.stderr


def test_direction_comes_from_the_catalogue() -> None:
    done = run_cli("budget", "--tm-bytes", "0", "--message", "PA:20:1", "--message", "RV:18:1",
                   "--message", "ZZ:10:1")
    assert done.returncode == 0, done.stderr
    rows = {line.split("│")[2].strip(): line.split("│")[1].strip()
            for line in done.stdout.splitlines() if line.count("│") > 3}
    assert rows == {"PA": "board→host", "RV": "host→board", "ZZ": "host→board"}


def _rows(stdout: str) -> dict[str, list[str]]:
    return {cells[2]: cells for cells in
            ([c.strip() for c in line.split("│")] for line in stdout.splitlines()
             if line.count("│") > 3)}


def test_crc_adds_two_content_bytes_to_every_counted_message() -> None:
    plain = run_cli("budget", "--message", "RV:18:1")
    crc = run_cli("budget", "--crc", "--message", "RV:18:1")
    assert plain.returncode == crc.returncode == 0, crc.stderr
    before, after = _rows(plain.stdout), _rows(crc.stdout)
    # content B, then wire B: TM 52 → 54 content, 54 → 56 wire (no escapes assumed)
    assert (before["TM"][3], before["TM"][4]) == ("52", "54")
    assert (after["TM"][3], after["TM"][4]) == ("54", "56")
    assert (before["RV"][3], after["RV"][3]) == ("18", "20")
    assert "wire CRC on" in " ".join(crc.stdout.split())
    assert "board→host: 56 wire bytes per period (56.0%)" in crc.stdout


def test_crc_over_the_content_limit_exits_2() -> None:
    done = run_cli("budget", "--crc", "--message", "BIG:199:1")
    assert done.returncode == 2 and "CRC" in done.stderr
