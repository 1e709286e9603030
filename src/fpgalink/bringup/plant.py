"""A wheel's plant from its PWM and speed: the seed's model form, fitted by least squares.

The seed identified each gear's duty → wheel speed response as a discrete transfer function
(§3.4: Hammerstein-Wiener with a linear block of nb = 2 zeros, nf = 3 poles, nk = 1 sample
of delay, at Ts = 0.05 s; docs/emulator_models.md)::

    y[k] = B(q)/F(q) u[k] (+ c)      B = b1 q^-nk + … + b_nb q^-(nk+nb-1)
                                     F = 1 + f1 q^-1 + … + f_nf q^-nf

:func:`fit_plant` fits that form to samples taken every ``ts`` seconds (``u`` the applied
duty in PWM counts, ``y`` the measured speed in deg/s; NaN where a sample is missing) as an
output-error model: an ARX least-squares start, then Steiglitz–McBride iterations (least
squares on the data filtered by 1/F of the last estimate), which converge to the output
error fit without a nonlinear optimiser. ``offset`` adds a constant output term (a real
drive's friction makes the response affine around its operating point; the seed linearised
around 50 % duty). Held-out data (the record's last :data:`VALIDATION_SHARE`) measures the
fit: Matlab's "fit %", 100·(1 − ‖y − ŷ‖/‖y − ȳ‖), of the simulated model.

:class:`DiscreteModel` reports the seed's figures: DC gain, poles, delay; its continuous
equivalent (:meth:`DiscreteModel.continuous`, the exact inverse of the zero-order hold for
distinct poles) gives the poles in rad/s, a first-order-plus-dead-time summary
(:class:`Fopdt`, Smith's two-point method on the step response), the frequency response
and the model at any other sample time (the seed's 0.05 s included).

Sans-I/O, numpy only.
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "VALIDATION_SHARE",
    "ContinuousModel",
    "DiscreteModel",
    "FitError",
    "Fopdt",
    "PlantFit",
    "fit_percent",
    "fit_plant",
]

Array = NDArray[np.float64]

#: The share of the record (its end) held out to measure the fit.
VALIDATION_SHARE = 0.3
#: Steiglitz–McBride stops when no coefficient moves by more than this, relatively.
TOLERANCE = 1e-9
MAX_ITERATIONS = 50


class FitError(ValueError):
    """The data cannot give the model asked for (too short, not exciting enough, not
    finite); the message says why."""


@dataclass(frozen=True, slots=True)
class Fopdt:
    """First order plus dead time: K·e^(−θs)/(τs + 1)."""

    gain: float  #: deg/s per PWM count
    tau: float  #: s
    dead_time: float  #: s


@dataclass(frozen=True, slots=True)
class ContinuousModel:
    """G(s) = e^(−delay·s) · Σ residues[i]/(s − poles[i]) (+ the offset at the output)."""

    poles: tuple[complex, ...]  #: rad/s
    residues: tuple[complex, ...]
    delay: float = 0.0  #: s
    offset: float = 0.0  #: deg/s

    @property
    def dc_gain(self) -> float:
        return float(sum(-c / p for c, p in zip(self.residues, self.poles, strict=True)).real)

    @property
    def dominant_pole(self) -> complex:
        """The slowest pole (smallest |Re s|): the one a step response is mostly made of."""
        return min(self.poles, key=lambda p: abs(p.real))

    @property
    def time_constant(self) -> float:
        """s: −1/Re of the dominant pole."""
        return -1.0 / self.dominant_pole.real

    def step(self, times: Sequence[float] | Array, size: float = 1.0) -> Array:
        """The response to a step of ``size`` at t = 0 (without the offset)."""
        t = np.asarray(times, dtype=float) - self.delay
        out = np.zeros_like(t)
        after = t >= 0
        for c, p in zip(self.residues, self.poles, strict=True):
            out[after] += (c * (np.exp(p * t[after]) - 1.0) / p).real
        return out * size

    def frequency_response(self, omega: Array) -> NDArray[np.complex128]:
        s = 1j * np.asarray(omega, dtype=float)
        total = sum(c / (s - p) for c, p in zip(self.residues, self.poles, strict=True))
        return np.asarray(total * np.exp(-s * self.delay), dtype=np.complex128)

    def fopdt(self) -> Fopdt:
        """Smith's method: the times the step response reaches 28.3 % and 63.2 % of its
        final value give τ = 1.5·(t63 − t28) and θ = t63 − τ (never below 0)."""
        gain = self.dc_gain
        horizon = self.delay + 12.0 * self.time_constant
        t = np.linspace(0.0, horizon, 24001)
        y = self.step(t) / gain
        t28 = float(np.interp(0.283, _rising(y), t))
        t63 = float(np.interp(0.632, _rising(y), t))
        tau = 1.5 * (t63 - t28)
        return Fopdt(gain, tau, max(0.0, t63 - tau))

    def discretize(self, ts: float) -> DiscreteModel:
        """The zero-order-hold equivalent at sample time ``ts`` (the delay rounded to whole
        samples): B/F in the seed's form, nk = 1 + the delay's samples."""
        zs = [cmath.exp(p * ts) for p in self.poles]
        rho = [c * (z - 1.0) / p for c, z, p in zip(self.residues, zs, self.poles, strict=True)]
        f = np.poly(np.array(zs))  # z^n + f1 z^(n-1) + …
        numerator = np.zeros(len(zs), dtype=complex)
        for i, r in enumerate(rho):
            others = [z for j, z in enumerate(zs) if j != i]
            numerator += r * np.poly(np.array(others)) if others else r
        extra = round(self.delay / ts)
        b = tuple(float(v) for v in numerator.real)
        return DiscreteModel(ts, b, tuple(float(v) for v in f.real[1:]), 1 + extra,
                             self.offset)


def _rising(y: Array) -> Array:
    """``y`` made non-decreasing (np.interp needs it), keeping its first crossings."""
    return np.asarray(np.maximum.accumulate(y), dtype=float)


@dataclass(frozen=True, slots=True)
class DiscreteModel:
    """y[k] = B(q)/F(q) u[k] + offset, in the seed's form."""

    ts: float  #: s
    b: tuple[float, ...]  #: b1 … b_nb (b1 multiplies u[k − nk])
    f: tuple[float, ...]  #: f1 … f_nf
    nk: int = 1
    offset: float = 0.0  #: deg/s at the output

    @property
    def dc_gain(self) -> float:
        """deg/s per PWM count in steady state."""
        return sum(self.b) / (1.0 + sum(self.f))

    @property
    def poles(self) -> tuple[complex, ...]:
        return tuple(complex(z) for z in np.roots([1.0, *self.f]))

    def simulate(self, u: Sequence[float] | Array, *, initial_output: float | None = None
                 ) -> Array:
        """The model's output for input ``u`` (one value per sample). The past before the
        first sample is the steady state with ``u[0]`` held (``initial_output``: the output
        it held instead, when the record starts on a plant already moving)."""
        u = np.asarray(u, dtype=float)
        nb, nf, nk = len(self.b), len(self.f), self.nk
        y0 = self.dc_gain * u[0] + self.offset if initial_output is None else initial_output
        d = self.offset * (1.0 + sum(self.f))
        past_y = [y0] * nf
        out = np.empty(len(u))
        history = [float(u[0])] * (nk + nb)
        b, f = self.b, self.f
        for k, value in enumerate(u):
            history.insert(0, float(value))
            history.pop()
            y = d
            for j in range(nb):
                y += b[j] * history[nk + j]
            for i in range(nf):
                y -= f[i] * past_y[i]
            past_y.insert(0, y)
            past_y.pop()
            out[k] = y
        return out

    def continuous(self) -> ContinuousModel:
        """The continuous model whose zero-order hold this is (distinct poles): s = ln z/ts,
        residues from the partial fractions; a pole on the negative real axis, which no
        continuous pole samples to, keeps its decay (s = ln|z|/ts). ``FitError`` for a pole
        on or outside the unit circle or a repeated one."""
        zs = self.poles
        if any(abs(z) >= 1.0 for z in zs):
            raise FitError(f"the model is not stable (poles {_show(zs)}): no plant here")
        if len({round(z.real, 9) + 1j * round(z.imag, 9) for z in zs}) < len(zs):
            raise FitError(f"repeated poles {_show(zs)}: no modal form")
        n = len(self.f)
        if len(self.b) > n:
            raise FitError(f"nb = {len(self.b)} above nf = {n}: no strictly proper "
                           "continuous model")
        # H(z) = z^-(nk-1) · (b1 z^(n-1) + b2 z^(n-2) + …)/(z^n + f1 z^(n-1) + …)
        numerator = np.zeros(n)
        numerator[: len(self.b)] = self.b
        denominator = np.array([1.0, *self.f])
        derivative = np.polyder(denominator)
        poles, residues = [], []
        for z in zs:
            rho = np.polyval(numerator, z) / np.polyval(derivative, z)
            s = cmath.log(z) / self.ts if not (abs(z.imag) < 1e-12 and z.real < 0) \
                else complex(math.log(abs(z)) / self.ts, 0.0)
            poles.append(s)
            residues.append(complex(rho * s / (z - 1.0)))
        return ContinuousModel(tuple(poles), tuple(residues), (self.nk - 1) * self.ts,
                               self.offset)


def _show(zs: Sequence[complex]) -> str:
    return ", ".join(f"{z.real:.4g}{z.imag:+.4g}j" if abs(z.imag) > 1e-12 else f"{z.real:.4g}"
                     for z in zs)


def fit_percent(measured: Array, simulated: Array) -> float:
    """Matlab's normalised fit: 100·(1 − ‖y − ŷ‖/‖y − ȳ‖) over the finite samples."""
    keep = np.isfinite(measured) & np.isfinite(simulated)
    y, s = measured[keep], simulated[keep]
    spread = float(np.linalg.norm(y - y.mean()))
    if spread == 0.0:
        return -math.inf
    return 100.0 * (1.0 - float(np.linalg.norm(y - s)) / spread)


@dataclass(frozen=True, slots=True)
class PlantFit:
    """A fitted model and how well it fits."""

    model: DiscreteModel
    fit_percent: float  #: on the held-out samples
    residual: float  #: deg/s, RMS of the simulation error on the held-out samples
    estimation_fit_percent: float
    samples: int  #: samples used (finite ones)
    missing: int  #: samples missing from the grid (lost telemetry), not used
    validation_start: int  #: index of the first held-out sample
    simulated: Array  #: the model's output over the whole record
    iterations: int  #: Steiglitz–McBride iterations taken

    @property
    def continuous(self) -> ContinuousModel:
        return self.model.continuous()


def _filtered(x: Array, f: Sequence[float] | Array) -> Array:
    """x filtered by 1/F(q), started in the steady state of x[0]."""
    return DiscreteModel(1.0, (1.0,), tuple(float(v) for v in f), nk=0).simulate(x)


def _regression(y: Array, u: Array, ones: Array, nb: int, nf: int, nk: int,
                offset: bool, rows: Array, u_known: Array) -> tuple[Array, Array]:
    lag = max(nf, nk + nb - 1)
    ks = np.arange(lag, len(y))
    columns = [-y[ks - i] for i in range(1, nf + 1)]
    columns += [u[ks - nk - j] for j in range(nb)]
    if offset:
        columns.append(ones[ks])
    phi = np.column_stack(columns)
    target = y[ks]
    keep = rows[ks] & np.all(np.isfinite(phi), axis=1) & np.isfinite(target)
    for j in range(nb):  # a duty held over a lost sample may be wrong: not a regressor
        keep &= u_known[ks - nk - j]
    return phi[keep], target[keep]


def _stable(f: Array) -> Array:
    """F with every root outside the unit circle reflected inside (so 1/F can filter)."""
    roots = np.roots([1.0, *f])
    if np.all(np.abs(roots) < 1.0):
        return f
    roots = np.where(np.abs(roots) >= 1.0, 1.0 / np.conj(roots) * 0.999, roots)
    return np.asarray(np.poly(roots).real[1:], dtype=float)


def fit_plant(u: Sequence[float] | Array, y: Sequence[float] | Array, ts: float, *,
              nb: int = 2, nf: int = 3, nk: int = 1, offset: bool = False,
              validation_share: float = VALIDATION_SHARE) -> PlantFit:
    """Fit the seed's model form to ``u`` (duty, PWM counts) and ``y`` (speed, deg/s)
    sampled every ``ts`` s. NaN in either marks a sample that is missing (its rows are not
    used; a missing ``u`` is taken as held from the sample before for the simulation).
    ``FitError`` when the data cannot give the model."""
    u = np.asarray(u, dtype=float).copy()
    y = np.asarray(y, dtype=float)
    if u.shape != y.shape or u.ndim != 1:
        raise FitError("u and y must be one-dimensional and of the same length")
    if not (math.isfinite(ts) and ts > 0):
        raise FitError(f"the sample time must be a positive number, got {ts!r}")
    if min(nb, nf, nk) < 1 or max(nb, nf) > 8 or nk > 50:
        raise FitError(f"orders nb={nb}, nf={nf}, nk={nk}: each at least 1 (nb, nf at most 8)")
    if np.any(np.isinf(u)) or np.any(np.isinf(y)):
        raise FitError("infinite values in the data")
    if not 0.05 <= validation_share <= 0.5:
        raise FitError("validation_share must be within 0.05..0.5")
    missing = int(np.count_nonzero(np.isnan(u) | np.isnan(y)))
    present = ~np.isnan(u)
    if not present[0]:
        first = int(np.argmax(present)) if present.any() else -1
        if first < 0:
            raise FitError("no samples")
        u[:first] = u[first]
    for k in range(1, len(u)):  # held, as the board holds its PWM between writes
        if not present[k]:
            u[k] = u[k - 1]
    n = len(y)
    parameters = nf + nb + (1 if offset else 0)
    split = int(n * (1.0 - validation_share))
    if split < 10 * parameters or n - split < 5 * parameters:
        raise FitError(f"{n} samples are too few for {parameters} parameters (need about "
                       f"{int(15 * parameters / (1 - validation_share))})")
    estimation = np.zeros(n, dtype=bool)
    estimation[:split] = True
    finite = np.isfinite(y[:split])
    if np.ptp(u[:split][finite]) == 0.0:
        raise FitError("the duty never changed: nothing excites the plant")
    ones = np.ones(n)
    theta, iterations = _steiglitz_mcbride(y, u, ones, nb, nf, nk, offset, estimation,
                                           present)
    f = tuple(float(v) for v in theta[:nf])
    b = tuple(float(v) for v in theta[nf:nf + nb])
    d = float(theta[nf + nb]) if offset else 0.0
    model = DiscreteModel(ts, b, f, nk, d / (1.0 + sum(f)) if offset else 0.0)
    if not all(math.isfinite(v) for v in (*b, *f, model.offset)):
        raise FitError("the fit did not converge to finite coefficients")
    start = float(np.nan_to_num(y[np.isfinite(y)][0])) if np.isfinite(y).any() else 0.0
    simulated = model.simulate(u, initial_output=start)
    held_out = slice(split, n)
    residual = y[held_out] - simulated[held_out]
    residual = residual[np.isfinite(residual)]
    return PlantFit(model, fit_percent(y[held_out], simulated[held_out]),
                    float(np.sqrt(np.mean(residual**2))) if residual.size else math.nan,
                    fit_percent(y[:split], simulated[:split]), n - missing, missing, split,
                    simulated, iterations)


def _steiglitz_mcbride(y: Array, u: Array, ones: Array, nb: int, nf: int, nk: int,
                       offset: bool, rows: Array, u_known: Array) -> tuple[Array, int]:
    """ARX, then least squares on the data prefiltered by 1/F of the last estimate until
    the coefficients stop moving: the output-error estimate. Of the estimates met on the
    way, the one whose simulated output is closest to the data (over the estimation rows)
    is kept, so a run that strays — lost samples whose duty was held wrongly spread through
    the filter — never returns worse than where it started."""
    missing = ~np.isfinite(y)
    phi, target = _regression(np.where(missing, np.nan, y), u, ones, nb, nf, nk, offset,
                              rows, u_known)
    if len(target) < 2 * phi.shape[1]:
        raise FitError("too few complete samples for the model")
    theta = _solve(phi, target)
    scored = rows & ~missing
    start = float(y[~missing][0])

    def model_of(coefficients: Array) -> DiscreteModel:
        f = tuple(float(v) for v in coefficients[:nf])
        d = float(coefficients[nf + nb]) if offset else 0.0
        return DiscreteModel(1.0, tuple(float(v) for v in coefficients[nf:nf + nb]), f, nk,
                             d / (1.0 + sum(f)))

    def error(coefficients: Array) -> float:
        simulated = model_of(coefficients).simulate(u, initial_output=start)
        value = float(np.sum((simulated[scored] - y[scored]) ** 2))
        return value if math.isfinite(value) else math.inf

    best, best_error = theta, error(theta)
    iterations = 0
    while iterations < MAX_ITERATIONS:
        iterations += 1
        f = _stable(theta[:nf])
        # a missing y is bridged by the last estimate's own output there (so the filter
        # carries on through the gap), and its rows are left out
        y_filled = np.where(missing, model_of(theta).simulate(u, initial_output=start), y) \
            if missing.any() else y
        phi, target = _regression(_filtered(y_filled, f), _filtered(u, f),
                                  _filtered(ones, f), nb, nf, nk, offset,
                                  rows & ~missing, u_known)
        new = _solve(phi, target)
        moved = np.max(np.abs(new - theta) / np.maximum(np.abs(theta), 1e-12))
        theta = new
        if (candidate := error(theta)) < best_error:
            best, best_error = theta, candidate
        if moved < TOLERANCE:
            break
    return best, iterations


def _solve(phi: Array, target: Array) -> Array:
    scale = np.max(np.abs(phi), axis=0)
    scale[scale == 0.0] = 1.0
    solution, _, rank, _ = np.linalg.lstsq(phi / scale, target, rcond=None)
    if rank < phi.shape[1]:
        raise FitError("the data do not determine every coefficient (the duty must vary "
                       "more: a richer excitation, or a lower model order)")
    return np.asarray(solution / scale, dtype=float)
