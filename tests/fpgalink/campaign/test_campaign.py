"""Campaigns (issue 27): the emulated-time loop, the declaration, scenarios giving the same
figures wherever they run (here, in other processes, on a 2-worker Dask LocalCluster),
failures reported and not fatal, each scenario's MCAP recording, and the CLI's campaign and
tune commands.

Every figure is read on emulated time, so these assertions hold on a machine under any load.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import os
import stat
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

import pytest

from fpgalink.aio.virtualtime import NothingScheduled, run_virtual
from fpgalink.campaign import (
    Campaign,
    CampaignError,
    load_campaign,
    parse_campaign,
    run_campaign,
    run_scenario,
)
from fpgalink.campaign.results import deterministic_rows
from fpgalink.recording import partial_path
from tests.fpgalink.cli.test_errors import assert_one_line_error
from tests.support.cli import CAN_MOUNT, cli_env, cli_on_small_disk, run_cli

ROOT = Path(__file__).resolve().parents[3]
SEED36 = ROOT / "examples" / "campaigns" / "seed36.toml"


# --- the emulated-time loop ------------------------------------------------------------


def test_the_virtual_loop_jumps_to_each_timer_and_no_wall_time_passes() -> None:
    async def main() -> tuple[float, list[float]]:
        loop = asyncio.get_running_loop()
        seen: list[float] = []
        for delay in (0.25, 3600.0, 1e-3):
            await asyncio.sleep(delay)
            seen.append(loop.time())
        return loop.time(), seen

    import time

    started = time.perf_counter()
    end, seen = run_virtual(main())
    assert seen == pytest.approx([0.25, 3600.25, 3600.251])
    assert end == pytest.approx(3600.251)
    assert time.perf_counter() - started < 60  # an hour of sleeping, not an hour


def test_the_virtual_loop_says_so_when_nothing_can_ever_happen(monkeypatch: pytest.MonkeyPatch
                                                               ) -> None:
    import fpgalink.aio.virtualtime as vt

    monkeypatch.setattr(vt, "IDLE_WAIT_S", 0.05)

    async def main() -> None:
        await asyncio.Event().wait()  # nothing will ever set it

    with pytest.raises(NothingScheduled, match="nothing is scheduled"):
        run_virtual(main())


def test_the_virtual_loop_still_takes_a_threads_result() -> None:
    async def main() -> int:
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(None, sum, [1, 2, 3])

    assert run_virtual(main()) == 6


# --- the declaration -------------------------------------------------------------------


def _doc(**scenario: object) -> dict[str, object]:
    return {"scenario": [{"script": [{"wait": 0.1}], **scenario}]}


def test_a_grid_multiplies_every_scenario_and_sets_what_it_names() -> None:
    campaign = parse_campaign({
        "campaign": {"body": "kinematic", "seed": 4},
        "grid": {"surface": ["gravel", "marble"], "Kp_Wheel_Pid.A": [300.0, 400.0, 500.0]},
        "scenario": [{"name": "a", "script": [{"wait": 1}]},
                     {"name": "b", "params": {"L.Ti_Wheel_Pid.B": 0.3},
                      "script": [{"drive": [0.2, 0], "seconds": 1}]}]})
    assert len(campaign.scenarios) == 2 * 2 * 3
    assert [s.index for s in campaign.scenarios] == list(range(12))
    b = [s for s in campaign.scenarios if s.name == "b"]
    assert {(s.surface, s.params[-1].value) for s in b} == {
        (surface, kp) for surface in ("gravel", "marble") for kp in (300.0, 400.0, 500.0)}
    assert all(s.params[0].label == "L.Ti_Wheel_PidB" for s in b)
    assert all(s.seed == 4 and s.body == "kinematic" for s in campaign.scenarios)
    # The host's odometry takes the χ of the surface the scenario runs on.
    assert {s.description.surface for s in campaign.scenarios} == {"gravel", "marble"}
    urls = campaign.scenarios[0].urls()
    assert urls["L"].startswith("emu://robot/L?surface=gravel&body=kinematic&seed=4&run=0")


def test_which_scenarios_record_is_the_campaigns_choice_unless_a_scenario_says() -> None:
    campaign = parse_campaign({"campaign": {"mcap": True}, "scenario": [
        {"script": [{"wait": 1}]}, {"mcap": False, "script": [{"wait": 1}]}]})
    assert [s.mcap for s in campaign.scenarios] == [True, False]
    assert not any(s.mcap for s in parse_campaign(_doc()).scenarios)


@pytest.mark.parametrize(("document", "says"), [
    ({"scenario": []}, "no [[scenario]]"),
    (_doc(surface="lava"), "scenario 1 (scenario 1): surface 'lava': the kinematic body "
                           "knows ideal, gravel, marble, grass; the mujoco body gravel"),
    (_doc(surface="stairs"), "surface 'stairs' on the kinematic body: it knows ideal, "
                             "gravel, marble, grass (it is flat"),
    (_doc(surface="ideal", body="mujoco"), "surface 'ideal': the mujoco body knows gravel"),
    ({"grid": {"body": ["kinematic", "mujoco"], "surface": ["gravel", "stairs"]},
      **_doc(name="climb")}, "scenario 1 (climb), grid point body = 'kinematic', surface = "
                             "'stairs': surface 'stairs' on the kinematic body"),
    (_doc(faults=["L:restart=banana"]), "scenario 1 faults[1] 'L:restart=banana': bad fault "
                                        "spec 'restart=banana': T_S must be seconds"),
    ({"campaign": {"faults": ["R:tx-noise=1:100000000000"]}, **_doc()},
     "[campaign] faults[1] 'R:tx-noise=1:100000000000': bad fault spec "
     "'tx-noise=1:100000000000': LEN must be a whole number from 1 to 16"),
    (_doc(faults=["L:unplug=1:1"]), "unplug is a fault of fpgaemu serve's pty or TCP link"),
    (_doc(faults=[f"L:restart={t}" for t in range(101)]), "more than 100 faults for board L"),
    (_doc(params={"Kp_Wheel_PidA": 1.0, "Kp_Wheel_Pid.A": 2.0}),
     "'Kp_Wheel_PidA' and 'Kp_Wheel_Pid.A' both set Kp_Wheel_PidA"),
    ({"grid": {"Kp_Wheel_Pid": [1.0], "L.Kp_Wheel_Pid.B": [2.0, 3.0]}, **_doc()},
     "'Kp_Wheel_Pid' and 'L.Kp_Wheel_Pid.B' both set L.Kp_Wheel_PidB: give it one key"),
    ({"grid": {f"{name}.{channel}": [float(v) for v in range(1, 11)]
               for name in ("Kp_Wheel_Pid", "Ti_Wheel_Pid", "Td_Wheel_Pid", "TorqueCoef")
               for channel in "AB"} | {"seed": list(range(10))}, **_doc()},
     "1,000,000,000 scenarios (10 × 10 × 10 × 10 × 10 × 10 × 10 × 10 × 10 values × 1 "
     "[[scenario]]); at most 100,000"),
    (_doc(body="rigid"), "body"),
    (_doc(params={"Kp_Whel_Pid": 1.0}), "unknown parameter"),
    (_doc(params={"Kp_Wheel_Pid.A": -1.0}), "Kp_Wheel_Pid.A"),
    (_doc(params={"Q.Kp_Wheel_Pid.A": 1.0}), "the robot has boards"),
    (_doc(faults=["restart=3"]), "BOARD:FAULT"),
    (_doc(script=[]), "non-empty list of actions"),
    (_doc(script=[{"drive": [0.1, 0], "wait": 1}]), "exactly one of"),
    (_doc(script=[{"drive": [float("nan"), 0], "seconds": 1}]), "a number in"),
    (_doc(script=[{"drive": [0.1, 0], "seconds": 1e9}]), "a number in"),
    (_doc(script=[{"step": 0}]), "no step"),
    (_doc(seed=-1), "seed"),
    (_doc(mcap="yes"), "mcap: true or false"),
    (_doc(colour="red"), "unknown key 'colour'"),
    ({"grid": {"surface": []}, **_doc()}, "non-empty list"),
    ({"grid": {"seed": list(range(1000)), "Kp_Wheel_Pid": [float(v) for v in range(101)]},
      **_doc()}, "at most"),
])
def test_a_campaign_written_wrong_is_one_line_naming_where(document: dict[str, object],
                                                           says: str) -> None:
    with pytest.raises(CampaignError) as caught:
        parse_campaign(document, source="spec.toml")
    message = str(caught.value)
    assert says in message and "\n" not in message and message.startswith("spec.toml")


def test_the_seed_table_campaign_file_reads(tmp_path: Path) -> None:
    campaign = load_campaign(SEED36)
    assert len(campaign.scenarios) == 10
    assert {s.body for s in campaign.scenarios} == {"kinematic", "mujoco"}
    (tmp_path / "big.toml").write_bytes(b"#" * (2 << 20))
    with pytest.raises(CampaignError, match="larger than"):
        load_campaign(tmp_path / "big.toml")
    with pytest.raises(CampaignError, match="cannot read"):
        load_campaign(tmp_path / "absent.toml")


# --- running ---------------------------------------------------------------------------


def _short(campaign: Campaign, seconds: float = 1.0, settle: float = 0.5) -> Campaign:
    """The same scenarios with every action shortened (the figures' meaning unchanged)."""
    return replace(campaign, scenarios=tuple(
        replace(s, script=tuple(replace(a, seconds=seconds, settle=settle) for a in s.script))
        for s in campaign.scenarios))


def _kinematic_seed36() -> Campaign:
    campaign = _short(load_campaign(SEED36))
    kept = [s for s in campaign.scenarios if s.body == "kinematic"]
    return replace(campaign, scenarios=tuple(replace(s, index=i) for i, s in enumerate(kept)))


def test_a_scenario_measures_the_robot_from_its_truth_and_its_host() -> None:
    campaign = parse_campaign({
        "campaign": {"body": "kinematic", "surface": "gravel"},
        "scenario": [{"name": "all", "script": [
            {"wheels": [50, -50], "settle": 1, "seconds": 2, "label": "turn"},
            {"step": 45, "wheel": "FL", "seconds": 1.5, "label": "step"},
            {"goto": [0.6, 0.3], "seconds": 40, "label": "goto"}]}]})
    result = run_scenario(campaign.scenarios[0])
    assert result.ok, result.error
    f = result.figures
    # In place ±50 deg/s on gravel: the kinematic body turns at 2·r·ω/(χ·B), clockwise.
    r, chi, track = 0.2, 1.65, 0.66
    import math
    expected = -math.degrees(2 * r * math.radians(50) / (chi * track))
    assert f["turn.turn_rate_dps"] == pytest.approx(expected, rel=1e-3)
    assert f["turn.wander_x_m"] == pytest.approx(0.0, abs=1e-6)
    # The default gains' step (docs/emulator.md §12: 0 % overshoot, settled at 0.54 s).
    assert f["step.overshoot_pct"] == 0.0
    assert f["step.settling_s"] == pytest.approx(0.54, abs=0.02)
    assert f["goto.outcome"] == "arrived"
    assert isinstance(f["goto.error_m"], float) and f["goto.error_m"] < 0.06
    assert f["lost"] == 0 and f["stops"] == 0 and f["restarts"] == 0
    assert isinstance(f["telemetry"], int) and f["telemetry"] > 1000


def test_a_fault_in_a_scenario_is_counted_and_the_robot_goes_on() -> None:
    campaign = parse_campaign({
        "campaign": {"body": "kinematic", "surface": "gravel"},
        "scenario": [{"name": "restart", "faults": ["L:restart=2"], "script": [
            {"drive": [0.3, 0], "seconds": 6, "label": "drive"}]}]})
    result = run_scenario(campaign.scenarios[0])
    assert result.ok, result.error
    f = result.figures
    assert f["restarts"] == 1 and isinstance(f["stops"], int) and f["stops"] >= 1
    assert isinstance(f["first_stop"], str) and "board L" in f["first_stop"]
    assert isinstance(f["stopped_s"], float) and 0.0 < f["stopped_s"] < 3.0
    # Driving again after the restart: most of 6 s at 0.3 m/s.
    assert isinstance(f["drive.distance_m"], float) and 0.9 < f["drive.distance_m"] < 1.8


def test_a_failing_scenario_is_reported_and_the_others_still_run() -> None:
    campaign = parse_campaign({
        "campaign": {"body": "kinematic"},
        "scenario": [{"name": "bad", "script": [{"wait": 0.5}]},
                     {"name": "good", "script": [{"wait": 0.5}]}]})
    # A fault the emulator does not know, past the file's checks: it fails where it runs.
    bad, good = campaign.scenarios
    campaign = replace(campaign, scenarios=(replace(bad, faults=("L:meltdown=1",)), good))
    results = run_campaign(campaign, jobs=1)
    assert [r.status for r in results] == ["failed", "ok"]
    assert results[0].error and "meltdown" in results[0].error
    assert "\n" not in results[0].error


def test_the_same_campaign_gives_the_same_table_in_one_process_and_on_two() -> None:
    campaign = _kinematic_seed36()
    here = run_campaign(campaign, jobs=1)
    there = run_campaign(campaign, jobs=2)
    assert all(r.ok for r in here), [r.error for r in here]
    assert deterministic_rows(here) == deterministic_rows(there)
    assert all(r.worker.split(":")[1] != str(__import__("os").getpid()) for r in there)


def test_the_same_campaign_gives_the_same_table_on_a_dask_local_cluster() -> None:
    pytest.importorskip("dask.distributed")
    campaign = _kinematic_seed36()
    here = run_campaign(campaign, jobs=1)
    on_dask = run_campaign(campaign, dask="local", jobs=2)
    assert deterministic_rows(here) == deterministic_rows(on_dask)
    assert all(r.ok for r in on_dask)


def test_a_scenario_is_the_same_under_another_hash_seed(tmp_path: Path) -> None:
    # Set and dict order must not leak into the figures: another interpreter, another
    # PYTHONHASHSEED, the same figures.
    code = ("import json,sys; from fpgalink.campaign import parse_campaign, run_scenario; "
            "c = parse_campaign({'campaign': {'body': 'kinematic'}, 'scenario': [{"
            "'faults': ['R:restart=1'], 'script': [{'drive': [0.3, 20], 'seconds': 3}]}]}); "
            "print(json.dumps(run_scenario(c.scenarios[0]).figures, sort_keys=True))")
    outputs = set()
    for seed in ("1", "2"):
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              env={**cli_env(), "PYTHONHASHSEED": seed}, cwd=ROOT,
                              timeout=300)
        assert done.returncode == 0, done.stderr
        outputs.add(done.stdout)
    assert len(outputs) == 1


# --- the CLI ---------------------------------------------------------------------------


def test_campaign_through_the_console_script(tmp_path: Path) -> None:
    spec = tmp_path / "c.toml"
    spec.write_text('[campaign]\nbody = "kinematic"\n[grid]\nsurface = ["gravel", "marble"]\n'
                    '[[scenario]]\nname = "turn"\n'
                    'script = [{ wheels = [50, -50], settle = 0.5, seconds = 1 }]\n',
                    encoding="utf-8")
    out = tmp_path / "out"
    done = run_cli("campaign", str(spec), "--jobs", "1", "--format", "json", "--out", str(out),
                   timeout=300)
    assert done.returncode == 0, done.stderr
    rows = json.loads(done.stdout)
    assert [(r["surface"], r["status"]) for r in rows] == [("gravel", "ok"), ("marble", "ok")]
    # marble's χ is larger: the same wheel speeds turn the body more slowly
    assert abs(rows[1]["1.wheels.turn_rate_dps"]) < abs(rows[0]["1.wheels.turn_rate_dps"])
    assert json.loads((out / "results.json").read_text()) == rows
    assert (out / "results.csv").read_text().splitlines()[0].startswith("index,scenario")
    assert (out / "summary.png").stat().st_size > 1000


def test_campaign_refuses_a_bad_file_in_one_line(tmp_path: Path) -> None:
    spec = tmp_path / "c.toml"
    spec.write_text('[[scenario]]\nscript = [{ fly = 1 }]\n', encoding="utf-8")
    done = run_cli("campaign", str(spec))
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "exactly one of" in done.stderr
    done = run_cli("campaign", str(spec), "--jobs", "0")
    assert done.returncode == 2 and "--jobs" in done.stderr
    # fpgaemu campaign is the same command
    done = subprocess.run([sys.executable, "-m", "fpgaemu", "campaign", str(tmp_path / "no")],
                          capture_output=True, text=True, env=cli_env(), cwd=ROOT, timeout=60)
    assert done.returncode == 2 and "cannot read" in done.stderr
    assert "Traceback" not in done.stderr


def broken_mujoco(tmp_path: Path) -> dict[str, str]:
    """An environment whose MuJoCo is installed but does not load (a missing system
    library): what the campaign checks first finds it, and a scenario on it fails where it
    runs."""
    package = tmp_path / "broken" / "mujoco"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text(
        'raise ImportError("libGL.so.1: cannot open shared object file")\n', encoding="utf-8")
    return cli_env(PYTHONPATH=os.pathsep.join(
        [str(tmp_path / "broken"), *filter(None, [os.environ.get("PYTHONPATH")])]))


def test_a_failed_scenario_makes_the_campaign_exit_1(tmp_path: Path) -> None:
    spec = tmp_path / "c.toml"
    spec.write_text('[campaign]\nbody = "mujoco"\n'
                    '[[scenario]]\nscript = [{ wait = 0.2 }]\n', encoding="utf-8")
    done = run_cli("campaign", str(spec), "--jobs", "1", "--format", "csv", timeout=300,
                   env=broken_mujoco(tmp_path))
    assert done.returncode == 1
    assert "scenario 0" in done.stderr and "libGL.so.1" in done.stderr
    assert "Traceback" not in done.stderr
    assert done.stdout.splitlines()[1].split(",")[2] == "failed"


def test_tune_picks_the_gains_that_settle_soonest(tmp_path: Path) -> None:
    plot, recordings = tmp_path / "tune.png", tmp_path / "steps"
    done = run_cli("tune", "--channel", "A", "--grid", "Kp=100,520", "--grid", "Ti=0.24",
                   "--seconds", "1.5", "--jobs", "1", "--format", "json", "--plot", str(plot),
                   "--mcap", str(recordings), timeout=300)
    assert done.returncode == 0, done.stderr
    assert "wrote 3 recording(s)" in done.stderr
    rows = json.loads(done.stdout)
    assert [r["scenario"] for r in rows] == ["seed §3.4", "grid", "grid"]
    assert rows[0]["kp"] == 2502.0 and rows[0]["best"] is False  # the reference row
    best = [r for r in rows if r["best"]]
    assert len(best) == 1 and best[0]["kp"] == 520.0  # Kp 100 is far too soft to settle
    slow = next(r for r in rows if r["kp"] == 100.0)
    assert slow["step.settling_s"] is None or slow["step.settling_s"] > \
        best[0]["step.settling_s"]
    assert plot.stat().st_size > 1000
    # Each combination's step recorded, its gains in the file as set on the board.
    files = sorted(recordings.iterdir())
    assert [f.name for f in files] == ["0-seed_3.4.mcap", "1-grid.mcap", "2-grid.mcap"]
    for path, row in zip(files, rows, strict=True):
        messages, _ = _read_mcap(path)
        assert len(_on(messages, "/board/L/telemetry")) > 1000
        kp = [p["value"] for p in _on(messages, "/board/L/params")
              if p["name"] == "Kp_Wheel_PidA" and p["status"] == "in_force"]
        assert kp and kp[-1] == pytest.approx(row["kp"]), path


def test_tune_refuses_a_bad_grid_or_recording_directory(tmp_path: Path) -> None:
    for grid in ("Kq=1", "Kp=", "Kp=a,b", "Kp=inf"):
        done = run_cli("tune", "-c", "A", "-g", grid)
        assert done.returncode == 2, (grid, done.stderr)
        assert "--grid" in done.stderr and "Traceback" not in done.stderr
    (tmp_path / "file").write_text("")
    done = run_cli("tune", "-c", "A", "-g", "Kp=520", "--mcap", str(tmp_path / "file" / "x"))
    assert done.returncode != 0 and "--mcap" in done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1


def _children(pid: int) -> set[int]:
    found: set[int] = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):  # the thread ended meanwhile
            found |= {int(p) for p in (task / "children").read_text().split()}
    return found


def _is_worker(pid: int) -> bool:
    try:
        return b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False


def _long_campaign(tmp_path: Path, *, seeds: int, jobs: int, extra: tuple[str, ...] = ()
                   ) -> subprocess.Popen[str]:
    """The CLI running scenarios of 600 s emulated (minutes of wall time), in a process
    group of its own so a test can signal the group as a terminal's Ctrl-C does."""
    from tests.support.cli import CLI

    spec = tmp_path / "c.toml"
    spec.write_text(f'[campaign]\nbody = "kinematic"\n[grid]\nseed = {list(range(seeds))}\n'
                    '[[scenario]]\nscript = [{ wheels = [50, -50], seconds = 600 }]\n',
                    encoding="utf-8")
    return subprocess.Popen([*CLI, "campaign", str(spec), "--jobs", str(jobs), *extra], cwd=ROOT,
                            env=cli_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, preexec_fn=_as_foreground)


def _as_foreground() -> None:
    """Ctrl-C as a terminal's foreground job has it: a suite started as a shell's background
    job (``make test &``) passes SIGINT on ignored, and Python then leaves it ignored."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


CTRL_C_WHILE_A_WORKER_STARTS = """
import os, signal
from fpgalink.campaign.runner import _submit

class StartingPool:
    def submit(self, work, *args):
        os.kill(os.getpid(), signal.SIGINT)  # as the worker appears
        return None

# As in a terminal's foreground job (a shell's background job inherits SIGINT ignored).
signal.signal(signal.SIGINT, signal.default_int_handler)
try:
    _submit(StartingPool(), print)
except KeyboardInterrupt:
    print("reached")
else:
    print("lost")
"""


def test_a_ctrl_c_while_a_worker_starts_reaches_the_campaign() -> None:
    # The group's Ctrl-C came while the pool started its worker: it was ignored process-wide
    # then, so the campaign lost it and ran on (a test's campaign ran a minute past it).
    # In a process of its own: a SIGINT to the test's worker process, delivered late on a
    # loaded machine, stopped the whole test run (xdist took it for the user's Ctrl-C).
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", CTRL_C_WHILE_A_WORKER_STARTS],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.stdout.strip() == "reached", done.stdout + done.stderr


def test_a_campaign_worker_ignores_ctrl_c_and_does_not_block_it() -> None:
    # The parent stops a worker itself; the worker must not die of the group's Ctrl-C on its
    # own, nor keep it blocked as the parent held it while starting the worker.
    import multiprocessing
    import os
    import signal

    from fpgalink.campaign.runner import _pool, _submit

    pool = _pool(1, multiprocessing.get_context("spawn"))
    try:
        pid = _submit(pool, os.getpid).result(timeout=60)
        status = dict(line.split(":\t", 1) for line in
                      Path(f"/proc/{pid}/status").read_text().splitlines() if ":\t" in line)
        bit = 1 << (signal.SIGINT - 1)
        assert int(status["SigIgn"], 16) & bit
        assert not int(status["SigBlk"], 16) & bit
    finally:
        pool.shutdown()
    assert not signal.pthread_sigmask(signal.SIG_BLOCK, set()) & {signal.SIGINT}


@pytest.mark.parametrize(("signal_name", "group", "code", "says"), [
    ("SIGINT", True, 130, "interrupted"),  # Ctrl-C: the whole process group
    ("SIGTERM", False, 143, "terminated"),
])
def test_a_campaign_stopped_by_a_signal_ends_its_workers(
        tmp_path: Path, signal_name: str, group: bool, code: int, says: str) -> None:
    import os
    import signal
    import time

    proc = _long_campaign(tmp_path, seeds=4, jobs=2)
    try:
        deadline = time.monotonic() + 120
        workers: set[int] = set()
        # Wait for both workers to be there (what the signal must not leave behind).
        while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
            workers = {p for p in _children(proc.pid) if _is_worker(p)}
            time.sleep(0.05)
        assert len(workers) == 2
        sig = getattr(signal, signal_name)
        if group:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == code, err
    assert says in err and "Traceback" not in err
    deadline = time.monotonic() + 10
    while any(_is_worker(p) for p in workers):
        assert time.monotonic() < deadline, "a worker outlived the campaign"
        time.sleep(0.05)


def test_a_sigterm_ends_a_campaign_running_in_this_process(tmp_path: Path) -> None:
    # --jobs 1: the scenario runs in the CLI's own process, where it reports the exceptions
    # it meets as its failure; the signal must end the campaign all the same.
    import signal

    proc = _long_campaign(tmp_path, seeds=2, jobs=1)
    try:
        assert proc.stderr is not None
        # The campaign's first line comes after the handler is in place.
        assert "scenario(s) on" in proc.stderr.readline()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, err
    assert "terminated" in err and "failed" not in err and "Traceback" not in err


def test_a_stopped_campaign_leaves_its_recordings_readable(tmp_path: Path) -> None:
    # The signal's exception may break into a write: the file is left at its last complete
    # chunk, without summary, for the reader that needs none.
    import signal
    import time

    from tests.support.recordings import readable_topics

    out = tmp_path / "out"
    # Not finished: it is written, and left, under its partial name.
    path = partial_path(out / "0-scenario_1.mcap")

    proc = _long_campaign(tmp_path, seeds=1, jobs=1, extra=("--mcap", "--out", str(out)))
    try:
        # Stopped once the file holds a second of telemetry (its size says nothing: room is
        # kept allocated past the data), however long the machine takes to get there.
        deadline = time.monotonic() + 120
        readable = 0
        while readable <= 1000:
            assert time.monotonic() < deadline and proc.poll() is None, "no recording"
            time.sleep(0.2)
            if path.exists():
                readable = readable_topics(path).count("/board/L/telemetry")
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 143, err
    assert "Traceback" not in err
    left = readable_topics(path)
    # Every telemetry message readable before the signal is readable after it.
    assert left.count("/board/L/telemetry") >= readable and "/robot/truth" in left
    assert not (out / "0-scenario_1.mcap").exists()  # never taken for a finished one


def test_a_worker_that_dies_costs_only_its_scenario(tmp_path: Path) -> None:
    import os
    import signal
    import time

    from fpgalink.campaign.runner import iter_results

    campaign = parse_campaign({
        "campaign": {"body": "kinematic"},
        "grid": {"seed": [0, 1]},
        "scenario": [{"name": "long", "mcap": True, "script": [{"wait": 3600}]},
                     {"name": "short", "script": [{"wait": 0.2}]}]})
    # The two long scenarios take both workers first (an emulated hour each): kill those
    # workers while they run; the short ones then run on the workers started again.
    gen = iter_results(campaign.scenarios, jobs=2, mcap_dir=tmp_path)

    def kill_workers() -> None:
        deadline = time.monotonic() + 120
        workers: set[int] = set()
        while len(workers) < 2:
            assert time.monotonic() < deadline, "no workers"
            workers = {p for p in _children(os.getpid()) if _is_worker(p)}
            time.sleep(0.05)
        time.sleep(0.5)  # both long scenarios under way (they run an hour: no race)
        for pid in workers:
            os.kill(pid, signal.SIGKILL)

    import threading

    killer = threading.Thread(target=kill_workers)
    killer.start()
    try:
        results = list(gen)
    finally:
        killer.join()
    by_name: dict[str, list[str]] = {}
    for r in results:
        by_name.setdefault(r.name, []).append(r.status)
    assert sorted(by_name["long"]) == ["failed", "failed"]
    assert by_name["short"] == ["ok", "ok"]
    assert all("worker process died" in (r.error or "") for r in results if not r.ok)
    # The recordings they had begun are said unfinished (there, if they were begun).
    for r in results:
        if r.ok:
            assert r.mcap is None and r.mcap_error is None
        else:
            assert (r.mcap_error or "").startswith("not finished: its worker process died")
            assert r.mcap is None or (Path(r.mcap).exists() and Path(r.mcap).parent == tmp_path
                                      and r.mcap.endswith(".mcap.partial"))


def test_figures_are_over_the_seconds_asked_even_between_control_periods() -> None:
    import math

    campaign = parse_campaign({
        "campaign": {"body": "kinematic", "surface": "gravel"},
        "scenario": [{"script": [{"wheels": [50, -50], "settle": 1, "seconds": 0.25,
                                  "label": "turn"}]}]})
    result = run_scenario(campaign.scenarios[0])
    assert result.ok, result.error
    expected = -math.degrees(2 * 0.2 * math.radians(50) / (1.65 * 0.66))
    assert result.figures["turn.turn_rate_dps"] == pytest.approx(expected, rel=1e-3)
    assert result.figures["emulated_s"] == pytest.approx(1.25, abs=1e-6)


def test_a_robot_file_whose_path_holds_url_characters(tmp_path: Path) -> None:
    from fpgalink.protocol.robot import SEED_ROBOT_TOML

    folder = tmp_path / "c++ #1 50%"
    folder.mkdir()
    (folder / "robot.toml").write_text(SEED_ROBOT_TOML, encoding="utf-8")
    campaign = parse_campaign({
        "campaign": {"body": "kinematic", "robot": "robot.toml"},
        "scenario": [{"faults": ["L:restart=0.5"], "script": [{"wait": 1.0}]}]},
        base=folder)
    result = run_scenario(campaign.scenarios[0])
    assert result.ok, result.error
    assert result.figures["restarts"] == 1  # the fault after the path arrived too


# --- recordings (MCAP) -----------------------------------------------------------------


def _read_mcap(path: Path) -> tuple[list[tuple[str, int, int, bytes]], dict[str, dict[str, str]]]:
    """Every message in file order (topic, log time, publish time, data) and the metadata."""
    from mcap.reader import make_reader

    with path.open("rb") as stream:
        reader = make_reader(stream)
        messages = [(channel.topic, message.log_time, message.publish_time, message.data)
                    for _, channel, message in reader.iter_messages(log_time_order=False)]
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return messages, metadata


def _on(messages: list[tuple[str, int, int, bytes]], topic: str) -> list[dict[str, Any]]:
    return [json.loads(data) for t, _, _, data in messages if t == topic]


def test_a_recorded_scenario_holds_its_run_in_emulated_time(tmp_path: Path) -> None:
    campaign = parse_campaign({
        "campaign": {"body": "kinematic", "surface": "gravel"},
        "scenario": [{"name": "turn, go", "faults": ["L:restart=1.5"],
                      "params": {"Kp_Wheel_Pid.A": 520.0}, "script": [
                          {"wheels": [50, -50], "settle": 0.5, "seconds": 1, "label": "turn"},
                          {"drive": [0.3, 0], "seconds": 1.5, "label": "go"}]}]})
    scenario = campaign.scenarios[0]
    path = tmp_path / "run.mcap"
    recorded = run_scenario(scenario, path)
    assert recorded.ok and recorded.mcap == str(path) and recorded.mcap_error is None
    # Recording changes nothing it records.
    assert recorded.figures == run_scenario(scenario).figures
    messages, metadata = _read_mcap(path)
    topics = {t for t, _, _, _ in messages}
    boards = ("L", "R")
    assert topics == {f"/board/{b}/{kind}" for b in boards
                      for kind in ("telemetry", "params", "events", "stats")} | {
        "/robot/truth", "/robot/odometry", "/robot/events", "/scenario/actions"}
    # Emulated time: from 0, never going back in the file, ending just after the script
    # (the robot's start and close on either side of emulated_s).
    times = [log for _, log, _, _ in messages]
    assert times == sorted(times) and times[0] >= 0
    emulated_s = recorded.figures["emulated_s"]
    assert isinstance(emulated_s, float) and emulated_s == pytest.approx(3.0, abs=0.05)
    assert emulated_s < times[-1] / 1e9 < emulated_s + 1.0
    # Every sample the host received is in the file: each board's count is its link's at the
    # end (the last stats message), about one per emulated millisecond (the TM period).
    for board in boards:
        rows = _on(messages, f"/board/{board}/telemetry")
        stats = _on(messages, f"/board/{board}/stats")
        assert len(rows) == stats[-1]["telemetry_received"]
        span = [log / 1e9 for t, log, _, _ in messages if t == f"/board/{board}/telemetry"]
        assert len(rows) == pytest.approx((span[-1] - span[0]) * 1000, rel=0.03)
        assert len(stats) == int(times[-1] / 1e9) + 1  # every emulated second, and the end
    # R never restarted: its samples in order, none missing (the board's counter numbers
    # its parameter answers too, so a sample may follow one).
    counters = [row["counter"] for row in _on(messages, "/board/R/telemetry")]
    assert all(1 <= (b - a) % 100_000 <= 2 for a, b in itertools.pairwise(counters))
    assert recorded.figures["lost"] == 0
    assert sum(len(_on(messages, f"/board/{b}/telemetry")) for b in boards) >= \
        cast(int, recorded.figures["telemetry"])
    # The truth, 50 times per emulated second, ending where the figures say the body went.
    truth = _on(messages, "/robot/truth")
    assert len(truth) == pytest.approx((truth[-1]["t"] - truth[0]["t"]) * 50, abs=3)
    assert [r["t"] for r in truth] == sorted(r["t"] for r in truth)
    assert truth[-1]["distance"] == pytest.approx(recorded.figures["distance_m"], abs=0.01)
    assert len(_on(messages, "/robot/odometry")) == len(truth)
    # What happened: the parameter set, the restart, the stop it caused, the actions.
    assert any(r["name"] == "Kp_Wheel_PidA" and r.get("value") == 520.0
               and r["status"] == "in_force" for r in _on(messages, "/board/L/params"))
    assert any(e["message"].startswith("board_restarted")
               for e in _on(messages, "/board/L/events"))
    stops = [e for e in _on(messages, "/robot/events") if e["message"].startswith("stopped")]
    assert len(stops) == recorded.figures["stops"] and all(e["level"] == 3 for e in stops)
    assert [e["message"] for e in _on(messages, "/scenario/actions")] == [
        "turn: wheels for 1 s", "go: drive for 1.5 s"]
    # The file says what it is and what came of it.
    assert metadata["fpgalink"]["scenario"] == "turn, go"
    assert metadata["fpgalink"]["faults"] == "L:restart=1.5"
    result = metadata["fpgalink.result"]
    assert result.pop("status") == "ok" and result.pop("error") == ""
    assert {k: json.loads(v) for k, v in result.items()} == recorded.figures


def _two_short() -> Campaign:
    return parse_campaign({
        "campaign": {"body": "kinematic", "mcap": True},
        "grid": {"surface": ["gravel", "marble"]},
        "scenario": [{"name": "turn/left", "script": [
            {"wheels": [50, -50], "settle": 0.2, "seconds": 0.5}]}]})


def test_recordings_are_the_same_in_one_process_and_on_two_and_leave_the_table_as_it_was(
        tmp_path: Path) -> None:
    campaign = _two_short()
    here = run_campaign(campaign, jobs=1, mcap_dir=tmp_path / "here")
    there = run_campaign(campaign, jobs=2, mcap_dir=tmp_path / "there")
    unrecorded = run_campaign(replace(campaign, scenarios=tuple(
        replace(s, mcap=False) for s in campaign.scenarios)), jobs=1)
    assert all(r.ok and r.mcap_error is None for r in here + there), [
        (r.error, r.mcap_error) for r in here + there]
    assert deterministic_rows(here) == deterministic_rows(there) == \
        deterministic_rows(unrecorded)
    assert [Path(r.mcap or "").name for r in there] == ["0-turn_left.mcap", "1-turn_left.mcap"]
    for a, b in zip(here, there, strict=True):
        assert a.mcap is not None and b.mcap is not None
        assert Path(b.mcap).parent == tmp_path / "there"
        # The same scenario, the same recording, message for message (emulated time).
        assert _read_mcap(Path(a.mcap)) == _read_mcap(Path(b.mcap))
    with pytest.raises(CampaignError, match="mcap_dir"):
        run_campaign(campaign, jobs=1)


def test_a_dask_worker_writes_the_recordings(tmp_path: Path) -> None:
    pytest.importorskip("dask.distributed")
    campaign = _two_short()
    on_dask = run_campaign(campaign, dask="local", jobs=2, mcap_dir=tmp_path / "dask")
    here = run_campaign(campaign, jobs=1, mcap_dir=tmp_path / "here")
    assert all(r.ok and r.mcap is not None for r in on_dask), [r.error for r in on_dask]
    assert all(str(os.getpid()) != r.worker.split(":")[1] for r in on_dask)
    for a, b in zip(here, on_dask, strict=True):
        assert _read_mcap(Path(cast(str, a.mcap))) == _read_mcap(Path(cast(str, b.mcap)))


def test_a_recording_that_cannot_be_written_costs_the_recording_not_the_scenario(
        tmp_path: Path) -> None:
    campaign = replace(_two_short(), scenarios=_two_short().scenarios[:1])
    figures = run_scenario(replace(campaign.scenarios[0], mcap=False)).figures
    # A directory that cannot be made (a file is in the way).
    (tmp_path / "file").write_text("")
    [result] = run_campaign(campaign, jobs=1, mcap_dir=tmp_path / "file" / "out")
    assert result.ok and result.figures == figures
    assert result.mcap is None and result.mcap_error is not None
    assert "file/out" in result.mcap_error and "\n" not in result.mcap_error
    assert deterministic_rows([result]) == deterministic_rows(
        run_campaign(replace(campaign, scenarios=(replace(campaign.scenarios[0], mcap=False),
                                                  )), jobs=1))
    # A device where the file should go (a private /dev/full, char 1:7; the real one is
    # not touched): not a file a recording replaces, and left as it is.
    full_dir = tmp_path / "full"
    full_dir.mkdir()
    try:
        os.mknod(full_dir / "0-turn_left.mcap", stat.S_IFCHR | 0o666, os.makedev(1, 7))
    except PermissionError:
        pytest.skip("mknod needs root")
    [result] = run_campaign(campaign, jobs=1, mcap_dir=full_dir)
    assert result.ok and result.figures == figures
    assert result.mcap is None
    assert result.mcap_error is not None and "not a regular file" in result.mcap_error
    assert stat.S_ISCHR((full_dir / "0-turn_left.mcap").stat().st_mode)


def test_a_disk_that_fills_during_a_scenario_stops_its_recording_only(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import errno

    from fpgalink.recording import McapSink

    campaign = replace(_two_short(), scenarios=_two_short().scenarios[:1])
    figures = run_scenario(replace(campaign.scenarios[0], mcap=False)).figures
    add = McapSink.add

    def filling(self: McapSink, *args: Any, **kwargs: Any) -> None:
        if self.messages >= 500:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        add(self, *args, **kwargs)

    monkeypatch.setattr(McapSink, "add", filling)
    [result] = run_campaign(campaign, jobs=1, mcap_dir=tmp_path)
    assert result.ok and result.figures == figures
    assert result.mcap_error is not None and "No space left" in result.mcap_error
    assert "s emulated" in result.mcap_error
    # What was written before stays readable, summary and all.
    assert result.mcap is not None
    messages, _ = _read_mcap(Path(result.mcap))
    assert len(messages) == 500


def test_campaign_mcap_through_the_console_script(tmp_path: Path) -> None:
    spec = tmp_path / "c.toml"
    spec.write_text('[campaign]\nbody = "kinematic"\n[grid]\nsurface = ["gravel", "marble"]\n'
                    '[[scenario]]\nname = "turn"\n'
                    'script = [{ wheels = [50, -50], settle = 0.2, seconds = 0.5 }]\n',
                    encoding="utf-8")
    plain, recorded = tmp_path / "plain", tmp_path / "recorded"
    done = run_cli("campaign", str(spec), "--jobs", "2", "--out", str(plain), timeout=300)
    assert done.returncode == 0, done.stderr
    assert not list(plain.glob("*.mcap"))
    # The second scenario's file is blocked (a directory is in its place): said before
    # anything runs, one line, exit 2, nothing written.
    (recorded / "1-turn.mcap").mkdir(parents=True)
    done = run_cli("campaign", str(spec), "--jobs", "2", "--mcap", "--out", str(recorded),
                   "--format", "json", timeout=300)
    assert done.returncode == 2, done.stderr
    assert_one_line_error(done.stderr, "1-turn.mcap: is a directory")
    assert sorted(p.name for p in recorded.iterdir()) == ["1-turn.mcap"]
    (recorded / "1-turn.mcap").rmdir()
    done = run_cli("campaign", str(spec), "--jobs", "2", "--mcap", "--out", str(recorded),
                   "--format", "json", timeout=300)
    assert done.returncode == 0, done.stderr
    rows = json.loads(done.stdout)
    assert [r["status"] for r in rows] == ["ok", "ok"]
    assert Path(rows[0]["mcap"]).is_absolute()
    assert Path(rows[0]["mcap"]).samefile(recorded / "0-turn.mcap")
    assert rows[0]["mcap_error"] is None and rows[1]["mcap_error"] is None
    messages, _ = _read_mcap(recorded / "0-turn.mcap")
    assert {"/board/L/telemetry", "/robot/truth"} <= {t for t, _, _, _ in messages}
    # results.json as without recording, but for the columns that say how a row ran.
    from fpgalink.campaign.results import RUN_COLUMNS

    def measured(out: Path) -> list[dict[str, Any]]:
        table = json.loads((out / "results.json").read_text())
        return [{k: v for k, v in row.items() if k not in RUN_COLUMNS} for row in table]

    assert measured(recorded) == measured(plain)
    # Recording needs a directory to write into.
    done = run_cli("campaign", str(spec), "--mcap")
    assert done.returncode == 2 and "--out" in done.stderr


@pytest.mark.skipif(not CAN_MOUNT, reason="needs root and unshare for a private tmpfs")
def test_a_disk_that_fills_leaves_a_complete_recording_and_the_figures(tmp_path: Path) -> None:
    from mcap.reader import make_reader

    spec = tmp_path / "c.toml"
    # A 10 s scenario records about 0.9 MB: on a 1 MB disk the first fills it; then the
    # second finds no room to start one.
    spec.write_text('[campaign]\nbody = "kinematic"\nmcap = true\n[grid]\nseed = [0, 1]\n'
                    '[[scenario]]\nname = "turn"\nscript = [{ wheels = [50, -50], seconds = 10 '
                    '}]\n', encoding="utf-8")
    done, out = cli_on_small_disk(tmp_path, "1m", "out", "campaign", str(spec), "--jobs", "1",
                                  "--out", "{out}", timeout=300)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr and "2 of 2 recording(s) failed" in done.stderr
    rows = json.loads((out / "results.json").read_text())
    assert [r["status"] for r in rows] == ["ok", "ok"]  # the figures stand
    assert rows[0]["1.wheels.turn_rate_dps"] == rows[1]["1.wheels.turn_rate_dps"]
    first, second = rows
    assert "the disk is full" in first["mcap_error"]
    assert "complete up to there" in first["mcap_error"] and "s emulated" in first["mcap_error"]
    with (out / "0-turn.mcap").open("rb") as stream:
        reader = make_reader(stream)  # summary and footer: the normal reader
        assert reader.get_summary() is not None
        said = int(first["mcap_error"].split(" with ")[1].split()[0])
        assert sum(1 for _ in reader.iter_messages()) == said > 1000
    assert "could not be started; no file left" in second["mcap_error"]
    assert second["mcap"] is None
    assert not (out / "1-turn.mcap").exists()
    assert not (out / "1-turn.mcap.partial").exists()


def test_a_lost_scenario_names_only_a_recording_begun_in_this_run(tmp_path: Path) -> None:
    # A worker that died before opening its file leaves there, at most, an earlier run's
    # recording: complete, and not this scenario's unfinished one.
    import os
    import time

    from fpgalink.campaign.runner import _lost

    scenario = _two_short().scenarios[0]
    path = tmp_path / "0-x.mcap"
    path.write_bytes(b"an earlier run's")
    an_hour_ago = time.time() - 3600
    os.utime(path, (an_hour_ago, an_hour_ago))
    began = time.time()
    earlier = _lost(scenario, str(path), "its worker process died", began)
    assert earlier.mcap is None and earlier.mcap_error == "not finished: its worker process died"
    # What a worker that died had begun is under its partial name (never the finished one).
    partial = partial_path(path)
    partial.write_bytes(b"begun now")
    begun = _lost(scenario, str(path), "its worker process died", began - 1)
    assert begun.mcap == str(partial) and str(partial) in (begun.mcap_error or "")
    assert _lost(scenario, str(tmp_path / "none.mcap"), "died", began).mcap is None


def test_a_sigterm_in_a_scenarios_loop_ends_it_between_two_callbacks() -> None:
    # Raised wherever the signal landed, SIGTERM once broke into the loop's own bookkeeping
    # (a future set, its task's wakeup not yet scheduled): that task slept for ever and the
    # scenario ran on (1 SIGTERM in about 40, seen beside two busy loops). While a loop runs
    # the handler only asks the loop to raise it, from a callback of its own.
    import asyncio
    import signal

    from fpgalink.cli.termination import Terminated, on_sigterm

    ran: list[str] = []

    async def scenario() -> None:
        on_sigterm(signal.SIGTERM, None)  # as if the signal came now: nothing raised here
        ran.append("went on to the next await")
        await asyncio.sleep(3600)
        ran.append("never")

    with pytest.raises(Terminated):
        asyncio.run(scenario())
    assert ran == ["went on to the next await"]
    with pytest.raises(Terminated):  # no loop running: raised at once
        on_sigterm(signal.SIGTERM, None)
