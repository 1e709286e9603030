"""``step``: the response figures on known curves, and the command against the emulator."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from fpgalink.cli.step import step_metrics
from tests.support.cli import Board, completed, run_cli

pytestmark = pytest.mark.timeout(60)


def first_order(tau: float, start: float, target: float, n: int = 2000, dt: float = 0.001
                ) -> tuple[list[float], list[float]]:
    t = [i * dt for i in range(n)]
    return t, [target + (start - target) * math.exp(-ti / tau) for ti in t]


def test_first_order_figures() -> None:
    t, y = first_order(0.2, 0.0, 45.0)
    m = step_metrics(t, y, 0.0, 45.0)
    assert m.rise_time == pytest.approx(0.2 * math.log(9), abs=0.002)  # 10→90 %: τ ln 9
    assert m.settling_time == pytest.approx(0.2 * math.log(50), abs=0.002)  # 2 %: τ ln 50
    assert m.overshoot == 0.0
    assert m.steady_state_error == pytest.approx(0.0, abs=0.05)


def test_downward_step_with_overshoot_and_offset() -> None:
    # Underdamped second order, settling at 9 instead of 10 (a 1 deg/s offset) from 30 → 10.
    t = [i * 0.001 for i in range(5000)]
    zeta, wn = 0.3, 10.0
    wd = wn * math.sqrt(1 - zeta**2)
    y = [30 - 21 * (1 - math.exp(-zeta * wn * ti) * (math.cos(wd * ti) + zeta * wn / wd
                                                   * math.sin(wd * ti))) for ti in t]
    m = step_metrics(t, y, 30.0, 10.0)
    expected = 100 * (21 * (1 + math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))) - 20) / 20
    assert m.overshoot == pytest.approx(expected, rel=0.01)
    assert m.steady_state_error == pytest.approx(1.0, abs=0.01)
    assert m.settling_time is None or m.settling_time > 0


def test_never_reaching_target_reports_none() -> None:
    t, y = first_order(0.2, 0.0, 20.0)
    m = step_metrics(t, y, 0.0, 45.0)
    assert m.rise_time is None and m.settling_time is None


def test_step_plot_against_the_emulator(board: Board, tmp_path: Path) -> None:
    pytest.importorskip("fpgaemu.serve", reason="step needs a board with dynamics (emulator)")
    pytest.importorskip("matplotlib")
    if not board.has_dynamics:
        pytest.skip("the scripted fake board has no plant: step needs the emulator")
    png = tmp_path / "step.png"
    done = run_cli("step", "--channel", "A", "--to", "45", "--hold", "2", "--pre", "0.3",
                   "--plot", str(png), "--port", board.url, timeout=30)
    # Over a pty a loaded machine may stop the step for real (the emulator or the host not
    # scheduled in time, measured): then no figures and no plot. In-process (emu://) the
    # board keeps the link's time: it completes.
    if not completed(done, *([board.served] if board.served else [])):
        assert "the step was stopped: " in done.stderr and "rise time" not in done.stdout
        assert not png.exists()
        return
    for figure in ("rise time", "settling time", "overshoot", "steady-state error"):
        assert figure in done.stdout
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_step_rejects_a_zero_step() -> None:
    done = run_cli("step", "--channel", "A", "--to", "5", "--from", "5")
    assert done.returncode == 2
    assert "no step" in done.stderr


def test_step_shows_its_progress_on_a_terminal() -> None:
    # stderr on a pseudo-terminal, as at a shell: the phases show while the step runs.
    import os
    import subprocess

    from tests.support.cli import CLI, ROOT, cli_env

    master, slave = os.openpty()
    try:
        proc = subprocess.Popen([*CLI, "step", "-c", "A", "--to", "20", "--pre", "0.3",
                                 "--hold", "0.6", "--port", "emu://"], cwd=ROOT,
                                stdout=subprocess.PIPE, stderr=slave, env=cli_env())
        os.close(slave)
        seen = b""
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:  # EIO: the child closed its side
                break
            if not chunk:
                break
            seen += chunk
        assert proc.wait(timeout=30) == 0
    finally:
        os.close(master)
    text = seen.decode("utf-8", "replace")
    assert "holding 0 deg/s on A" in text and "stepped to 20 deg/s" in text


def test_the_step_plot_marks_what_the_table_measures(tmp_path: Path) -> None:
    """Issue 26: the step plot's axes give units, its title the gains, and it marks the rise,
    the settling time, the ±2 % band, the reference (dashed) and the PWM limit."""
    pytest.importorskip("matplotlib")
    svg = tmp_path / "step.svg"
    done = run_cli("step", "--channel", "A", "--to", "45", "--hold", "1.5", "--plot",
                   str(svg), "--port", "emu://", timeout=60)
    assert done.returncode == 0, done.stderr
    # matplotlib's SVG keeps each text as a comment beside its glyphs.
    texts = re.findall(r"<!-- (.*?) -->", svg.read_text(encoding="utf-8"))
    for label in ("channel A speed, deg/s", "PWM, counts", "time since the step, s",
                  "±2% band", "reference", "limit ±32760 (MaxControlSignal)"):
        assert label in texts, texts
    assert any(t.startswith("Kp 520") and "Ti 0.24 s" in t for t in texts), texts
    assert any(t.startswith("rise 10–90 %: ") for t in texts), texts
    assert any(t.startswith("settled (2 %): ") for t in texts), texts
    assert "stroke-dasharray" in svg.read_text()
