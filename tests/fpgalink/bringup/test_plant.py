"""The plant fit on synthetic plants with known answers: the seed's own identified models
(both gears) recovered from PRBS data, with noise, with lost samples, with a longer delay,
with an output offset; the continuous form and the seed's-Ts form exact round trips; the
FOPDT summary exact on a first-order plant with dead time; data that cannot give a model
refused with a reason, never a wrong model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fpgalink.bringup.excitation import Excitation, prbs
from fpgalink.bringup.plant import (
    ContinuousModel,
    DiscreteModel,
    FitError,
    fit_percent,
    fit_plant,
)

#: The seed's identified models (SPEC §6, §3.4), at Ts = 0.05 s.
SEED = {
    "high": DiscreteModel(0.05, (-0.053, -0.07017), (-1.393, 0.7321, -0.2117)),
    "low": DiscreteModel(0.05, (-0.009263, -0.0291), (-1.394, 0.7058, -0.198)),
}
#: docs/emulator_models.md: the continuous poles and DC gains
SEED_POLES = {"high": (-4.15, complex(-13.45, 19.32)), "low": (-3.69, complex(-14.35, 19.13))}
SEED_DC = {"high": -0.9668, "low": -0.3371}


def prbs_input(samples: int, bit: int, low: float, high: float, seed: int = 1) -> np.ndarray:
    bits = prbs(7, seed)
    levels = [high if bits[(k // bit) % len(bits)] else low for k in range(samples)]
    return np.asarray(levels, dtype=float)


@pytest.mark.parametrize("gear", ["high", "low"])
def test_the_seeds_models_are_recovered_from_their_own_output(gear: str) -> None:
    plant = SEED[gear]
    u = prbs_input(1200, 4, 40.0, 100.0)
    y = plant.simulate(u)
    fit = fit_plant(u, y, 0.05)
    assert fit.model.b == pytest.approx(plant.b, rel=1e-6)
    assert fit.model.f == pytest.approx(plant.f, rel=1e-6)
    assert fit.fit_percent > 99.99 and fit.residual < 1e-6
    assert fit.model.dc_gain == pytest.approx(SEED_DC[gear], abs=1e-4)
    continuous = fit.continuous
    slow, pair = SEED_POLES[gear]
    assert continuous.dominant_pole.real == pytest.approx(slow, abs=0.01)
    assert any(abs(p - pair) < 0.02 for p in continuous.poles)


@pytest.mark.parametrize("gear", ["high", "low"])
def test_noise_leaves_the_gain_and_dominant_pole_within_a_few_percent(gear: str) -> None:
    plant = SEED[gear]
    rng = np.random.default_rng(7)
    u = prbs_input(2000, 4, 40.0, 100.0, seed=3)
    clean = plant.simulate(u)
    sigma = 0.02 * float(np.ptp(clean))  # 2 % of the swing, white
    y = clean + rng.normal(0.0, sigma, len(u))
    fit = fit_plant(u, y, 0.05)
    # issue 40 asks 5 % of the emulated plant; noise this large still leaves it in 3 %
    assert fit.model.dc_gain == pytest.approx(plant.dc_gain, rel=0.03)
    assert fit.continuous.dominant_pole.real == pytest.approx(
        plant.continuous().dominant_pole.real, rel=0.03)
    # the residual is the noise (output error: nothing of the plant left in it)
    assert fit.residual == pytest.approx(sigma, rel=0.15)
    # the fit % says how much of the swing the model explains
    assert 80.0 < fit.fit_percent < 100.0


def test_lost_samples_are_gaps_not_shifts() -> None:
    plant = SEED["high"]
    u = prbs_input(1500, 4, 40.0, 100.0)
    y = plant.simulate(u)
    rng = np.random.default_rng(2)
    lost = rng.random(len(u)) < 0.05
    lost[:3] = False
    y_lost, u_lost = y.copy(), u.copy()
    y_lost[lost] = np.nan
    u_lost[lost & (rng.random(len(u)) < 0.5)] = np.nan  # some with their duty too
    fit = fit_plant(u_lost, y_lost, 0.05)
    assert fit.missing == int(np.count_nonzero(lost))
    assert fit.model.dc_gain == pytest.approx(plant.dc_gain, rel=0.01)
    assert fit.continuous.dominant_pole.real == pytest.approx(-4.148, rel=0.01)


def test_a_longer_delay_is_found_with_its_order_and_missed_without() -> None:
    truth = ContinuousModel((-4.0 + 0j, -30.0 + 0j), (-0.5 + 0j, 0.62 + 0j), delay=0.03)
    plant = truth.discretize(0.01)  # a ZOH plant with nk = 4
    assert plant.nk == 4
    u = prbs_input(3000, 15, 0.0, 200.0)
    y = plant.simulate(u)
    right = fit_plant(u, y, 0.01, nb=2, nf=2, nk=4)
    wrong = fit_plant(u, y, 0.01, nb=2, nf=2, nk=1)
    assert right.fit_percent > 99.9 > wrong.fit_percent
    assert right.continuous.delay == pytest.approx(0.03)
    assert right.model.dc_gain == pytest.approx(truth.dc_gain, rel=1e-6)


def test_an_offset_is_fitted_when_asked() -> None:
    plant = DiscreteModel(0.01, (0.002, 0.0015), (-1.5, 0.56), offset=-3.0)
    u = prbs_input(2000, 10, 8000.0, 20000.0)
    y = plant.simulate(u)
    fit = fit_plant(u, y, 0.01, nb=2, nf=2, offset=True)
    assert fit.model.offset == pytest.approx(-3.0, abs=1e-6)
    assert fit.model.dc_gain == pytest.approx(plant.dc_gain, rel=1e-6)
    assert fit_plant(u, y, 0.01, nb=2, nf=2).fit_percent < fit.fit_percent


@pytest.mark.parametrize("gear", ["high", "low"])
def test_continuous_and_back_is_exact(gear: str) -> None:
    model = SEED[gear]
    continuous = model.continuous()
    assert continuous.dc_gain == pytest.approx(model.dc_gain, rel=1e-9)
    back = continuous.discretize(model.ts)
    assert back.f == pytest.approx(model.f, abs=1e-12)
    assert back.b[:2] == pytest.approx(model.b, abs=1e-12) and abs(back.b[2]) < 1e-12
    # the continuous step sampled at Ts is the discrete model's step (a ZOH model)
    t = np.arange(40, dtype=np.float64) * model.ts
    step = model.simulate(np.r_[0.0, np.ones(40)])[1:]
    assert continuous.step(t) == pytest.approx(step, abs=1e-9)


def test_the_fopdt_summary_is_exact_on_a_first_order_plant_with_dead_time() -> None:
    plant = ContinuousModel((-1 / 0.3 + 0j,), (2.0 / 0.3 + 0j,), delay=0.05)
    summary = plant.fopdt()
    assert summary.gain == pytest.approx(2.0, rel=1e-9)
    assert (summary.tau, summary.dead_time) == pytest.approx((0.3, 0.05), abs=1e-3)


def test_data_that_cannot_give_a_model_is_refused() -> None:
    u = prbs_input(400, 4, 40.0, 100.0)
    y = SEED["high"].simulate(u)
    with pytest.raises(FitError, match="never changed"):
        fit_plant(np.full(400, 50.0), y, 0.05)
    with pytest.raises(FitError, match="too few"):
        fit_plant(u[:40], y[:40], 0.05)
    with pytest.raises(FitError, match="infinite"):
        fit_plant(np.r_[u[:-1], math.inf], y, 0.05)
    with pytest.raises(FitError, match="same length"):
        fit_plant(u, y[:-1], 0.05)
    with pytest.raises(FitError, match="sample time"):
        fit_plant(u, y, 0.0)
    with pytest.raises(FitError, match="orders"):
        fit_plant(u, y, 0.05, nb=0)
    with pytest.raises(FitError, match="not stable"):
        DiscreteModel(0.05, (1.0,), (-1.2,)).continuous()


def test_fit_percent_is_matlabs() -> None:
    y = np.array([1.0, 2.0, 3.0, 4.0])
    assert fit_percent(y, y) == 100.0
    assert fit_percent(y, np.full(4, 2.5)) == pytest.approx(0.0)
    assert fit_percent(y, np.array([1.0, np.nan, 3.0, 4.0])) == 100.0


def test_the_excitation_is_a_maximum_length_sequence_between_the_levels() -> None:
    for order in (5, 6, 7, 8, 9, 10):
        bits = prbs(order)
        n = len(bits)
        assert n == 2**order - 1 and sum(bits) == 2 ** (order - 1)
        signs = [1 if b else -1 for b in bits]
        # two-valued autocorrelation: the mark of a maximum-length sequence
        assert {sum(signs[i] * signs[(i + k) % n] for i in range(n)) for k in range(1, n)} \
            == {-1}
    air = Excitation.for_wheels("air", 30000, duration_s=10.0)
    duties = {duty for _, duty in air.changes()}
    assert duties == {12000, 30000, 0} and air.duty_at(0.5) == 30000
    assert air.changes()[-1] == (10.0, 0) and air.duty_at(-1) == 0 and air.duty_at(11) == 0
    ground = Excitation.for_wheels("ground", 20000)
    assert {d for _, d in ground.changes()} == {-20000, 20000, 0}
    with pytest.raises(ValueError):
        Excitation.for_wheels("water", 100)
    with pytest.raises(ValueError):
        Excitation.for_wheels("air", 40000)
    with pytest.raises(ValueError):
        Excitation(1, 1)
