"""PID design and the closed-loop prediction on plants with known answers: a first-order
plant under a PI that cancels its pole closes as a first-order loop of the time constant
the formula says; the board's M/T counter as the FPGA block behaves (exact at constant
speed, blind until two edges, decaying when the wheel stops); the predicted steps of the
shipped gains on the seed's plants are the figures docs/emulator_models.md measured on the
emulated board; the design on both gears settles a step at least as well as the seed's
converted gains; the confirmation rule; bad models refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fpgaemu.motor import continuous_model
from fpgalink.bringup.design import (
    DesignError,
    FirmwarePid,
    Gains,
    MtCounter,
    confirms,
    design_pi,
    margins,
    predict_step,
    seed_gains,
)
from fpgalink.bringup.plant import ContinuousModel
from fpgalink.robot.response import StepMetrics, step_metrics

FULL_SPEED = {"high": 90.0, "low": 31.38}  #: deg/s at full duty (docs/emulator_models.md)


def seed_plant(gear: str) -> ContinuousModel:
    """The emulated board's plant exactly: the continuous form of the seed's identified H(z)
    the emulator runs (fpgaemu.motor), physical sign, scaled to deg/s per PWM count."""
    model = continuous_model(gear)
    scale = FULL_SPEED[gear] / 32760 / abs(model.dc_gain)
    return ContinuousModel(model.poles, tuple(-r * scale for r in model.residues()))


def metrics(model: ContinuousModel, gains: Gains, target: float, **options: object
            ) -> StepMetrics:
    t, y, _ = predict_step(model, gains, period=0.001, target=target, duration=3.0,
                           counts_per_turn=5000, **options)  # type: ignore[arg-type]
    return step_metrics(list(t), list(y), 0.0, target)


def test_a_pi_cancelling_a_first_order_pole_closes_first_order() -> None:
    tau, gain, kp = 0.25, 0.003, 1000.0
    plant = ContinuousModel((-1 / tau + 0j,), (gain / tau + 0j,))
    t, y, _ = predict_step(plant, Gains(kp, tau), period=0.0005, target=10.0, duration=2.0)
    closed = tau / (gain * kp)  # L = K·Kp/(τs): the loop is 1/(closed·s + 1)
    expected = 10.0 * (1 - np.exp(-(t - 0.0005) / closed))
    late = t > 0.05
    assert np.max(np.abs(y[late] - expected[late])) < 0.15  # half a period's lag, no more


def test_the_firmware_pid_clamps_and_integrates_only_out_of_the_clamp() -> None:
    pid = FirmwarePid(Gains(1000.0, 0.1), 5000)
    assert pid(10.0, 0.0, 0.001) == 5000  # clamped
    assert pid.integral == 0.0  # pushing further into the clamp: not integrated
    assert pid(0.0, 2.0, 0.001) == round(1000 * -2 + 1000 * 0.001 / 0.1 * -2)
    derivative = FirmwarePid(Gains(10.0, 1e9, 0.1), 32760)
    derivative(0.0, 0.0, 0.001)
    assert derivative(5.0, 0.0, 0.001) == 50  # a reference step does not kick it
    assert derivative(5.0, 1.0, 0.001) < 40  # a measurement step does


def test_the_mt_counter_is_the_boards() -> None:
    counter = MtCounter(5000)  # 0.072° a count
    t, angle = 0.0, 0.0
    readings = []
    for _ in range(100):  # 45 deg/s: 0.625 counts a millisecond
        counter.move(t, angle, t + 0.001, angle + 0.045)
        t, angle = t + 0.001, angle + 0.045
        readings.append(counter.read(t))
    first = next(i for i, r in enumerate(readings) if r)
    assert readings[:first] == [0.0] * first and first >= 2  # blind until two edges
    assert readings[-1] == pytest.approx(45.0, rel=1e-9)  # exact at constant speed
    for _ in range(20):  # the wheel stops: the reading decays as one count over the wait
        t += 0.001
        readings.append(counter.read(t))
    assert counter.last_edge is not None
    assert readings[-1] == pytest.approx(0.072 / (t - counter.last_edge), rel=1e-9)
    t += 1.5
    assert counter.read(t) == 0.0  # after a second without an edge


@pytest.mark.parametrize(("gear", "gains", "target", "settling", "overshoot"), [
    # docs/emulator_models.md, measured on the emulated board at 1 ms
    ("high", "seed", 45.0, 0.71, 2.9),
    ("low", "seed", 20.0, 0.86, 2.5),
    ("high", Gains(520.0, 0.24), 45.0, 0.535, 0.0),
    ("low", Gains(520.0, 0.24), 20.0, 1.58, 0.0),
])
def test_the_prediction_gives_the_boards_documented_steps(
        gear: str, gains: Gains | str, target: float, settling: float,
        overshoot: float) -> None:
    chosen = seed_gains(gear) if gains == "seed" else gains
    assert isinstance(chosen, Gains)
    figures = metrics(seed_plant(gear), chosen, target)
    assert figures.settling_time == pytest.approx(settling, abs=0.01)
    assert figures.overshoot == pytest.approx(overshoot, abs=0.1)


@pytest.mark.parametrize(("gear", "target"), [("high", 45.0), ("low", 20.0)])
def test_the_design_settles_at_least_as_well_as_the_seeds_gains(gear: str,
                                                                target: float) -> None:
    plant = seed_plant(gear)
    design = design_pi(plant, period=0.001, target=target, counts_per_turn=5000)
    seed = metrics(plant, seed_gains(gear), target)
    assert design.prediction.settling_time is not None and seed.settling_time is not None
    assert design.prediction.settling_time <= seed.settling_time
    assert design.prediction.overshoot <= min(seed.overshoot, 2.0)
    assert design.margins.phase_margin >= 45.0 and design.margins.gain_margin_db >= 6.0
    assert design.gains.td == 0.0 and design.gains.ti == pytest.approx(plant.time_constant)
    assert "SIMC" in design.rule and f"{design.tau_c:.3f}" in design.rule


def test_margins_of_a_known_loop() -> None:
    # integrator loop L = K·Kp/(τs) after the PI cancels the pole: crossover K·Kp/τ, phase
    # margin 90° less the delay's phase there
    plant = ContinuousModel((-4.0 + 0j,), (4.0 * 0.003 + 0j,))
    stability = margins(plant, Gains(1000.0, 0.25), 0.001)
    assert stability.crossover == pytest.approx(12.0, rel=0.01)
    assert stability.phase_margin == pytest.approx(90 - math.degrees(12.0 * 0.0015), abs=0.5)


def test_a_plant_that_makes_no_pi_is_refused() -> None:
    backwards = ContinuousModel((-4.0 + 0j,), (-0.01 + 0j,))
    with pytest.raises(DesignError, match="negative"):
        design_pi(backwards, period=0.001, target=45.0)


def test_confirmation_holds_a_step_to_its_prediction() -> None:
    predicted = StepMetrics(0.15, 0.50, 0.0, 0.0, 45.0)
    assert confirms(predicted, StepMetrics(0.16, 0.55, 1.0, 0.0, 45.4))[0]
    slow, why = confirms(predicted, StepMetrics(0.3, 0.80, 0.0, 0.0, 45.0))
    assert not slow and "0.800 s" in why
    fast = confirms(predicted, StepMetrics(0.1, 0.30, 0.0, 0.0, 45.0))[0]
    assert not fast  # faster than the model by far is another plant too
    assert not confirms(predicted, StepMetrics(0.1, 0.5, 4.5, 0.0, 47.0))[0]
    assert not confirms(predicted, StepMetrics(0.1, None, 0.0, 0.0, 40.0))[0]
