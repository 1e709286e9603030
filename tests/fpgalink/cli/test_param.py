"""``param get|set|list|load|dump`` end to end through the CLI subprocess."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from tests.support.cli import Board, run_cli

pytestmark = pytest.mark.timeout(60)


def test_set_then_get_confirms_and_reads_back(board: Board) -> None:
    if not board.persistent:
        pytest.skip("emu:// boots a fresh board for each command; covered over pty")
    done = run_cli("param", "set", "Kp_Wheel_Pid", "7.11", "--channel", "A", "--port", board.url)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "Kp_Wheel_PidA = 7.11"
    got = run_cli("param", "get", "Kp_Wheel_PidA", "--port", board.url)
    assert got.returncode == 0, got.stderr
    assert got.stdout.strip() == "7.11"  # float32 shown as typed, not 7.110000133514404


def test_negative_value_needs_no_separator(board: Board) -> None:
    done = run_cli("param", "set", "IncSenzCountDirectionB", "-1", "--port", board.url)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "IncSenzCountDirectionB = -1"


def test_list_shows_every_parameter_with_board_values(board: Board) -> None:
    if not board.persistent:
        pytest.skip("emu:// boots a fresh board for each command; covered over pty")
    run_cli("param", "set", "TsTimerPeriod", "4", "--port", board.url)
    done = run_cli("param", "list", "--port", board.url)
    assert done.returncode == 0, done.stderr
    for name in ("TsTimerPeriod", "GetDataPeriodical", "Kp_Wheel_Pid", "Td_Wheel_Pid",
                 "IncSenzCountDirection", "0..32760", "-1 or 1"):
        assert name in done.stdout
    line = next(li for li in done.stdout.splitlines() if "TsTimerPeriod" in li)
    assert " 4 " in line


def test_dump_then_load_round_trip(board: Board, tmp_path: Path) -> None:
    if not board.persistent:
        pytest.skip("emu:// boots a fresh board for each command; covered over pty")
    values = tmp_path / "params.toml"
    done = run_cli("param", "dump", str(values), "--port", board.url)
    assert done.returncode == 0, done.stderr
    document = tomllib.loads(values.read_text(encoding="utf-8"))
    assert set(document) >= {"TsTimerPeriod", "GetDataPeriodical", "A", "B"}
    assert "Kp_Wheel_Pid" in document["A"]
    # Edit as a user would: change a board value, move a channel value to the suffixed form.
    text = values.read_text(encoding="utf-8").replace("TsTimerPeriod = ", "TsTimerPeriod = 7  #", 1)
    head, _, channel_b = text.partition("\n[B]\n")
    channel_b = "\n".join(li for li in channel_b.splitlines()
                          if not li.startswith("MaxControlSignal "))
    head = head.replace("\n[A]\n", "\nMaxControlSignalB = 1234\n\n[A]\n", 1)
    values.write_text(f"{head}\n[B]\n{channel_b}\n", encoding="utf-8")
    loaded = run_cli("param", "load", str(values), "--port", board.url)
    assert loaded.returncode == 0, loaded.stderr + loaded.stdout
    lines = loaded.stdout.splitlines()
    assert len(lines) == 19 and all(li.startswith("ok ") for li in lines), loaded.stdout
    assert any("TsTimerPeriod = 7" in li for li in lines)
    assert run_cli("param", "get", "MaxControlSignalB", "--port", board.url).stdout.strip() \
        == "1234"


def test_load_refusal_reports_each_line_exit_3(fake_board, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    fake = fake_board(nack=3)
    values = tmp_path / "p.toml"
    values.write_text("TsTimerPeriod = 5\n[A]\nKp_Wheel_Pid = 2.5\n", encoding="utf-8")
    done = run_cli("param", "load", str(values), "--port", fake.url)
    assert done.returncode == 3
    assert done.stdout.count("failed") == 2
    assert "value out of range" in done.stdout
    assert "2 of 2 parameters failed" in done.stderr
