"""``plot``: a recording's fields against time into an image, complete or torn files."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from fpgalink.cli.plot import field_value, read_series
from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import run_cli

pytestmark = pytest.mark.timeout(90)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    done = run_cli("record", str(path), "--duration", "0.6", "--port", "emu://")
    assert done.returncode == 0, done.stderr
    return path


def test_field_paths_flat_and_nested() -> None:
    assert field_value({"a_speed": 3}, "a.speed") == 3.0
    assert field_value({"a": {"speed": 2.5}}, "a.speed") == 2.5
    assert field_value({"pose": {"x": 1}}, "pose.x") == 1.0
    assert field_value({"a_speed": None}, "a.speed") is None  # non-finite on the wire
    assert field_value({"a_flags": True}, "a.flags") is None
    assert field_value({"b": 1}, "a.speed") is None


def test_plot_writes_a_png_of_the_default_fields(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "out.png"
    done = run_cli("plot", str(recording), "-o", str(out))
    assert done.returncode == 0, done.stderr
    assert out.read_bytes().startswith(PNG_MAGIC)
    assert "4 field(s) from 1 topic(s)" in done.stderr


def test_series_are_in_time_order_from_zero(recording: Path) -> None:
    reading = read_series(recording, None, ["a.speed", "t_us"])
    assert reading.complete and reading.skipped == 0
    (speed, t_us) = reading.series
    assert speed.topic == "/board/0/telemetry" and len(speed.t) > 100
    assert speed.t[0] == 0.0 and speed.t == sorted(speed.t)
    # Board time advances as the axis does (publish_time is the board's clock).
    span_board = (t_us.values[-1] - t_us.values[0]) / 1e6
    assert span_board == pytest.approx(t_us.t[-1] - t_us.t[0], abs=0.05)


def test_plot_of_a_torn_recording_uses_its_complete_chunks(recording: Path,
                                                           tmp_path: Path) -> None:
    data = recording.read_bytes()
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(data[: len(data) * 3 // 4])
    out = tmp_path / "torn.png"
    done = run_cli("plot", str(torn), "--fields", "a.speed+a.ref", "-o", str(out))
    # Its torn end is skipped and said (exit 9); what came before it is plotted.
    assert done.returncode == 9, done.stderr
    assert "was not closed" in done.stderr
    assert "cut short: the file ends inside it; skipped" in done.stderr
    assert out.read_bytes().startswith(PNG_MAGIC)
    # Cut back to its last complete chunk (as a writer cut short leaves it), nothing is
    # skipped: only "not closed".
    with torn.open("rb+") as stream:
        stream.truncate(int(done.stderr.split(": bytes ")[1].split("–")[0]))
    done = run_cli("plot", str(torn), "--fields", "a.speed+a.ref", "-o", str(out), "--force")
    assert done.returncode == 0, done.stderr
    assert "was not closed" in done.stderr and "damaged" not in done.stderr


@pytest.mark.parametrize(("args", "needles"), [
    # What is not there is named, with what is (the fields asked for can be corrected).
    (["--fields", "nosuch"], ["no field nosuch", "a_speed", "/board/0/telemetry"]),
    (["--topic", "/nope"], ["no topic /nope", "/board/0/telemetry"]),
    (["-o", "x.txt"], ["--output", ".png"]),
    (["-o", "{missing}/x.png"], ["no such directory"]),
    (["--fields", ","], ["at least one field"]),
])
def test_plot_bad_requests_are_one_line(recording: Path, args: list[str],
                                        needles: list[str], tmp_path: Path) -> None:
    args = [a.format(missing=tmp_path / "missing") for a in args]
    done = run_cli("plot", str(recording), *args)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, *needles)


@pytest.mark.parametrize("content", [b"", b"junk", b"\x89MCAP0\r\n" + b"\x00" * 20])
def test_plot_of_something_not_mcap_is_one_line(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    done = run_cli("plot", str(path), "-o", str(tmp_path / "x.png"))
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, "not a readable MCAP file")


def _svg_texts(path: Path) -> list[str]:
    """The figure's texts: matplotlib's SVG keeps each as a comment beside its glyphs."""
    return re.findall(r"<!-- (.*?) -->", path.read_text(encoding="utf-8"))


@pytest.mark.parametrize(("fields", "labels"), [
    (None, ["a.speed / a.ref, deg/s", "b.speed / b.ref, deg/s"]),
    ("a.current,a.pwm,a.position", ["a.current, A", "a.pwm, PWM counts",
                                    "a.position, encoder counts"]),
])
def test_every_axis_gives_its_unit_and_references_are_dashed(
        recording: Path, tmp_path: Path, fields: str | None, labels: list[str]) -> None:
    """Issue 26: units on every y axis; a reference equal to its speed not hidden under it
    (dashed, in the lines and in their legend)."""
    out = tmp_path / "out.svg"
    done = run_cli("plot", str(recording), *(["--fields", fields] if fields else []),
                   "-o", str(out))
    assert done.returncode == 0, done.stderr
    texts = _svg_texts(out)
    for label in labels:
        assert label in texts, texts
    references = sum(1 for t in texts if t.endswith(".ref"))  # legend entries
    assert out.read_text().count("stroke-dasharray") == 2 * references
