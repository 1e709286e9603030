"""The seed's §3.6 measurements on both emulated bodies, the kinematic one and MuJoCo's: the
table docs/robot.md shows (tests/fpgaemu/test_seed_table.py asserts a shorter run of it).

* the turn rates and radii of §3.6.2–3.6.6 (3 s to settle, then 20 s measured; the MuJoCo
  body's figure is the mean over three friction fields, seeds 0–2, with their range);
* §3.6.3: how far the centre of a 60 s in-place turn on gravel wanders (seeds 0–2);
* §3.6.7: the rear wheels' PWM over the front wheels' up the 45° sandy slope;
* §3.6.8: the IMU down the 40° stair;
* the physics step halved (2 ms → 1 ms): how much each MuJoCo figure moves;
* odometry against truth after each of the seed's runs (its length), per body.

Run ``python -m benchmarks.seed_table`` from the repository root (a few minutes);
``--quick`` runs everything short (the smoke test). Emulated time only: the figures do not
depend on the machine's speed or load.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from typing import Any

from benchmarks._common import (
    common_parser,
    environment_line,
    print_table,
    report_header,
    write_results,
)
from fpgaemu import physics
from fpgaemu.timeline import ms
from tests.support.seedtable import (
    ODOMETRY_RUNS,
    SEED_RUNS,
    TOLERANCE,
    measure,
    odometry_against_truth,
    seed_figure,
    slope_pwm_ratio,
    stairs_imu,
)

NAME = "seed_table"
FIELDS = (0, 1, 2)


def table(settle: float, seconds: float, step_ms: int = 2) -> dict[str, Any]:
    """Every SEED_RUNS row on both bodies; runs shared between rows of the same run."""
    motions: dict[tuple[Any, ...], Any] = {}

    def motion(surface: str, left: float | None, right: float, body: str, seed: int) -> Any:
        key = (surface, left, right, body, seed)
        if key not in motions:
            options = {"physics_step_cycles": ms(step_ms)} if body == "mujoco" else {}
            motions[key] = measure(surface, left, right, body, settle=settle,
                                   seconds=seconds, seed=seed, **options)
        return motions[key]

    rows = {}
    for key, surface, left, right, quantity, seed, span, section in SEED_RUNS:
        kinematic = seed_figure(key, motion(surface, left, right, "kinematic", 0))
        fields = FIELDS if physics.SURFACES[surface].field_spread else (0,)
        figures = [seed_figure(key, motion(surface, left, right, "mujoco", f))
                   for f in fields]
        mujoco = sum(figures) / len(figures)
        rows[key] = {"section": section, "quantity": quantity, "seed": seed,
                     "seed_range": list(span), "kinematic": kinematic, "mujoco": mujoco,
                     "mujoco_fields": figures,
                     "kinematic_within": abs(kinematic / seed - 1) <= TOLERANCE,
                     "mujoco_within": abs(mujoco / seed - 1) <= TOLERANCE}
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    parser = common_parser(__doc__, NAME, "every run short (the smoke test)")
    args = parser.parse_args(argv)
    if not physics.available():
        print(f"seed_table: {physics.why_unavailable()}", file=sys.stderr)
        return 2
    started = time.perf_counter()
    settle, seconds = (0.5, 1.5) if args.quick else (3.0, 20.0)
    rows = table(settle, seconds)
    halved = table(settle, seconds, step_ms=1)
    step_change = {key: abs(halved[key]["mujoco"] / rows[key]["mujoco"] - 1) for key in rows}
    wander_s = 3.0 if args.quick else 60.0
    wander = [measure("gravel", 50, -50, "mujoco", settle=1.0, seconds=wander_s, seed=f)
              for f in FIELDS]
    slope = slope_pwm_ratio(seconds=1.0 if args.quick else 4.0)
    stairs = stairs_imu(seconds=12.0 if args.quick else 16.0)
    odometry: dict[str, dict[str, Any]] = {}
    for key, surface, left, right, length, section in ODOMETRY_RUNS:
        length = min(length, 1.0) if args.quick else length
        for body in ("kinematic", "mujoco"):
            if body == "kinematic" and surface not in ("gravel", "marble"):
                continue
            error = odometry_against_truth(surface, left, right, body, length)
            odometry[f"{key} {body}"] = {"section": section, "body": body,
                                         **error.__dict__}
    elapsed = time.perf_counter() - started
    payload: dict[str, Any] = {
        **report_header(NAME, ["mujoco"]),
        "config": {"quick": args.quick, "settle_s": settle, "measure_s": seconds,
                   "fields": list(FIELDS), "physics_step_ms": physics.STEP_CYCLES // ms(1),
                   "argv": sys.argv[1:] if argv is None else list(argv)},
        "table": rows,
        "step_halved": {"relative_change": step_change,
                        "largest": max(step_change.values())},
        "wander_60s": [{"seed": f, "span_x": w.span_x, "span_y": w.span_y,
                        "rate_dps": w.rate_dps} for f, w in zip(FIELDS, wander, strict=True)],
        "slope": slope,
        "stairs": stairs,
        "odometry": odometry,
        "timing": {"total_s": elapsed},
    }
    path = write_results(NAME, payload, args.output)
    print(f"the seed's §3.6 runs on both bodies (±{TOLERANCE:.0%}), "
          f"{settle:g} s settle + {seconds:g} s measured")
    print(environment_line(payload))
    print_table(
        ["run", "quantity", "seed", "kinematic", "diff", "MuJoCo (3 fields)", "diff",
         "step halved"],
        [[f"{r['section']} {key}", r["quantity"],
          f"{r['seed']:g}" if r["seed_range"][0] == r["seed_range"][1]
          else f"{r['seed_range'][0]:g}–{r['seed_range'][1]:g}",
          f"{r['kinematic']:.2f}", f"{r['kinematic'] / r['seed'] - 1:+.0%}",
          f"{r['mujoco']:.2f} ({min(r['mujoco_fields']):.2f}–{max(r['mujoco_fields']):.2f})",
          f"{r['mujoco'] / r['seed'] - 1:+.0%}", f"{step_change[key]:.1%}"]
         for key, r in rows.items()],
        align="<<>>>>>>")
    print()
    spans = ", ".join(f"{w.span_x:.2f} m × {w.span_y:.2f} m" for w in wander)
    print(f"§3.6.3 in-place turn on gravel, {wander_s:g} s: the centre wanders {spans} "
          "(seed: 0.22 m × 0.6 m); the kinematic body's does not move")
    print(f"§3.6.7 45° sandy slope at 15 deg/s: rear/front PWM {slope['ratio']:.2f} "
          f"(seed: 1.2); loads front {slope['front_load_n']:.0f} N, rear "
          f"{slope['rear_load_n']:.0f} N; climbed {slope['climbed_m']:.2f} m")
    print(f"§3.6.8 40° stair down at 25 deg/s: pitch up to {stairs['max_pitch_deg']:.1f}°, "
          f"descended {stairs['descended_m']:.2f} m; IMU level aX {stairs['ax_level']:+.2f} "
          f"aZ {stairs['az_level']:.2f} m/s², on the stair aX {stairs['ax_on_stair']:+.2f} "
          f"aZ {stairs['az_on_stair']:.2f} (g tilted {stairs['g_tilt_deg']:.0f}°)")
    print()
    print("odometry (the robot file's χ, 1 kHz telemetry) against truth at the end of each "
          "of the seed's runs")
    print_table(
        ["run", "body", "s", "travelled m", "turned °", "position error m",
         "heading error °"],
        [[key.rsplit(" ", 1)[0], o["body"], f"{o['seconds']:g}", f"{o['travelled']:.2f}",
          f"{o['turned_deg']:.0f}", f"{o['position']:.3f}", f"{o['heading_deg']:+.1f}"]
         for key, o in odometry.items()],
        align="<<>>>>>")
    print(f"\nlargest change with the step halved: {payload['step_halved']['largest']:.1%}; "
          f"{elapsed:.0f} s; results in {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
