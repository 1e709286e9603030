"""Every command that writes a file, through its console script: on a disk too small to start
(nothing left behind), on one that fills (one line, exit 1, the file complete up to there),
on one whose directory goes away; a target that exists (refused without --force, one line
naming it and the flag); one another process is writing (exit 5). Issue 37 items 5 and 10,
issue 41 item 9."""

from __future__ import annotations

import os
import shlex
import signal
import subprocess
from pathlib import Path

import pytest
from mcap.reader import make_reader

from fpgalink.recording import RecordingReader, partial_path
from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import (
    CAN_MOUNT,
    CLI,
    ROOT,
    cli_env,
    run_cli,
    start_cli,
)
from tests.support.waiting import wait_until_sync as wait_until

pytestmark = pytest.mark.timeout(180)
needs_tmpfs = pytest.mark.skipif(not CAN_MOUNT, reason="needs root and unshare for a tmpfs")


def on_small_disk(tmp_path: Path, size: str, *args: str, timeout: float = 150
                  ) -> tuple[subprocess.CompletedProcess[str], list[str], Path]:
    """``fpgalink-cli ARGS`` (``{small}`` in them: a directory on a tmpfs of ``size``, in a
    private mount namespace); returns the run, every name left in that directory, and a
    copy of what was left there (taken before the namespace goes)."""
    small, kept, listing = tmp_path / "small", tmp_path / "kept", tmp_path / "listing"
    small.mkdir()
    kept.mkdir()
    command = shlex.join([*CLI, *(a.replace("{small}", str(small)) for a in args)])
    script = (f"mount -t tmpfs -o size={size} tmpfs {small} || exit 97\n{command}\n"
              f"rc=$?\nls -A {small} > {listing}\ncp -a {small}/. {kept}/\nexit $rc\n")
    done = subprocess.run(["unshare", "--mount", "sh", "-c", script], capture_output=True,
                          text=True, cwd=ROOT, env=cli_env(), timeout=timeout)
    if done.returncode == 97:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    return done, listing.read_text().split(), kept


def error_line(stderr: str) -> str:
    errors = [line for line in stderr.splitlines() if "error:" in line]
    assert len(errors) == 1, stderr
    assert "Traceback" not in stderr
    return errors[0]


def mcap_messages(path: Path) -> int:
    with path.open("rb") as stream:
        reader = make_reader(stream)  # the normal reader: summary and footer are there
        assert reader.get_summary() is not None
        return sum(1 for _ in reader.iter_messages())


def bag_messages(path: Path) -> int:
    from rosbags.rosbag2 import Reader

    with Reader(path) as reader:
        return sum(1 for _ in reader.messages())


# --- a disk too small to begin on: refused, nothing left ------------------------------------

#: Every way to write a recording from the command line, each into ``{small}``.
WRITERS = {
    "record": ["record", "{small}/run.mcap", "--duration", "60"],
    "record --csv": ["record", "{small}/run.csv", "--csv", "--duration", "60"],
    "record --rosbag2": ["record", "--rosbag2", "{small}/bag", "--duration", "60"],
    "drive --record": ["drive", "--v", "0.1", "--for", "60", "--record", "{small}/run.mcap"],
    "drive --rosbag2": ["drive", "--v", "0.1", "--for", "60", "--rosbag2", "{small}/bag"],
    "goto --record": ["goto", "30", "0", "--time-limit", "60", "--record", "{small}/run.mcap"],
}
#: The bring-up commands' recordings: identify's and autotune's of a board driven for a
#: minute at 1 kHz, calibrate's of the robot turning round ten times.
BRINGUP = ("--wheels", "air", "--max-duty", "100", "--duration", "60", "--period-ms", "1")
WRITERS.update({
    "identify --record": ["identify", "-c", "A", *BRINGUP, "--record", "{small}/run.mcap"],
    "autotune --record": ["autotune", "-c", "A", *BRINGUP, "--record", "{small}/run.mcap"],
    "calibrate --record": ["calibrate", "--turn", "3600", "--omega", "90", "--record",
                           "{small}/run.mcap"],
})
#: A disk that fills within seconds: the 768 KiB kept for a bag's summary and metadata.yaml
#: (512 KiB for a file's summary) and what a writer at rest (compressed well) fills quickly.
FILLS = {"drive --record": "1200k", "goto --record": "1200k", "record --rosbag2": "900k",
         "identify --record": "1200k", "autotune --record": "1200k",
         "calibrate --record": "1200k"}


@needs_tmpfs
@pytest.mark.parametrize("writer", [w for w in WRITERS if w != "record --csv"])
def test_a_recording_that_cannot_begin_is_one_line_and_leaves_nothing(
        tmp_path: Path, writer: str) -> None:
    # Issue 37.10: on a disk too small it refused, but left an unreadable stub (a header,
    # no summary) under the name asked.
    if "rosbag2" in writer:
        pytest.importorskip("rosbags")
    done, left, _ = on_small_disk(tmp_path, "300k", *WRITERS[writer])
    assert done.returncode == 1, done.stderr
    line = error_line(done.stderr)
    assert "the disk is full" in line and ("no file left" in line or "no bag left" in line)
    assert "recorded" not in done.stderr
    assert left == []


# --- a disk that fills: one line, exit 1, complete up to there --------------------------------


@needs_tmpfs
@pytest.mark.parametrize("writer", list(FILLS))
def test_a_disk_that_fills_stops_the_recording_complete_with_one_line(
        tmp_path: Path, writer: str) -> None:
    # Issue 37.10: drive --record said the recording stopped, then that it recorded the
    # path, and exited 0, leaving a file without summary no MCAP reader opened.
    if "rosbag2" in writer:
        pytest.importorskip("rosbags")
    done, left, kept = on_small_disk(tmp_path, FILLS[writer], *WRITERS[writer])
    assert done.returncode == 1, done.stderr
    line = error_line(done.stderr)
    assert "the disk is full" in line and "complete up to there" in line, line
    assert "recorded" not in done.stderr.replace(line, "")
    said = int(line.split(" with ")[1].split()[0])
    if writer == "autotune --record":
        # The disk filled while the wheel was being identified: the run stopped there (the
        # board disabled and set back), it did not go on to drive the confirming step.
        assert "stepping" not in done.stderr, done.stderr
    if "rosbag2" in writer:
        assert left == ["bag"]
        assert bag_messages(kept / "bag") == said > 500
    else:
        assert left == ["run.mcap"]
        assert mcap_messages(kept / "run.mcap") == said > 1000


@needs_tmpfs
def test_tune_on_a_disk_that_fills_says_each_recording_and_leaves_only_whole_files(
        tmp_path: Path) -> None:
    done, left, kept = on_small_disk(tmp_path, "1200k", "tune", "-c", "A", "--grid",
                                     "Kp=100,200,300", "--seconds", "4", "--jobs", "1",
                                     "--format", "json", "--mcap", "{small}/steps")
    assert done.returncode == 1, done.stderr
    assert "error: 3 of 4 recording(s) failed" in done.stderr and "Traceback" not in done.stderr
    said = [line for line in done.stderr.splitlines() if ": recording: " in line]
    assert len(said) == 3 and all("the disk is full" in line for line in said), said
    assert left == ["steps"]
    files = sorted(p.name for p in (kept / "steps").iterdir())
    assert files and not [f for f in files if not f.endswith(".mcap")]  # no stub, no partial
    for name in files:
        assert mcap_messages(kept / "steps" / name) > 1000


@needs_tmpfs
def test_plot_onto_a_full_disk_is_one_line_and_leaves_no_stub(tmp_path: Path) -> None:
    recording = tmp_path / "run.mcap"
    assert run_cli("record", str(recording), "--duration", "0.5").returncode == 0
    done, left, _ = on_small_disk(tmp_path, "8k", "plot", str(recording), "-o",
                                  "{small}/run.png")
    assert done.returncode == 1, done.stderr
    assert "run.png" in error_line(done.stderr)
    assert left == []  # was: a truncated PNG under the name asked


def test_a_directory_that_goes_away_is_one_line_exit_1(tmp_path: Path) -> None:
    where = tmp_path / "gone"
    where.mkdir()
    target = where / "run.mcap"
    proc = start_cli("record", str(target), "--port", "emu://")
    try:
        wait_until(lambda: proc.poll() is not None or partial_path(target).exists(),
                   timeout=30, what="the recording to begin")
        assert proc.poll() is None, proc.communicate()
        for name in os.listdir(where):
            os.unlink(where / name)
        where.rmdir()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    # Was: "recorded N telemetry samples … to run.mcap", exit 130, and no file anywhere.
    assert proc.returncode == 1, err
    line = error_line(err)
    assert str(target) in line and "gone" in line
    assert "recorded" not in err


# --- a target that exists: refused without --force --------------------------------------------

#: (command, the file or directory it writes in ``{dir}``, whether it is a directory)
TARGETS = [
    (["record", "{dir}/x", "--duration", "0.3"], "x", False),
    (["record", "{dir}/x", "--csv", "--duration", "0.3"], "x", False),
    (["record", "--rosbag2", "{dir}/x", "--duration", "0.3"], "x", True),
    (["drive", "--for", "0.3", "--record", "{dir}/x"], "x", False),
    (["drive", "--for", "0.3", "--plot", "{dir}/x.png"], "x.png", False),
    (["drive", "--for", "0.3", "--rosbag2", "{dir}/x"], "x", True),
    (["goto", "0", "0", "--record", "{dir}/x"], "x", False),
    (["goto", "0", "0", "--plot", "{dir}/x.png"], "x.png", False),
    (["step", "--channel", "A", "--to", "10", "--hold", "0.2", "--port", "emu://", "--plot",
      "{dir}/x.png"], "x.png", False),
    (["plot", "{recording}", "-o", "{dir}/x.png"], "x.png", False),
    (["param", "dump", "--port", "emu://", "{dir}/x"], "x", False),
    (["campaign", "{spec}", "--out", "{dir}"], "results.csv", False),
    (["campaign", "{spec}", "--mcap", "--out", "{dir}"], "0-s.mcap", False),
    (["tune", "-c", "A", "--grid", "Kp=100", "--seconds", "0.2", "--plot", "{dir}/x.png"],
     "x.png", False),
    (["tune", "-c", "A", "--grid", "Kp=100", "--seconds", "0.2", "--mcap", "{dir}"],
     "0-seed_3.4.mcap", False),
    # The bring-up commands (they passed force=False, and wrote around the rule): checked
    # before the board or the robot is driven.
    (["identify", "-c", "A", *("--wheels", "air", "--max-duty", "50", "--duration", "3"),
      "--port", "emu://", "--record", "{dir}/x"], "x", False),
    (["identify", "-c", "A", *("--wheels", "air", "--max-duty", "50", "--duration", "3"),
      "--port", "emu://", "--plot", "{dir}/x.png"], "x.png", False),
    (["identify", "-c", "A", *("--wheels", "air", "--max-duty", "50", "--duration", "3"),
      "--port", "emu://", "--save-model", "{dir}/x"], "x", False),
    (["autotune", "-c", "A", *("--wheels", "air", "--max-duty", "50", "--duration", "3"),
      "--port", "emu://", "--record", "{dir}/x"], "x", False),
    (["autotune", "-c", "A", *("--wheels", "air", "--max-duty", "50", "--duration", "3"),
      "--port", "emu://", "--plot", "{dir}/x.png"], "x.png", False),
    (["calibrate", "--turn", "30", "--record", "{dir}/x"], "x", False),
]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    done = run_cli("record", str(path), "--duration", "0.5", "--port", "emu://")
    assert done.returncode == 0, done.stderr
    return path


@pytest.mark.parametrize(("args", "name", "directory"), TARGETS,
                         ids=[" ".join([*a[:2], a[-2]]) for a, _, _ in TARGETS])
def test_an_existing_target_is_refused_without_force_and_left_as_it_was(
        tmp_path: Path, recording: Path, args: list[str], name: str, directory: bool) -> None:
    # Issue 41.9: record run.mcap silently replaced the run.mcap drive had just written.
    if "--rosbag2" in args:
        pytest.importorskip("rosbags")
    out = tmp_path / "out"
    out.mkdir()
    spec = tmp_path / "c.toml"
    spec.write_text('[campaign]\nbody = "kinematic"\n[[scenario]]\nname = "s"\n'
                    'script = [{ wheels = [10, 10], seconds = 0.2 }]\n', encoding="utf-8")
    target = out / name
    if directory:
        target.mkdir()
        (target / "mine").write_text("keep me")
    else:
        target.write_text("keep me")
    argv = [a.format(dir=out, recording=recording, spec=spec) for a in args]
    done = run_cli(*argv, timeout=120)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, str(target), "exists", "--force")
    kept = target / "mine" if directory else target
    assert kept.read_text() == "keep me"
    assert sorted(os.listdir(out)) == [name]  # nothing begun beside it


def test_force_replaces_what_is_there(tmp_path: Path, recording: Path) -> None:
    target = tmp_path / "x.png"
    target.write_text("old")
    done = run_cli("plot", str(recording), "-o", str(target), "--force")
    assert done.returncode == 0, done.stderr
    assert target.read_bytes().startswith(b"\x89PNG")
    assert sorted(os.listdir(tmp_path)) == ["x.png"]
    run = tmp_path / "run.mcap"
    run.write_bytes(recording.read_bytes())
    done = run_cli("drive", "--for", "0.5", "--record", str(run), "--force", timeout=60)
    assert done.returncode == 0, done.stderr
    with run.open("rb") as stream:
        topics = {c.topic for _, c, _ in make_reader(stream).iter_messages()}
    assert "/robot/odometry" in topics  # drive's, not record's


def test_the_bring_up_commands_replace_with_force_and_say_who_the_board_was(
        tmp_path: Path) -> None:
    record, plot, model = tmp_path / "id.mcap", tmp_path / "id.png", tmp_path / "model.toml"
    for path in (record, plot, model):
        path.write_text("old")
    done = run_cli("identify", "-c", "A", "--wheels", "air", "--max-duty", "50",
                   "--duration", "3", "--port", "emu://?seed=2", "--record", str(record),
                   "--plot", str(plot), "--save-model", str(model), "--force",
                   timeout=120)
    assert done.returncode == 0, done.stderr
    assert plot.read_bytes().startswith(b"\x89PNG") and "[plant]" in model.read_text()
    with RecordingReader(record) as reader:
        assert sum(1 for _ in reader.messages()) > 100 and reader.complete
        metadata = reader.metadata["fpgalink"]
    assert metadata["command"] == "identify" and metadata["board.0.match"] == "match"
    assert metadata["host_protocol"] == metadata["board.0.protocol"]
    assert sorted(os.listdir(tmp_path)) == ["id.mcap", "id.png", "model.toml"]


def test_record_without_a_port_says_what_it_records(tmp_path: Path) -> None:
    # Issue 41.9: 10 s of zeros from an idle emulated board, recorded without a word.
    done = run_cli("record", str(tmp_path / "idle.mcap"), "--duration", "0.3")
    assert done.returncode == 0, done.stderr
    said = done.stderr.splitlines()[0]
    assert "recording the built-in emulated board emu://" in said and "at rest" in said


# --- one writer at a time ---------------------------------------------------------------------


def test_a_file_another_process_is_writing_is_refused_with_exit_5(tmp_path: Path) -> None:
    target = tmp_path / "run.mcap"
    first = start_cli("record", str(target), "--duration", "60", "--port", "emu://")
    try:
        wait_until(lambda: first.poll() is not None or partial_path(target).exists(),
                   timeout=30, what="the first recording to begin")
        second = run_cli("record", str(target), "--force", "--duration", "1")
        assert second.returncode == 5, second.stderr
        assert_one_line_error(second.stderr, str(target), "another process is writing it")
        first.send_signal(signal.SIGINT)
        _, err = first.communicate(timeout=30)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 130, err
    with RecordingReader(target) as reader:  # the first one's, whole
        assert sum(1 for _ in reader.messages()) > 10 and not reader.damage
        assert reader.complete


def test_two_campaigns_on_one_out_the_second_is_refused(tmp_path: Path) -> None:
    # Issue 37.5: both ran into the same files and said they had written them; one of the
    # recordings was unreadable (ZstdError).
    spec = tmp_path / "c.toml"
    spec.write_text('[campaign]\nbody = "kinematic"\nmcap = true\n[grid]\nseed = [0, 1]\n'
                    '[[scenario]]\nname = "s"\nscript = [{ wheels = [50, -50], seconds = 30 '
                    '}]\n', encoding="utf-8")
    out = tmp_path / "out"
    first = subprocess.Popen([*CLI, "campaign", str(spec), "--jobs", "1", "--out", str(out)],
                             cwd=ROOT, env=cli_env(), stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: first.poll() is not None or partial_path(out / "0-s.mcap").exists(),
                   timeout=120, what="the first campaign to record")
        second = run_cli("campaign", str(spec), "--jobs", "1", "--out", str(out), "--force",
                         timeout=120)
        assert second.returncode == 5, second.stderr
        assert_one_line_error(second.stderr, str(out), "another campaign is writing there")
        _, err = first.communicate(timeout=600)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 0, err
    for name in ("0-s.mcap", "1-s.mcap"):
        with RecordingReader(out / name) as reader:
            assert sum(1 for _ in reader.messages()) > 10_000
            assert reader.complete and not reader.damage, reader.damage
    names = set(os.listdir(out))
    assert {"0-s.mcap", "1-s.mcap", "results.csv", "results.json"} <= names
    assert not [n for n in names if n.endswith(".partial")]
