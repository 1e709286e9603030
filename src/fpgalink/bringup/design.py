"""Speed-PID gains from a fitted plant, and the closed loop they will give.

**The rule: SIMC (Skogestad 2003) PI, its one tuning knob τc chosen on the full model.**
With K the model's DC gain, τ its dominant time constant and θ the dead time of its
first-order-plus-dead-time summary (:meth:`~fpgalink.bringup.plant.ContinuousModel.fopdt`)::

    Kp = τ / (K·(τc + θ))        Ti = min(τ, 4·(τc + θ))        Td = 0

τc is the closed loop's time constant (SIMC's closed loop is e^(−θs)/(τc·s + 1)); Ti = τ
cancels the dominant pole. The summary hides the plant's faster poles (the seed's complex
pair near 23 rad/s) and the duty's clamp, so τc is not taken from a formula: of 60 values
from θ/4 to 2τ, the one whose closed loop — simulated on the *whole* fitted model with the
board's PID as the firmware runs it (period, clamp, conditional integration) and the
speed as the board's M/T counter measures it (:class:`MtCounter`: at low speed a count
comes less often than a period, and the loop starts blind until two edges have come), for
the step the user will take — settles soonest (2 %) while it overshoots by at most ``max_overshoot``
(2 %) and keeps a phase margin of ``min_phase_margin`` (45°) and a gain margin of
``min_gain_margin_db`` (6 dB): the margins so that a plant a little off the model still
behaves. No derivative: the encoder's quantisation is not amplified, and the PI
alone meets the targets on the seed's plants (docs/hardware.md has the figures).

:func:`predict_step` is the prediction a board's own step is held to: the model's output,
sampled by the board's timer, as its M/T counter measures it, through :class:`FirmwarePid`
— the speed PID of docs/emulator_models.md written out as the firmware computes it. On the
emulated board, whose plant is known, it gives the documented figures of the shipped gains
to the millisecond (the seed's converted: 0.715 s and 2.9 %; the defaults 0.538 s).

Sans-I/O, numpy only.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from fpgalink.bringup.plant import Array, ContinuousModel
from fpgalink.robot.response import StepMetrics, step_metrics

__all__ = [
    "Design",
    "DesignError",
    "FirmwarePid",
    "Gains",
    "Margins",
    "MtCounter",
    "confirms",
    "design_pi",
    "margins",
    "predict_step",
    "seed_gains",
]

MAX_DUTY = 32760
#: The firmware's derivative filter: time constant Td/N.
DERIVATIVE_FILTER_N = 10.0


class DesignError(ValueError):
    """No gains meet the targets on this model (the message says which failed)."""


@dataclass(frozen=True, slots=True)
class Gains:
    """The board's speed PID parameters: ``Kp_Wheel_Pid`` (PWM counts per deg/s),
    ``Ti_Wheel_Pid`` (s), ``Td_Wheel_Pid`` (s)."""

    kp: float
    ti: float
    td: float = 0.0


def seed_gains(gear: str) -> Gains:
    """The seed's §3.4 gains for ``gear`` (``high``, ``low``), converted to the board's
    units: the shipped parameter set ``seed-<gear>`` (docs/emulator_models.md), channel A."""
    from importlib import resources

    from fpgalink.protocol.paramfile import parse_parameter_file

    name = f"seed-{gear}.toml"
    text = resources.files("fpgalink.parameter_sets").joinpath(name).read_text("utf-8")
    values = {param.name: float(value) for param, channel, value
              in parse_parameter_file(text, name) if channel == 1}
    return Gains(values["Kp_Wheel_Pid"], values["Ti_Wheel_Pid"], values["Td_Wheel_Pid"])


class FirmwarePid:
    """The board's speed PID as the firmware runs it each timer period: standard form
    Kp·(e + ∫e/Ti + Td·d(−y)/dt), the derivative on the measurement filtered with Td/10,
    the output rounded and clamped to ±limit, the integral moved only out of the clamp."""

    def __init__(self, gains: Gains, limit: int) -> None:
        self.gains = gains
        self.limit = limit
        self.integral = 0.0
        self.derivative = 0.0
        self.last: float | None = None

    def __call__(self, reference: float, measured: float, dt: float) -> int:
        kp, ti, td = self.gains.kp, self.gains.ti, self.gains.td
        error = reference - measured
        if td > 0 and self.last is not None:
            raw = -kp * td * (measured - self.last) / dt
            self.derivative += (raw - self.derivative) * dt / (td / DERIVATIVE_FILTER_N + dt)
        self.last = measured
        increment = kp * dt / ti * error
        wanted = kp * error + self.integral + increment + self.derivative
        if wanted > self.limit:
            self.integral += min(increment, 0.0)
            return self.limit
        if wanted < -self.limit:
            self.integral += max(increment, 0.0)
            return -self.limit
        self.integral += increment
        return round(wanted)


class MtCounter:
    """The board's position counter and its time-and-count speed measurement, as
    docs/emulator_models.md ("Encoder") describes the FPGA block: the wheel at rest sits in
    the middle of a count; an edge each 360/counts_per_turn degrees, its time found with the
    angle taken as linear over each period; a reading is the counts since the reference edge
    over the time from it to the last edge; with no edge since the last reading it is at most
    one count over the time since the last edge, and 0 after :data:`SPEED_TIMEOUT_S`; the
    first edge after rest only becomes the reference. At low speed (45 deg/s is 0.6 counts a
    millisecond at 5,000 counts a turn) this is what the loop sees: a start that reads 0
    until two edges have come, then readings a count's time late."""

    SPEED_TIMEOUT_S = 1.0

    def __init__(self, counts_per_turn: int) -> None:
        self.step = 360.0 / counts_per_turn
        self.count = 0
        self.reference: tuple[float, int] | None = None  #: (time, count) of the reference edge
        self.last_edge: float | None = None
        self.reading = 0.0

    def move(self, t0: float, a0: float, t1: float, a1: float) -> None:
        """The wheel went from ``a0`` deg at ``t0`` to ``a1`` at ``t1`` (s)."""
        n0, n1 = math.floor(a0 / self.step + 0.5), math.floor(a1 / self.step + 0.5)
        if n0 == n1:
            return
        up = n1 > n0

        def crossing(boundary: int) -> float:
            fraction = ((boundary - 0.5) * self.step - a0) / (a1 - a0)
            return t0 + min(1.0, max(0.0, fraction)) * (t1 - t0)

        first = crossing(n0 + 1 if up else n0)
        if self.reference is None or self.last_edge is None or \
                first - self.last_edge > self.SPEED_TIMEOUT_S:
            self.reference = (first, n0 + 1 if up else n0 - 1)
        self.last_edge = crossing(n1 if up else n1 + 1)
        self.count = n1

    def read(self, now: float) -> float:
        reference, last = self.reference, self.last_edge
        if reference is None or last is None:
            self.reading = 0.0
        elif last > reference[0]:
            self.reading = (self.count - reference[1]) * self.step / (last - reference[0])
            self.reference = (last, self.count)
        elif now - last > self.SPEED_TIMEOUT_S:
            self.reading = 0.0
        elif now > last:
            self.reading = math.copysign(min(abs(self.reading), self.step / (now - last)),
                                         self.reading)
        return self.reading


def predict_step(model: ContinuousModel, gains: Gains, *, period: float, target: float,
                 limit: int = MAX_DUTY, duration: float = 3.0,
                 counts_per_turn: int | None = None) -> tuple[Array, Array, Array]:
    """The closed loop's response to a reference step 0 → ``target`` deg/s at t = 0 from
    rest: (times at each timer tick, the measured speed, the duty). Exact for the model:
    each mode integrated over the period with the duty held, the model's delay a whole
    number of periods; the measurement the board's M/T counter (:class:`MtCounter`) with
    ``counts_per_turn`` (10 × ``IncSenzRes``), or the mean speed over the period
    (``None``)."""
    steps = math.ceil(duration / period) + 1
    decay = [cmath.exp(p * period) for p in model.poles]
    # a mode's state after one period with unit duty held, and its mean over the period
    gain_end = [c * (d - 1.0) / p for c, d, p in zip(model.residues, decay, model.poles,
                                                       strict=True)]
    mean_from_state = [(d - 1.0) / (p * period) for d, p in zip(decay, model.poles,
                                                                  strict=True)]
    mean_from_input = [c / p * ((d - 1.0) / (p * period) - 1.0)
                       for c, d, p in zip(model.residues, decay, model.poles, strict=True)]
    lag = round(model.delay / period)
    pending = [0] * lag
    states = [0j] * len(model.poles)
    pid = FirmwarePid(gains, limit)
    counter = None if counts_per_turn is None else MtCounter(counts_per_turn)
    times, speeds, duties = np.empty(steps), np.empty(steps), np.empty(steps)
    measured = angle = 0.0
    for k in range(steps):
        duty = pid(target, measured, period)
        times[k], speeds[k], duties[k] = k * period, measured, duty
        pending.append(duty)
        applied = pending.pop(0)
        mean = 0.0
        for i, x in enumerate(states):
            mean += (x * mean_from_state[i] + applied * mean_from_input[i]).real
            states[i] = x * decay[i] + applied * gain_end[i]
        if counter is None:
            measured = mean
        else:
            counter.move(k * period, angle, (k + 1) * period, angle + mean * period)
            measured = counter.read((k + 1) * period)
        angle += mean * period
    return times, speeds, duties


@dataclass(frozen=True, slots=True)
class Margins:
    phase_margin: float  #: degrees at the gain crossover (inf: |L| never reaches 1)
    gain_margin_db: float  #: dB at the phase crossover (inf: the phase never reaches −180°)
    crossover: float  #: rad/s


def margins(model: ContinuousModel, gains: Gains, period: float) -> Margins:
    """The loop's stability margins on the model: L(jω) = C(jω)·G(jω)·e^(−jω·1.5·period)
    (the hold's half period and the M/T measurement's mean over the last period)."""
    omega = np.logspace(-2, math.log10(math.pi / period), 6000)
    s = 1j * omega
    controller = gains.kp * (1.0 + 1.0 / (gains.ti * s) + gains.td * s
                             / (1.0 + gains.td / DERIVATIVE_FILTER_N * s))
    loop = controller * model.frequency_response(omega) * np.exp(-s * 1.5 * period)
    magnitude = np.abs(loop)
    phase = np.unwrap(np.angle(loop))
    phase_margin, crossover = math.inf, math.nan
    above = np.nonzero(magnitude >= 1.0)[0]
    if above.size and above[-1] + 1 < len(omega):
        i = int(above[-1])
        crossover = float(omega[i])
        phase_margin = math.degrees(float(phase[i])) + 180.0
    gain_margin = math.inf
    below = np.nonzero(phase <= -math.pi)[0]
    if below.size:
        gain_margin = -20.0 * math.log10(float(magnitude[int(below[0])]))
    return Margins(phase_margin, gain_margin, crossover)


@dataclass(frozen=True, slots=True)
class Design:
    gains: Gains
    tau_c: float  #: s, the chosen closed-loop time constant
    prediction: StepMetrics
    margins: Margins
    target: float  #: deg/s, the step predicted
    period: float  #: s, the board's timer period the prediction is for
    rule: str


def _metrics(model: ContinuousModel, gains: Gains, period: float, target: float,
             limit: int, duration: float, counts_per_turn: int | None) -> StepMetrics:
    t, y, _ = predict_step(model, gains, period=period, target=target, limit=limit,
                           duration=duration, counts_per_turn=counts_per_turn)
    return step_metrics(list(t), list(y), 0.0, target)


def design_pi(model: ContinuousModel, *, period: float, target: float,
              limit: int = MAX_DUTY, max_overshoot: float = 2.0, min_phase_margin: float = 45.0,
              min_gain_margin_db: float = 6.0, counts_per_turn: int | None = None) -> Design:
    """The SIMC PI of the module's rule for ``model``, its step 0 → ``target`` predicted at
    the board's ``period``, duty ``limit`` and encoder resolution (:func:`predict_step`)."""
    summary = model.fopdt()
    gain, theta = summary.gain, summary.dead_time
    tau = model.time_constant
    if not (math.isfinite(gain) and gain != 0 and math.isfinite(tau) and tau > 0):
        raise DesignError(f"the model (K {gain:.4g}, τ {tau:.4g} s) makes no PI")
    if gain < 0:
        raise DesignError("the model's gain is negative (the speed falls as the duty rises): "
                          "count the encoder the other way (IncSenzCountDirection) first")
    duration = max(3.0, 12.0 * tau)
    floor = max(theta / 4.0, 2.0 * period)
    best: Design | None = None
    failures: list[str] = []
    for tau_c in np.geomspace(floor, 2.0 * tau, 60):
        tau_c = float(tau_c)
        gains = Gains(tau / (gain * (tau_c + theta)), min(tau, 4.0 * (tau_c + theta)))
        stability = margins(model, gains, period)
        if stability.phase_margin < min_phase_margin or \
                stability.gain_margin_db < min_gain_margin_db:
            failures.append(f"τc {tau_c:.3f} s: margins {stability.phase_margin:.0f}°, "
                            f"{stability.gain_margin_db:.1f} dB")
            continue
        metrics = _metrics(model, gains, period, target, limit, duration, counts_per_turn)
        if metrics.settling_time is None or metrics.overshoot > max_overshoot:
            failures.append(f"τc {tau_c:.3f} s: overshoot {metrics.overshoot:.1f} %")
            continue
        if best is None or metrics.settling_time < (best.prediction.settling_time
                                                    or math.inf) - 1e-9:
            rule = (f"SIMC PI on K {gain:.4g} deg/s per count, τ {tau:.3f} s (the dominant "
                    f"pole), θ {theta:.3f} s (the FOPDT summary's); τc {tau_c:.3f} s, the "
                    f"quickest to settle with overshoot ≤ {max_overshoot:g} %, phase margin ≥ "
                    f"{min_phase_margin:g}°, gain margin ≥ {min_gain_margin_db:g} dB on the "
                    "fitted model")
            best = Design(gains, tau_c, metrics, stability, target, period, rule)
    if best is None:
        raise DesignError("no τc meets the targets: " + "; ".join(failures[-3:]))
    return best


def confirms(predicted: StepMetrics, measured: StepMetrics, *, settling_tolerance: float = 0.25,
             settling_slack: float = 0.05, overshoot_slack: float = 2.0) -> tuple[bool, str]:
    """Whether a board's own step confirms a prediction: it settles, within
    ``settling_tolerance`` (25 %) + ``settling_slack`` (0.05 s) of the predicted 2 %
    settling time, and overshoots by at most ``overshoot_slack`` (2) percentage points more
    than predicted. (ok, why not)."""
    if measured.settling_time is None:
        return False, "the board's step did not settle within the hold"
    if predicted.settling_time is None:
        return False, "the prediction does not settle"
    allowed = predicted.settling_time * (1.0 + settling_tolerance) + settling_slack
    lowest = predicted.settling_time * (1.0 - settling_tolerance) - settling_slack
    if not lowest <= measured.settling_time <= allowed:
        return False, (f"settled in {measured.settling_time:.3f} s, predicted "
                       f"{predicted.settling_time:.3f} s (allowed {max(lowest, 0):.3f}–"
                       f"{allowed:.3f} s)")
    if measured.overshoot > predicted.overshoot + overshoot_slack:
        return False, (f"overshoot {measured.overshoot:.1f} %, predicted "
                       f"{predicted.overshoot:.1f} % (+{overshoot_slack:g} allowed)")
    return True, "the board's step matches the prediction"
