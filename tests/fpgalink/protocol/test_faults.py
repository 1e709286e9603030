"""The ``--fault`` grammar (fpgalink.protocol.faults): what each spec says, as data, and every
number bounded where it is parsed, the bound named in one line."""

from __future__ import annotations

import pytest

from fpgalink.protocol.faults import (
    FAULT_KEYS,
    LONGEST_S,
    MAX_FAULTS,
    MAX_NOISE_LEN,
    Babble,
    DropFrames,
    FaultSpecError,
    LineNoise,
    LineRate,
    LineWindow,
    Restart,
    TelemetryLoss,
    Unplug,
    WheelStuck,
    parse_fault,
    parse_faults,
)


@pytest.mark.parametrize(("spec", "parsed"), [
    ("rx-ber=1e-4", LineRate("rx-ber=1e-4", ("rx",), "ber", 1e-4)),
    ("tx-drop=0.5", LineRate("tx-drop=0.5", ("tx",), "drop", 0.5)),
    ("rx-dup=1", LineRate("rx-dup=1", ("rx",), "dup", 1.0)),
    ("tx-noise=2e-4:6", LineNoise("tx-noise=2e-4:6", ("tx",), 2e-4, 6)),
    ("rx-noise=0.1", LineNoise("rx-noise=0.1", ("rx",), 0.1, 1)),
    (f"rx-noise=1:{MAX_NOISE_LEN}", LineNoise(f"rx-noise=1:{MAX_NOISE_LEN}", ("rx",), 1.0,
                                              MAX_NOISE_LEN)),
    ("stuck=1:0.2", LineWindow("stuck=1:0.2", 1.0, 0.2, ("rx", "tx"), "stuck")),
    ("disconnect=2:1", LineWindow("disconnect=2:1", 2.0, 1.0, ("rx", "tx"), "cut")),
    ("stall=4:0.5", LineWindow("stall=4:0.5", 4.0, 0.5, ("rx",), "cut")),
    ("tx-cut=0:1", LineWindow("tx-cut=0:1", 0.0, 1.0, ("tx",), "cut")),
    ("babble=1:2", Babble("babble=1:2", 1.0, 2.0)),
    ("tm-loss=3:1", TelemetryLoss("tm-loss=3:1", 3.0, 1.0)),
    ("unplug=1.5:0.5", Unplug("unplug=1.5:0.5", 1.5, 0.5)),
    ("drop-frames=PS:3", DropFrames("drop-frames=PS:3", "PS", 3)),
    ("wheel-stuck=B", WheelStuck("wheel-stuck=B", "B")),
    ("wheel-stuck=A:1:2", WheelStuck("wheel-stuck=A:1:2", "A", 1.0, 2.0)),
    ("restart=5", Restart("restart=5", 5.0)),
    ("restart@1.25", Restart("restart@1.25", 1.25)),
    (f"restart={LONGEST_S:.0f}", Restart(f"restart={LONGEST_S:.0f}", LONGEST_S)),
])
def test_each_spec_is_what_it_says(spec: str, parsed: object) -> None:
    assert parse_fault(spec) == parsed


@pytest.mark.parametrize(("spec", "says"), [
    ("tx-noise=1:100000000000", "LEN must be a whole number from 1 to 16, got '100000000000'"),
    ("rx-noise=1:100000000000", "LEN must be a whole number from 1 to 16"),
    (f"rx-noise=1:{MAX_NOISE_LEN + 1}", "LEN must be a whole number from 1 to 16"),
    ("rx-noise=1:0", "LEN must be a whole number from 1 to 16"),
    ("rx-noise=1:", "LEN must be"),
    ("rx-noise=1:٣", "LEN must be"),  # a digit, but not an ASCII one
    ("rx-ber=2", "RATE must be a probability in [0, 1], got '2'"),
    ("tx-drop=nan", "RATE must be a probability in [0, 1]"),
    ("tx-dup=-0.1", "RATE must be a probability"),
    ("rx-noise=x:3", "RATE must be a probability"),
    ("restart=banana", "T_S must be seconds from 0 to 31,536,000 (a year), got 'banana'"),
    ("restart=inf", "T_S must be seconds from 0 to 31,536,000"),
    ("restart=-1", "T_S must be seconds"),
    ("restart@1e99", "T_S must be seconds"),
    ("stall=1e308:1", "START_S must be seconds from 0 to 31,536,000"),
    ("unplug=1:1e99", "DURATION_S must be seconds from 0 to 31,536,000"),
    ("babble=1", "write START_S:DURATION_S"),
    ("wheel-stuck=A:nan:1", "START_S must be seconds"),
    ("wheel-stuck=C", "the wheel is A or B"),
    ("drop-frames=PS:99999999999", "N must be a whole number from 0 to 1,000,000,000"),
    ("drop-frames=PS:-1", "N must be a whole number"),
    ("drop-frames=ps:1", "ID a message ID"),
    ("drop-frames=PSX:1", "ID a message ID"),
    ("drop-frames=PS", "ID a message ID"),
    ("restart@5=1", "KEY one of"),
    ("nonsense", "KEY one of " + ", ".join(FAULT_KEYS)),
    ("rx-bogus=1", "KEY one of"),
    ("rx-" + "9" * 200, "longer than 100 characters"),
])
def test_a_spec_outside_the_grammar_is_one_line_naming_the_bound(spec: str, says: str) -> None:
    with pytest.raises(FaultSpecError) as caught:
        parse_fault(spec)
    message = str(caught.value)
    assert says in message and "\n" not in message, message
    assert isinstance(caught.value, ValueError)  # what the emulator's callers catch
    assert len(message) < 400


def test_a_board_takes_at_most_max_faults_specs() -> None:
    assert len(parse_faults([f"restart={t}" for t in range(MAX_FAULTS)])) == MAX_FAULTS
    with pytest.raises(FaultSpecError, match=f"at most {MAX_FAULTS}"):
        parse_faults(f"restart={t}" for t in range(MAX_FAULTS + 1))
