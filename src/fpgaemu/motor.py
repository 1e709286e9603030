"""The motors and wheels: the physical world the board's PWM stages drive and its encoders and
Hall sensors observe. Each wheel is a plant identified in the seed (SPEC §6).

The seed identified wheel speed against PWM at Ts = 0.05 s:

    high gear  H(z) = (−0.07017 z⁻² − 0.053 z⁻¹) / (1 − 1.393 z⁻¹ + 0.7321 z⁻² − 0.2117 z⁻³)
    low gear   H(z) = (−0.0291 z⁻² − 0.009263 z⁻¹) / (1 − 1.394 z⁻¹ + 0.7058 z⁻² − 0.198 z⁻³)

The continuous-time model behind it:

* Poles: sᵢ = ln(pᵢ)/Ts for each root of the denominator. Both gears have one real positive
  pole and a complex pair, so the logarithm is well defined (a real negative pole, which
  rings at Nyquist and has no continuous image, would be mapped to ln|p|/Ts and lose its
  alternation; `continuous_model` does that, neither gear needs it). High gear: −4.15 and
  −13.5 ± 19.3j rad/s (dominant τ = 0.24 s); low gear: −3.69 and −14.4 ± 19.1j rad/s.
* Zeros: the identified zeros (−1.32 high, −3.14 low) are negative real, sampling zeros of
  the zero-order hold with no continuous image. The continuous model whose ZOH is exactly
  H(z) exists but is non-minimum-phase (a right-half-plane zero at +2069 rad/s in high gear
  and +82 rad/s in low): a motor driven forward would first turn backwards (in low gear by
  0.1 deg/s), and the wheel would dither across an encoder count at start. So instead the
  model has the poles above and one real zero s = −c, with c fitted so that the continuous
  step response, sampled at Ts, matches the identified one in least squares. The response
  is linear in 1/c, so the fit is one projection (`continuous_model`). Fitted c: 67.5 rad/s
  (high), 200 rad/s (low); the sampled step response then matches H(z) within 0.03 % (high)
  and 0.8 % (low) of its final value (without the zero: 4.8 % and 1.6 %).
* DC gain: the identified one (the zero and the pole mapping keep it), then scaled below.

The model is stepped in modal form, Σ rᵢ/(s − sᵢ), which integrates *any* interval exactly
for a constant input, so the board can advance the wheel to the exact cycle a PWM value
changes, and the wheel angle is the exact integral of the speed.

Scaling: the identification's negative sign is the encoder's counting direction; physical
speed is positive for positive duty. Full duty (32760) gives 90 deg/s in high gear; low
gear keeps the identified ratio of DC gains (0.349), so about 31 deg/s at full duty.

Current: the winding of a DC motor behind the 1:70 gearbox, L·di/dt = V·duty − k_e·ω_motor −
R·i, integrated exactly over each step with the step's mean speed (R = 1 Ω, L = 1 mH: an
electrical time constant of 1 ms, a pole at 1,000 rad/s that the seed's identification at
Ts = 0.05 s — Nyquist 63 rad/s — could not have seen, so the identified speed response is
untouched; k_e puts the back-EMF at 90 % of the supply at full speed, which leaves 2.4 A of
friction current at full duty). The current does not feed back into the speed plant: the
identified response from duty to speed already contains the motor's dynamics. A load
torque acts as an input disturbance in the same units; a stalled wheel holds speed 0 and
its current rises to V·duty/R. The Hall sensor reads the current, with optional seeded
Gaussian noise (``Motors(current_noise_a=…)``).

:class:`Motors` attaches the two wheels to a board: each channel's PWM output drives its
wheel, the wheel turns that channel's encoder, the Hall sensor reads the motor current.
The physics is integrated lazily, up to each cycle the PWM output changes and each cycle the
processor samples (:meth:`fpgaemu.board.Board.settle`), in steps of at most 1 ms so encoder
edges follow the wheel closely.
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final

from fpgaemu.timeline import CLOCK_HZ, ms

if TYPE_CHECKING:
    from fpgaemu.board import Board, ChannelIo
    from fpgaemu.encoder import QuadratureEncoder

__all__ = [
    "GEARS",
    "PHYSICS_STEP_CYCLES",
    "REST_CURRENT_A",
    "REST_SPEED_DPS",
    "ContinuousModel",
    "DriveTrain",
    "DrivenMotors",
    "MotorConstants",
    "Motors",
    "WheelDrive",
    "WheelPlant",
    "continuous_model",
    "drive_train",
    "identified_response",
    "turn",
]

#: The wheels are integrated at least this often, so encoder edges follow them closely.
PHYSICS_STEP_CYCLES: Final = ms(1)

SEED_TS: Final = 0.05
#: numerator (z⁻¹, z⁻²) and denominator (z⁻¹, z⁻², z⁻³) coefficients
GEARS: dict[str, tuple[tuple[float, float], tuple[float, float, float]]] = {
    "high": ((-0.053, -0.07017), (-1.393, 0.7321, -0.2117)),
    "low": ((-0.009263, -0.0291), (-1.394, 0.7058, -0.198)),
}
MAX_DUTY: Final = 32760
MAX_SPEED_HIGH_DPS: Final = 90.0
#: Static friction's dead band: an unpowered, unloaded wheel whose motion can no longer
#: exceed this speed (deg/s at the wheel; one encoder count, 0.072°, would take 72 s) is
#: held by it and stops, having rolled out the rest of its decay at once. Without it the
#: linear model's modes decay towards zero for minutes (until float underflow), and a board
#: that has been driven never counts as at rest again.
REST_SPEED_DPS: Final = 1e-3
#: Below this an unpowered winding's current is zero (the Hall sensor's noise is far above).
REST_CURRENT_A: Final = 1e-6
GEAR_RATIO: Final = 70.0
_radians = math.radians


@dataclass(frozen=True, slots=True)
class MotorConstants:
    """A plausible 24 V geared DC motor (the seed gives only the gearbox and wheel speed)."""

    supply_v: float = 24.0
    resistance_ohm: float = 1.0
    inductance_h: float = 1e-3
    #: back-EMF constant; 90 % of the supply at full wheel speed leaves 2.4 A of friction
    #: current at full duty
    ke_v_s_per_rad: float = 0.9 * 24.0 / (GEAR_RATIO * MAX_SPEED_HIGH_DPS * cmath.pi / 180)

    @property
    def stall_torque_wheel_nm(self) -> float:
        """Wheel torque at full duty and zero speed (k_t = k_e in SI units)."""
        return self.ke_v_s_per_rad * self.supply_v / self.resistance_ohm * GEAR_RATIO


def _roots_cubic(a1: float, a2: float, a3: float) -> list[complex]:
    import numpy as np

    return [complex(r) for r in np.roots([1.0, a1, a2, a3])]


@dataclass(frozen=True, slots=True)
class ContinuousModel:
    """G(s) = dc_gain · (1 + s/zero_c) · Π(−sᵢ) / Π(s − sᵢ), per unit of duty/32760, with the
    seed's sign (scaled to deg/s by :class:`WheelPlant`)."""

    poles: tuple[complex, ...]
    zero_c: float  #: the real zero is at s = −zero_c
    dc_gain: float

    def residues(self) -> list[complex]:
        """rᵢ of G(s) = Σ rᵢ / (s − sᵢ)."""
        prod_neg = complex(1.0)
        for p in self.poles:
            prod_neg *= -p
        out = []
        for i, p in enumerate(self.poles):
            others = complex(1.0)
            for j, q in enumerate(self.poles):
                if j != i:
                    others *= p - q
            out.append(self.dc_gain * (1.0 + p / self.zero_c) * prod_neg / others)
        return out

    def step_response(self, times_s: list[float]) -> list[float]:
        residues = self.residues()
        return [sum(((r * (cmath.exp(p * t) - 1) / p).real
                     for p, r in zip(self.poles, residues, strict=True)), 0.0) for t in times_s]


def continuous_model(gear: str) -> ContinuousModel:
    """Mapped poles, fitted real zero, identified DC gain (see the module docstring)."""
    (b1, b2), (a1, a2, a3) = GEARS[gear]
    poles = []
    for p in _roots_cubic(a1, a2, a3):
        if abs(p.imag) < 1e-12 and p.real < 0:
            poles.append(complex(cmath.log(abs(p.real)).real / SEED_TS))
        else:
            poles.append(cmath.log(p) / SEED_TS)
    dc_gain = (b1 + b2) / (1 + a1 + a2 + a3)
    samples = 80  # 4 s: the whole visible transient of either gear
    times = [k * SEED_TS for k in range(samples)]
    target = identified_response(gear, [1.0] * samples)
    # A ZOH discretisation's step response equals the continuous one at the sample
    # instants, so compare there (both start at 0: H(z) has its nk = 1 sample delay).
    base = ContinuousModel(tuple(poles), float("inf"), dc_gain)
    y0 = base.step_response(times)
    residues = base.residues()
    # With the zero, y(t) = y0(t) + (1/c)·Σ rᵢ(e^{sᵢt} − 1): linear in 1/c.
    # Sums from 0.0 (the same floats as from sum()'s int 0, which the compiled build cannot
    # add floats to).
    y1 = [sum(((r * (cmath.exp(p * t) - 1)).real
               for p, r in zip(poles, residues, strict=True)), 0.0) for t in times]
    inv_c = (sum(((a - b) * c for a, b, c in zip(target, y0, y1, strict=True)), 0.0)
             / sum((c * c for c in y1), 0.0))
    return ContinuousModel(tuple(poles), 1.0 / inv_c, dc_gain)


def _dc_gain(gear: str) -> float:
    (b1, b2), (a1, a2, a3) = GEARS[gear]
    return (b1 + b2) / (1 + a1 + a2 + a3)


def identified_response(gear: str, inputs: list[float]) -> list[float]:
    """The seed's difference equation itself, for checking the modal model."""
    (b1, b2), (a1, a2, a3) = GEARS[gear]
    y = [0.0, 0.0, 0.0]
    u = [0.0, 0.0]
    out = []
    for value in inputs:
        new = b1 * u[0] + b2 * u[1] - a1 * y[0] - a2 * y[1] - a3 * y[2]
        out.append(new)
        y = [new, y[0], y[1]]
        u = [value, u[0]]
    return out


class WheelPlant:
    """One wheel: ``advance(seconds)`` with the duty held, then read ``speed_dps``,
    ``angle_deg`` and ``current_a``."""

    def __init__(self, gear: str = "high", motor: MotorConstants | None = None) -> None:
        if gear not in GEARS:
            raise ValueError(f"gear must be one of {sorted(GEARS)}, got {gear!r}")
        self.gear = gear
        self.motor = motor or MotorConstants()
        model = continuous_model(gear)
        dc_gain = model.dc_gain
        high_dc = _dc_gain("high")
        # Output in deg/s per unit input, sign flipped to physical; input is duty/32760.
        scale = MAX_SPEED_HIGH_DPS / high_dc
        self._s = list(model.poles)
        self._b = [complex(1.0)] * 3
        self._c = [r * scale for r in model.residues()]
        # The three modes' states, complex, each held as its real and imaginary parts (the
        # compiled build's arithmetic on them is then on machine floats; the formulas are
        # Python's own complex arithmetic, term for term, so both builds round alike).
        self._x0_re = self._x0_im = self._x1_re = self._x1_im = self._x2_re = self._x2_im = 0.0
        self.max_speed_dps = MAX_SPEED_HIGH_DPS * dc_gain / high_dc
        self.duty = 0
        self.load_torque_nm = 0.0  #: at the wheel; positive opposes positive speed
        self.stalled = False
        self.angle_deg = 0.0
        self.current = 0.0  #: A, the winding current (the state)
        self._steps: dict[float, _ModalStep] = {}
        self._decay: dict[float, float] = {}

    @property
    def _x(self) -> list[complex]:
        """The three modes' states."""
        return [complex(self._x0_re, self._x0_im), complex(self._x1_re, self._x1_im),
                complex(self._x2_re, self._x2_im)]

    def _rest_modes(self) -> None:
        self._x0_re = self._x0_im = self._x1_re = self._x1_im = self._x2_re = self._x2_im = 0.0

    @property
    def _moving(self) -> bool:
        """Any mode's state not zero."""
        return bool(self._x0_re or self._x0_im or self._x1_re or self._x1_im
                    or self._x2_re or self._x2_im)

    @property
    def speed_dps(self) -> float:
        if self.stalled:
            return 0.0
        total = 0.0
        for c, x in zip(self._c, self._x, strict=True):
            total += (c * x).real
        return total

    @property
    def current_a(self) -> float:
        return self.current

    def _follow_current(self, dt: float, mean_speed_dps: float) -> None:
        """The winding current over ``dt`` with the duty held and the wheel at its mean
        speed: exact for a first-order circuit with constant input."""
        m = self.motor
        decay = self._decay.get(dt)
        if decay is None:
            decay = math.exp(-dt * m.resistance_ohm / m.inductance_h)
            if len(self._decay) < 64:
                self._decay[dt] = decay
        steady = (m.supply_v * self.duty / MAX_DUTY
                  - m.ke_v_s_per_rad * (_radians(mean_speed_dps) * GEAR_RATIO)
                  ) / m.resistance_ohm
        self.current = steady + (self.current - steady) * decay

    def _input(self) -> float:
        # A load torque is the duty it would take to hold it at stall.
        return self.duty / MAX_DUTY - self.load_torque_nm / self.motor.stall_torque_wheel_nm

    def _step(self, dt: float) -> _ModalStep:
        step = self._steps.get(dt)
        if step is None:
            coefficients = []
            for s, b, c in zip(self._s, self._b, self._c, strict=True):
                e = cmath.exp(s * dt)
                phi = (e - 1) / s  # ∫ e^{sτ} dτ over the step
                # state update (e, input gain) and the angle it adds (from state, from input)
                coefficients.append((e, phi * b, c * phi, c * (phi - dt) / s * b))
            step = _ModalStep(coefficients)
            if len(self._steps) < 64:
                self._steps[dt] = step
        return step

    def advance(self, dt: float) -> tuple[float, float]:
        """Hold the duty for ``dt`` seconds; returns (angle at start, speed at start) so a
        caller can interpolate within the step."""
        angle0, speed0 = self.angle_deg, self.speed_dps
        if dt > 0:
            self.hold(dt)
        return angle0, speed0

    def hold(self, dt: float) -> None:
        """:meth:`advance` for a caller that needs neither starting figure (``dt`` > 0): the
        physics step every emulated millisecond, so it skips what :meth:`advance` reports."""
        if self.stalled:
            self._follow_current(dt, 0.0)
            if not self.duty and abs(self.current) < REST_CURRENT_A:
                self.current = 0.0
            return
        # Unloaded (the usual case) the input is the duty alone: the same value, no division.
        u = self._input() if self.load_torque_nm else self.duty / MAX_DUTY
        k = self._step(dt)
        # Per mode, the angle it adds, (s·x + i·u).real, and its next state, e·x + g·u, with
        # u as the complex (u, 0.0), as Python multiplies a complex by a float; the angle
        # summed from 0.0 in mode order, as a loop would.
        x_re, x_im = self._x0_re, self._x0_im
        angle_gain = 0.0 + ((k.s0_re * x_re - k.s0_im * x_im) + (k.i0_re * u - k.i0_im * 0.0))
        self._x0_re = (k.e0_re * x_re - k.e0_im * x_im) + (k.g0_re * u - k.g0_im * 0.0)
        self._x0_im = (k.e0_re * x_im + k.e0_im * x_re) + (k.g0_re * 0.0 + k.g0_im * u)
        x_re, x_im = self._x1_re, self._x1_im
        angle_gain += (k.s1_re * x_re - k.s1_im * x_im) + (k.i1_re * u - k.i1_im * 0.0)
        self._x1_re = (k.e1_re * x_re - k.e1_im * x_im) + (k.g1_re * u - k.g1_im * 0.0)
        self._x1_im = (k.e1_re * x_im + k.e1_im * x_re) + (k.g1_re * 0.0 + k.g1_im * u)
        x_re, x_im = self._x2_re, self._x2_im
        angle_gain += (k.s2_re * x_re - k.s2_im * x_im) + (k.i2_re * u - k.i2_im * 0.0)
        self._x2_re = (k.e2_re * x_re - k.e2_im * x_im) + (k.g2_re * u - k.g2_im * 0.0)
        self._x2_im = (k.e2_re * x_im + k.e2_im * x_re) + (k.g2_re * 0.0 + k.g2_im * u)
        self.angle_deg += angle_gain
        self._follow_current(dt, angle_gain / dt)
        if not u:
            self._come_to_rest()

    def _come_to_rest(self) -> None:
        """Unpowered and unloaded: within the dead band the wheel stops (see
        :data:`REST_SPEED_DPS`). Each mode only decays from here, so the bound on the speed
        is the sum of the modes' magnitudes, and the angle the decay would still add is
        added now, so the wheel rests where the model's motion would have ended."""
        c, x = self._c, self._x
        if (x[0] or x[1] or x[2]) and (abs(c[0] * x[0]) + abs(c[1] * x[1])
                                       + abs(c[2] * x[2])) < REST_SPEED_DPS:
            s = self._s
            self.angle_deg += (-(c[0] * x[0] / s[0] + c[1] * x[1] / s[1]
                                 + c[2] * x[2] / s[2])).real
            self._rest_modes()
        if self.current and abs(self.current) < REST_CURRENT_A and not self._moving:
            self.current = 0.0

    @property
    def at_rest(self) -> bool:
        """Exactly still, unpowered and unloaded: advancing changes nothing at all (true
        from power-up until driven; after being driven, once its motion has decayed into
        static friction's dead band, :data:`REST_SPEED_DPS`, a few seconds after the duty
        went to 0)."""
        return (self.duty == 0 and self.current == 0.0 and self.load_torque_nm == 0.0
                and not self._moving)

    def stall(self, stalled: bool = True) -> None:
        """Block the wheel (or free it): a blocked wheel's dynamics restart from rest."""
        self.stalled = stalled
        if stalled:
            self._rest_modes()


class _ModalStep:
    """What one step of a given length does to each of the three modes: its state update
    ``e`` and input gain ``g``, and the angle it adds from its state ``s`` and from the
    input ``i``; each complex, as its real and imaginary parts."""

    def __init__(self, coefficients: list[tuple[complex, complex, complex, complex]]
                 ) -> None:
        (e0, g0, s0, i0), (e1, g1, s1, i1), (e2, g2, s2, i2) = coefficients
        self.e0_re, self.e0_im, self.g0_re, self.g0_im = e0.real, e0.imag, g0.real, g0.imag
        self.s0_re, self.s0_im, self.i0_re, self.i0_im = s0.real, s0.imag, i0.real, i0.imag
        self.e1_re, self.e1_im, self.g1_re, self.g1_im = e1.real, e1.imag, g1.real, g1.imag
        self.s1_re, self.s1_im, self.i1_re, self.i1_im = s1.real, s1.imag, i1.real, i1.imag
        self.e2_re, self.e2_im, self.g2_re, self.g2_im = e2.real, e2.imag, g2.real, g2.imag
        self.s2_re, self.s2_im, self.i2_re, self.i2_im = s2.real, s2.imag, i2.real, i2.imag


def turn(wheel: WheelPlant, encoder: QuadratureEncoder, start: int, end: int) -> None:
    """Hold ``wheel``'s duty from cycle ``start`` to ``end``, feeding ``encoder`` the angle
    at least every :data:`PHYSICS_STEP_CYCLES`."""
    c0 = start
    while c0 < end:
        c1 = min(end, c0 + PHYSICS_STEP_CYCLES)
        angle0 = wheel.angle_deg
        wheel.hold((c1 - c0) / CLOCK_HZ)
        encoder.follow(c0, angle0, c1, wheel.angle_deg)
        c0 = c1


class BoardMotors:
    """A board's two channels' motors and wheels as one peripheral, wired to its PWM stages,
    encoders and current (Hall) sensors: what :class:`Motors` and :class:`DrivenMotors`
    share. A subclass has its wheels, wires each channel's (:meth:`wire`) and integrates
    them (:meth:`advance_to`, called at every PWM change and whenever the board settles)."""

    def __init__(self, gear: str = "high", current_noise_a: float = 0.0) -> None:
        if not (math.isfinite(current_noise_a) and current_noise_a >= 0):
            raise ValueError(f"current_noise_a must be ≥ 0 A, got {current_noise_a!r}")
        self.gear = gear
        self.current_noise_a = current_noise_a
        self._board: Board | None = None
        self._cycle = 0
        self._noise: Any = None

    def attach(self, board: Board) -> None:
        """Wire the wheels to ``board``'s PWM stages and encoders. Attached again after a
        power cycle (:meth:`fpgaemu.board.Board.power_cycle`), the wheels are the same
        ones, turning on: only the board's counters start again, from their present
        angles (:meth:`wire`)."""
        self._board = board
        self._cycle = board.now
        if self.current_noise_a > 0 and self._noise is None:
            self._noise = board.timeline.rng("hall")
        for code, io in board.channels.items():
            self.wire(code, io)
            io.pwm.on_change(self.advance_to)
        board.on_settle(self.advance_to)

    def wire(self, code: int, io: ChannelIo) -> None:
        """Channel ``code``'s wheel: made at the first attach, its encoder and current
        sensor powered up from where it is at the next."""
        raise NotImplementedError

    def advance_to(self, cycle: int) -> None:
        raise NotImplementedError


class Motors(BoardMotors):
    """Both channels' motor and wheel, attached to a board's PWM stages, encoders and
    current sensors (a board peripheral)."""

    def __init__(self, gear: str = "high", current_noise_a: float = 0.0) -> None:
        super().__init__(gear, current_noise_a)
        self.wheels: dict[int, WheelPlant] = {}

    def wire(self, code: int, io: ChannelIo) -> None:
        wheel = self.wheels.get(code)
        if wheel is None:
            self.wheels[code] = WheelPlant(self.gear)
        else:
            io.encoder.power_up(wheel.angle_deg)
            io.current_a = wheel.current

    @property
    def at_rest(self) -> bool:
        """Every wheel exactly still, unpowered and unloaded (see :attr:`WheelPlant.at_rest`)."""
        return all(wheel.at_rest for wheel in self.wheels.values())

    def advance_to(self, cycle: int) -> None:
        """Integrate both wheels up to ``cycle`` with the duty their PWM applies now."""
        start = self._cycle
        if cycle <= start:
            return
        assert self._board is not None
        channels = self._board.channels
        one_step = cycle - start <= PHYSICS_STEP_CYCLES
        for code, wheel in self.wheels.items():
            io = channels[code]
            pwm = io.pwm
            wheel.duty = pwm.applied_duty
            if wheel.at_rest:
                pass  # advancing changes nothing (an idle robot's long quiet stretches)
            elif one_step:  # turn() in one step, the usual case
                angle0 = wheel.angle_deg
                wheel.hold((cycle - start) / CLOCK_HZ)
                io.encoder.follow(start, angle0, cycle, wheel.angle_deg)
            else:
                turn(wheel, io.encoder, start, cycle)
            io.current_a = wheel.current if self._noise is None else (
                wheel.current + float(self._noise.normal(0.0, self.current_noise_a)))
        self._cycle = cycle


# --- the wheel as a torque source, for a body whose physics turns it --------------------------


@dataclass(frozen=True, slots=True)
class DriveTrain:
    """The motor and gearbox of one wheel as a two-mass system, in wheel units (everything
    reflected through the gearbox): the motor's rotor (``rotor_inertia``, with its own
    friction ``rotor_friction`` and the winding's torque) is coupled to the wheel side
    (``wheel_inertia``) by a compliant transmission (``stiffness``, ``damping``), and the
    ground loads the wheel side. The winding: ``L·di/dt = V·duty − k·ω_rotor − R·i``, torque
    ``k·i`` (``k`` = ``torque_constant``, k_t = k_e in SI units).

    The parameters are solved so that, with the wheel in the air, duty → wheel speed is the
    seed's identified model (:func:`continuous_model`: three poles and a real zero) with its
    DC gain (:func:`drive_train`); the winding adds a pole near R/L = 1,000 rad/s that the
    identification at Ts = 0.05 s could not see."""

    gear: str
    rotor_inertia: float  #: kg·m²
    wheel_inertia: float  #: kg·m²
    stiffness: float  #: N·m/rad, rotor to wheel
    damping: float  #: N·m·s/rad, rotor to wheel
    rotor_friction: float  #: N·m·s/rad, viscous, on the rotor
    torque_constant: float  #: N·m/A (= V·s/rad) at the wheel
    motor: MotorConstants

    @property
    def stall_torque_nm(self) -> float:
        """Wheel torque at full duty, at rest: k·V/R."""
        return self.torque_constant * self.motor.supply_v / self.motor.resistance_ohm


def drive_train(gear: str = "high", motor: MotorConstants | None = None) -> DriveTrain:
    """The two-mass drive whose air response is the identified model of ``gear``.

    With the rotor carrying all viscous friction (b = back-EMF k²/R + ``rotor_friction``)
    and none on the wheel side, G(s) = k·V/R · (c·s + K) / (J_m·J_w·s³ + (b·J_w + c·J)·s² +
    (K·J + c·b)·s + K·b), J = J_m + J_w. Matching the identified denominator
    s³ + a₂s² + a₁s + a₀, zero −z and DC gain ω_max/V·R/k gives, in turn, b = stall torque /
    full speed, q = K/(J_m·J_w) = a₀/b, J = (a₁ − q·b/z)/q, J_m = b/(a₂ − q·J/z), J_w =
    J − J_m, K = q·J_m·J_w, c = K/z. The low gear is a different reduction of the same motor:
    its torque constant at the wheel is the high gear's over the ratio of their full-duty
    speeds (0.349), so its stall torque is about 950 N·m (the seed's §3.1 gives 1,000 N·m as
    the robot's maximum wheel torque)."""
    motor = motor or MotorConstants()
    model = continuous_model(gear)
    p0, p1, p2 = model.poles
    a2 = -(p0 + p1 + p2).real
    a1 = (p0 * p1 + p0 * p2 + p1 * p2).real
    a0 = -(p0 * p1 * p2).real
    full_speed = _radians(MAX_SPEED_HIGH_DPS * model.dc_gain / _dc_gain("high"))
    k_high = motor.ke_v_s_per_rad * GEAR_RATIO
    k = k_high * _radians(MAX_SPEED_HIGH_DPS) / full_speed
    b = k * motor.supply_v / motor.resistance_ohm / full_speed
    z = model.zero_c
    q = a0 / b
    total = (a1 - q * b / z) / q
    rotor = b / (a2 - q * total / z)
    wheel = total - rotor
    stiffness = q * rotor * wheel
    back_emf = k * k / motor.resistance_ohm
    if min(rotor, wheel, stiffness, b - back_emf) <= 0:  # pragma: no cover - model data
        raise ValueError(f"no passive two-mass drive matches the {gear} gear's model")
    return DriveTrain(gear, rotor, wheel, stiffness, stiffness / z, b - back_emf, k, motor)


class WheelDrive:
    """One wheel's motor as a torque source for a body's physics: the winding's current
    (exact over any interval with the duty and the rotor's speed held) and the torque it
    gives; the wheel's angle comes from the physics (:meth:`follow_physics`), one physics
    step at a time, and is interpolated linearly within the step for the encoder.

    It has :class:`WheelPlant`'s reading interface (``duty``, ``speed_dps``, ``angle_deg``,
    ``current_a``, ``stall``, ``at_rest``), so the board cannot tell them apart."""

    def __init__(self, train: DriveTrain) -> None:
        self.train = train
        self.duty = 0
        self.current = 0.0  #: A
        self.stalled = False
        #: the physics step the wheel is in: (cycle, angle deg) at its start and end, and
        #: the rotor's mean speed over it (rad/s at the wheel, for the back-EMF)
        self._c0 = 0
        self._a0 = 0.0
        self._c1 = 0
        self._a1 = 0.0
        self.rotor_speed = 0.0
        self.wheel_speed_dps = 0.0  #: the wheel's speed at the end of the step
        m = train.motor
        self._tau = m.inductance_h / m.resistance_ohm
        self._decay: dict[int, float] = {}
        #: set by the body: whether its physics is asleep (nothing moves until driven)
        self.body_asleep = True
        #: the body's hook for :meth:`stall` (it holds the wheel's joint)
        self.on_stall: Callable[[WheelDrive], None] | None = None

    @property
    def speed_dps(self) -> float:
        return 0.0 if self.stalled else self.wheel_speed_dps

    @property
    def angle_deg(self) -> float:
        return self._a1

    @property
    def current_a(self) -> float:
        return self.current

    def angle_at(self, cycle: int) -> float:
        """The wheel's angle (deg) at ``cycle`` within the present physics step."""
        c0, c1 = self._c0, self._c1
        if cycle >= c1 or c1 == c0:
            return self._a1
        if cycle <= c0:
            return self._a0
        return self._a0 + (self._a1 - self._a0) * (cycle - c0) / (c1 - c0)

    def follow_physics(self, cycle0: int, cycle1: int, angle_deg: float, speed_dps: float,
                       rotor_speed: float) -> None:
        """The physics has moved the wheel to ``angle_deg`` at ``cycle1`` (from where it was
        at ``cycle0``), with the rotor at ``rotor_speed`` (rad/s, its mean over the step)."""
        self._c0, self._a0 = cycle0, self._a1
        self._c1, self._a1 = cycle1, angle_deg
        self.wheel_speed_dps = speed_dps
        self.rotor_speed = rotor_speed

    def hold_current(self, cycles: int) -> None:
        """The winding over ``cycles`` with the duty and the rotor's speed held (exact)."""
        m = self.train.motor
        decay = self._decay.get(cycles)
        if decay is None:
            decay = math.exp(-cycles / CLOCK_HZ / self._tau)
            if len(self._decay) < 64:
                self._decay[cycles] = decay
        steady = (m.supply_v * self.duty / MAX_DUTY
                  - self.train.torque_constant * self.rotor_speed) / m.resistance_ohm
        self.current = steady + (self.current - steady) * decay
        if not self.duty and abs(self.current) < REST_CURRENT_A and not self.rotor_speed:
            self.current = 0.0

    def torque_over(self, seconds: float) -> float:
        """The winding's mean torque (N·m at the wheel) over the next ``seconds`` if the duty
        and the rotor's speed stay as they are (exact then): what the physics applies over
        its next step."""
        m = self.train.motor
        steady = (m.supply_v * self.duty / MAX_DUTY
                  - self.train.torque_constant * self.rotor_speed) / m.resistance_ohm
        share = self._tau / seconds * (1.0 - math.exp(-seconds / self._tau))
        return self.train.torque_constant * (steady + (self.current - steady) * share)

    @property
    def at_rest(self) -> bool:
        """Unpowered, no current, and the body's physics asleep: nothing will move."""
        return self.duty == 0 and self.current == 0.0 and self.body_asleep

    def stall(self, stalled: bool = True) -> None:
        """Block the wheel (the physics holds its joint while this is set)."""
        self.stalled = stalled
        if self.on_stall is not None:
            self.on_stall(self)


class DrivenMotors(BoardMotors):
    """:class:`Motors` for a board whose wheels a body's physics turns (a board peripheral):
    each channel's PWM drives a :class:`WheelDrive`, whose current the Hall sensor reads and
    whose wheel (moved by the physics) turns the channel's encoder. The physics is stepped
    by its owner (:class:`fpgaemu.robot.EmulatedRobot`), which hands each drive the wheel's
    motion over a step before the board runs through it."""

    def __init__(self, gear: str = "high", current_noise_a: float = 0.0) -> None:
        super().__init__(gear, current_noise_a)
        self.train = drive_train(gear)
        self.wheels: dict[int, WheelDrive] = {}

    def wire(self, code: int, io: ChannelIo) -> None:
        """After a power cycle the drives are the same ones, which the body's physics
        holds: their wheels turn on, the power-up board's PWM (0) drives them from now on,
        and only its counters start again, from the wheels' present angles. (New drives
        here left the physics driving the old ones at the duty they had when the power
        went, and the board counting wheels that never turned: odometry saw half the
        motion.)"""
        wheel = self.wheels.get(code)
        if wheel is None:
            self.wheels[code] = WheelDrive(self.train)
        else:
            wheel.duty = 0  # the power-up PWM, until the board's next write
            io.encoder.power_up(wheel.angle_deg)
            io.current_a = wheel.current

    @property
    def at_rest(self) -> bool:
        return all(wheel.at_rest for wheel in self.wheels.values())

    def prepare_step(self, cycle: int) -> None:
        """Before the physics steps from ``cycle``: the windings up to it, and each drive's
        duty as its PWM applies it now (a write at this very cycle included)."""
        self.advance_to(cycle)
        assert self._board is not None
        channels = self._board.channels
        for code, wheel in self.wheels.items():
            pwm = channels[code].pwm
            wheel.duty = pwm.duty_register if pwm.global_enable else 0

    def advance_to(self, cycle: int) -> None:
        """The windings up to ``cycle`` with the duty their PWM applies now, and the
        encoders along the wheels' motion (interpolated within the physics step)."""
        start = self._cycle
        if cycle <= start:
            return
        assert self._board is not None
        channels = self._board.channels
        for code, wheel in self.wheels.items():
            io = channels[code]
            pwm = io.pwm
            wheel.duty = duty = pwm.duty_register if pwm.global_enable else 0
            if duty or wheel.current or wheel.rotor_speed:
                wheel.hold_current(cycle - start)
            begin, end = wheel.angle_at(start), wheel.angle_at(cycle)
            if begin != end:
                io.encoder.follow(start, begin, cycle, end)
            io.current_a = wheel.current if self._noise is None else (
                wheel.current + float(self._noise.normal(0.0, self.current_noise_a)))
        self._cycle = cycle
