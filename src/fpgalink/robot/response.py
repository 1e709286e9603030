"""A wheel's step response in figures: rise time, settling time, overshoot, steady-state
error (``fpgalink-cli step``, campaigns and ``tune``). Sans-I/O: samples in, figures out."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["RISE_HIGH", "RISE_LOW", "SETTLING_BAND", "STEADY_FRACTION", "StepMetrics",
           "step_metrics"]

RISE_LOW, RISE_HIGH = 0.1, 0.9  #: rise time is measured between 10 % and 90 % of the step
SETTLING_BAND = 0.02  #: settled once within ±2 % of the step size, for good
STEADY_FRACTION = 0.1  #: steady-state error: mean of the last 10 % of the hold

@dataclass(frozen=True, slots=True)
class StepMetrics:
    rise_time: float | None  #: s, 10 → 90 %; None if 90 % was never reached
    settling_time: float | None  #: s after the step; None if not settled by the end
    overshoot: float  #: % of the step size, ≥ 0
    steady_state_error: float  #: target − mean of the last 10 %, in the signal's unit
    peak: float
    rise_start: float | None = None  #: s, when 10 % of the step was first reached
    rise_end: float | None = None  #: s, when 90 % of the step was first reached


def step_metrics(t: list[float], y: list[float], start: float, target: float) -> StepMetrics:
    """Classic step-response figures of ``y(t)`` (``t`` = 0 at the step) for a step from
    ``start`` to ``target``. Works for downward steps too (everything relative to the step)."""
    if not t or len(t) != len(y):
        raise ValueError("need matching, non-empty time and value lists")
    size = target - start
    if size == 0:
        raise ValueError("the step has zero size")
    progress = [(v - start) / size for v in y]  # 0 at start, 1 at target
    t_low = next((ti for ti, p in zip(t, progress, strict=True) if p >= RISE_LOW), None)
    t_high = next((ti for ti, p in zip(t, progress, strict=True) if p >= RISE_HIGH), None)
    rise = t_high - t_low if t_low is not None and t_high is not None else None
    band = SETTLING_BAND
    outside = [i for i, p in enumerate(progress) if abs(p - 1.0) > band]
    if not outside:
        settling: float | None = t[0]
    elif outside[-1] == len(t) - 1:
        settling = None
    else:
        settling = t[outside[-1] + 1]
    peak_progress = max(progress)
    tail = y[-max(1, int(len(y) * STEADY_FRACTION)):]
    return StepMetrics(
        rise_time=rise,
        settling_time=settling,
        overshoot=max(0.0, (peak_progress - 1.0) * 100.0),
        steady_state_error=target - sum(tail) / len(tail),
        peak=start + peak_progress * size,
        rise_start=t_low,
        rise_end=t_high,
    )
