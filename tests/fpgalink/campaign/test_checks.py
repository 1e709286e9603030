"""Everything a campaign file or ``tune``'s options say is checked before anything runs
(issue 37 items 3 and 4, issue 41 item 1): a grid counted before it is built, a gain given
twice, a surface its body cannot stand on, a bad fault spec, a body whose extra is not
installed — each one line and exit 2, no scenario run, nothing written. And what the CLI
prints through rich is literal text: a ``[physics]`` in a name or a hint survives.

Through the console scripts; "before anything runs" is asserted as what did not happen (no
scenario announced, no output directory made) and, for the grids, in a process that could
not have built them (its address space capped at 1 GiB), never as a wall-clock bound.
"""

from __future__ import annotations

import json
import re
import resource
import shlex
import subprocess
from pathlib import Path

import pytest

from fpgalink.cli.formats import Column, emit_rows
from tests.fpgalink.campaign.test_campaign import broken_mujoco
from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import CLI, ROOT, cli_env, run_cli
from tests.test_plain_install import CLI as PLAIN_CLI
from tests.test_plain_install import _plain

pytestmark = pytest.mark.timeout(300)

README = (ROOT / "README.md").read_text(encoding="utf-8")
ANNOUNCED = "scenario(s) on"  #: what the campaign says as it starts running


def _capped(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """The CLI in a process whose address space is capped at 1 GiB: it cannot build a
    grid of a billion scenarios (it would fail with MemoryError), only refuse it."""
    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))

    return subprocess.run([*CLI, *args], capture_output=True, text=True, cwd=ROOT,
                          env=env or cli_env(), timeout=60, preexec_fn=cap)


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


# --- the grid is counted before it is built --------------------------------------------


def test_a_campaign_grid_too_large_is_refused_before_it_is_built(tmp_path: Path) -> None:
    # 12 keys of 10 values: a trillion scenarios.
    floats = [f"{name}.{channel}" for name in ("Kp_Wheel_Pid", "Ti_Wheel_Pid", "Td_Wheel_Pid",
                                                "TorqueCoef") for channel in "AB"]
    ints = ["MaxControlSignal.A", "MaxControlSignal.B", "TsTimerPeriod", "seed"]
    grid = "".join(f'"{key}" = [{", ".join(f"{v}.0" for v in range(1, 11))}]\n'
                   for key in floats)
    grid += "".join(f'"{key}" = {list(range(1, 11))}\n' for key in ints)
    spec = _write(tmp_path / "big.toml", "[[scenario]]\nscript = [{ wait = 1 }]\n[grid]\n"
                  + grid)
    done = _capped("campaign", str(spec), "--out", str(tmp_path / "out"))
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, "big.toml: [grid]: 1,000,000,000,000 scenarios",
                          "at most 100,000")
    assert not (tmp_path / "out").exists()


def test_tune_counts_its_grid_before_building_it() -> None:
    values = ",".join(str(v) for v in range(1, 1001))
    done = _capped("tune", "--channel", "A", "--grid", f"Kp={values}", "--grid",
                   f"Ti={values}", "--grid", f"Td={values}")
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, "--grid: 1,000,000,000 combinations "
                          "(1,000 × 1,000 × 1,000); at most 99,999")


# --- tune: every option checked first --------------------------------------------------


@pytest.mark.parametrize(("args", "says"), [
    (("--grid", "Kp=500", "--grid", "Kp=600"), "--grid 'Kp=600': Kp given twice"),
    (("--grid", "Kp=500", "--grid", "kp=600,700"), "kp given twice (also --grid 'Kp=500')"),
    (("--grid", "Kp=500", "--surface", "stairs", "--body", "kinematic"),
     "--surface stairs --body kinematic: surface 'stairs' on the kinematic body"),
    (("--grid", "Kp=500", "--surface", "ideal", "--body", "mujoco"),
     "the mujoco body knows gravel"),
    (("--grid", "Kp=500", "--surface", "lava"), "surface 'lava'"),
    (("--grid", "Kp=500", "--to", "0"), "--to 0: a step to 0 deg/s from rest is no step"),
    (("--grid", "Kp=500", "--to", "5000"), "--to"),
    (("--grid", "Kp=500", "--seconds", "0"), "--seconds"),
    (("--grid", "Kp=500", "--seconds", "1e9"), "--seconds"),
    (("--grid", "Kp=500", "--plot", "/proc/no-such-dir/t.png"), "--plot"),
    (("--grid", "Kp=" + ",".join(["1"] * 100) + ",x"), "values must be numbers"),
], ids=["repeated", "repeated-case", "stairs", "mujoco-ideal", "unknown-surface", "to-0",
        "to-far", "seconds-0", "seconds-far", "plot-dir", "long-entry"])
def test_tune_refuses_what_would_fail_at_run_time_before_running(args: tuple[str, ...],
                                                                  says: str) -> None:
    done = run_cli("tune", "--channel", "A", *args, timeout=60)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, says)
    assert len(done.stderr) < 400  # a long --grid is cut in the message
    assert ANNOUNCED not in done.stderr and done.stdout == ""


# --- campaign files: every value checked first -----------------------------------------


@pytest.mark.parametrize(("head", "says"), [
    ('faults = ["L:restart=banana"]', "c.toml: [campaign] faults[1] 'L:restart=banana': bad "
     "fault spec 'restart=banana': T_S must be seconds from 0 to 31,536,000 (a year), got "
     "'banana'"),
    ('faults = ["L:tx-noise=1:100000000000"]', "LEN must be a whole number from 1 to 16"),
    ('faults = ["R:unplug=1:1"]', "unplug is a fault of fpgaemu serve's pty or TCP link"),
    ('faults = ["X:restart=1"]', "fault 'X:restart=1': write BOARD:FAULT, BOARD one of L, R"),
    ('surface = "stairs"', "surface 'stairs' on the kinematic body"),
    ('body = "mujoco"\nsurface = "ideal"', "surface 'ideal': the mujoco body knows"),
], ids=["restart-banana", "noise-len", "unplug", "board", "stairs", "mujoco-ideal"])
def test_a_campaign_file_written_wrong_runs_nothing(tmp_path: Path, head: str,
                                                   says: str) -> None:
    spec = _write(tmp_path / "c.toml", f"[campaign]\n{head}\n[grid]\nseed = [0, 1]\n"
                  "[[scenario]]\nscript = [{ wait = 0.5 }]\n")
    out = tmp_path / "out"
    done = run_cli("campaign", str(spec), "--out", str(out), "--mcap", timeout=120)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, says)
    assert ANNOUNCED not in done.stderr and not out.exists()


def test_the_kinematic_body_stands_on_the_robot_files_own_surfaces(tmp_path: Path) -> None:
    from fpgalink.campaign import CampaignError, parse_campaign
    from fpgalink.protocol.robot import SEED_ROBOT_TOML

    robot = SEED_ROBOT_TOML.replace("[surfaces]", "[surfaces]\nasphalt = 1.2", 1)
    assert robot != SEED_ROBOT_TOML
    _write(tmp_path / "robot.toml", robot)
    head: dict[str, str] = {"robot": "robot.toml", "surface": "asphalt"}
    document = {"campaign": head, "scenario": [{"script": [{"wait": 0.1}]}]}
    (scenario,) = parse_campaign(document, base=tmp_path).scenarios
    assert scenario.description.chi == 1.2  # the host's odometry takes its χ
    head["body"] = "mujoco"
    with pytest.raises(CampaignError, match="surface 'asphalt': the mujoco body knows"):
        parse_campaign(document, base=tmp_path)


def test_the_mujoco_grounds_are_the_emulators() -> None:
    from fpgaemu import physics
    from fpgalink.campaign.spec import MUJOCO_SURFACES

    assert tuple(physics.SURFACES) == MUJOCO_SURFACES


# --- what a file needs installed -------------------------------------------------------


def test_a_file_that_needs_mujoco_where_it_is_missing_runs_nothing(tmp_path: Path) -> None:
    spec = _write(tmp_path / "both.toml", '[grid]\nbody = ["kinematic", "mujoco"]\n'
                  '[[scenario]]\nscript = [{ wait = 0.2 }]\n')
    out = tmp_path / "out"
    # A plain install (MuJoCo is the physics extra): the rest of the environment hidden.
    done = _plain("fpgalink-cli", PLAIN_CLI, "campaign", str(spec), "--out", str(out),
                  "--jobs", "1")
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, "both.toml: 1 of 2 scenario(s) run on body 'mujoco', "
                          "which needs MuJoCo, not installed here: pip install "
                          "'fpgalink[physics]'")
    assert ANNOUNCED not in done.stderr and not out.exists()
    done = _plain("fpgalink-cli", PLAIN_CLI, "tune", "-c", "A", "-g", "Kp=500", "--body",
                  "mujoco")
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, "tune --body mujoco: 2 of 2 scenario(s)",
                          "pip install 'fpgalink[physics]'")


def test_dask_where_it_is_missing_runs_nothing(tmp_path: Path) -> None:
    spec = _write(tmp_path / "c.toml", "[[scenario]]\nscript = [{ wait = 0.2 }]\n")
    out = tmp_path / "out"
    done = _plain("fpgalink-cli", PLAIN_CLI, "campaign", str(spec), "--dask", "local",
                  "--out", str(out), "--mcap")
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, "--dask needs dask.distributed: pip install "
                          "'fpgalink[campaign]'")
    assert ANNOUNCED not in done.stderr and not out.exists()


EXAMPLES = sorted((ROOT / "examples" / "campaigns").glob("*.toml"))


def _needs_mujoco(path: Path) -> bool:
    from fpgalink.campaign import load_campaign

    return any(s.body == "mujoco" for s in load_campaign(path).scenarios)


@pytest.mark.parametrize("example", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_each_example_campaign_runs_after_make_demo_or_says_what_it_needs(
        tmp_path: Path, example: Path) -> None:
    """``make demo`` installs the package and matplotlib: here a plain install (matplotlib
    left out too; it only adds summary.png). A file on the kinematic body runs whole, every
    scenario ok, recorded; one with mujoco scenarios is refused at once, naming the extra."""
    out = tmp_path / "out"
    args = ("campaign", str(example.relative_to(ROOT)), "--out", str(out), "--mcap",
            "--format", "json")
    if _needs_mujoco(example):
        done = _plain("fpgalink-cli", PLAIN_CLI, *args)
        assert done.returncode == 2, done.stderr
        assert_one_line_error(done.stderr, f"{example.name}: ", "scenario(s) run on body "
                              "'mujoco'", "pip install 'fpgalink[physics]'")
        assert not out.exists()
        return
    done = _plain("fpgalink-cli", PLAIN_CLI, *args, timeout=280)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = json.loads(done.stdout)
    assert rows and all(row["status"] == "ok" for row in rows), rows
    assert len(list(out.glob("*.mcap"))) == len(rows)


def test_what_the_readme_runs_after_make_demo_needs_no_extra() -> None:
    """README's campaign commands before its ``pip install`` line (what works after ``make
    demo``) name example files on the kinematic body; the test above runs each."""
    shown = re.findall(r"^\$ \.venv/bin/(\S+) (.*)$", README, re.MULTILINE)
    before_pip = []
    for program, line in shown:
        if program == "pip":
            break
        words = shlex.split(line, comments=True)
        if program == "fpgalink-cli" and words[0] == "campaign":
            before_pip.append(ROOT / words[1])
    assert before_pip or "fpgalink-cli campaign" not in README
    for path in before_pip:
        assert path in EXAMPLES and not _needs_mujoco(path), path


# --- literal text: nothing read as markup ----------------------------------------------


def test_a_campaign_table_shows_names_and_hints_as_they_are(tmp_path: Path) -> None:
    name = "[physics] [bold]x[/bold] :smile:"
    spec = _write(tmp_path / "c.toml", f'[campaign]\nname = "{name}"\nbody = "mujoco"\n'
                  f'[[scenario]]\nname = "{name}"\nscript = [{{ wait = 0.2 }}]\n')
    env = {**broken_mujoco(tmp_path), "COLUMNS": "600"}
    done = run_cli("campaign", str(spec), "--jobs", "1", timeout=120, env=env)
    assert done.returncode == 1, done.stderr  # the scenario fails where it runs (below)
    # The table (stdout): the names as written, and the error's hint whole.
    assert done.stdout.count(name) >= 2, done.stdout
    assert "pip install 'fpgalink[physics]'" in done.stdout, done.stdout
    assert "pip install 'fpgalink[physics]'" in done.stderr  # the note as it failed
    assert f"campaign {name}" in done.stderr


def test_every_table_prints_its_text_literally(monkeypatch: pytest.MonkeyPatch,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """emit_rows is what param, ports, budget, router, step, drive, campaign and tune print
    their tables with."""
    monkeypatch.setenv("COLUMNS", "200")
    emit_rows("table", [Column("a", "[b]header[/b]"), Column("b", "b", drop=1)],
              [{"a": "[physics]", "b": ":smile: [red]"}], title="[bold]title [x]")
    shown = capsys.readouterr().out
    for text in ("[b]header[/b]", "[physics]", ":smile: [red]", "[bold]title [x]"):
        assert text in shown, shown
    assert not re.search(r"\x1b\[", shown)  # and no styling was made of it


def test_the_console_factory_is_the_only_one() -> None:
    """Every rich console the CLI prints through is ``output.console`` (markup off)."""
    made = [path.relative_to(ROOT) for path in (ROOT / "src" / "fpgalink").rglob("*.py")
            if re.search(r"\b\w*Console\(", path.read_text(encoding="utf-8"))]
    assert made == [Path("src/fpgalink/cli/output.py")], made
