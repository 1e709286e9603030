"""The telemetry's fast JSON is the recording's row, value for value."""

from __future__ import annotations

import json
import math

from hypothesis import given
from hypothesis import strategies as st

from fpgalink.live.feeds import telemetry_json
from fpgalink.protocol import Telemetry
from fpgalink.protocol.catalogue import ChannelTelemetry
from fpgalink.recording import compact, json_safe, telemetry_row

_F32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
_I = st.integers(-(2**31), 2**31 - 1)


def _channel() -> st.SearchStrategy[ChannelTelemetry]:
    return st.builds(ChannelTelemetry, _I, _F32, _F32, st.integers(-32760, 32760), _F32,
                     st.integers(0, 7))


@given(st.integers(0, 2**32 - 1), _channel(), _channel(), st.none() | st.integers(0, 99999),
       st.floats(0, 2e9))
def test_the_fast_json_is_the_rows(t_us: int, a: ChannelTelemetry, b: ChannelTelemetry,
                                   counter: int | None, stamp: float) -> None:
    sample = Telemetry(t_us, a, b, counter)
    row = json_safe({k: compact(v) for k, v in telemetry_row(sample, 0.0).items()})
    row["timestamp"] = round(stamp, 6)
    fast = telemetry_json(sample, stamp)
    finite = all(math.isfinite(v) for v in (a.speed, a.current, a.reference, b.speed,
                                            b.current, b.reference))
    if not finite:
        assert fast is None  # the row's path writes null
        return
    assert fast is not None
    decoded = json.loads(fast)
    assert decoded.keys() == row.keys()
    for key, value in row.items():
        assert decoded[key] == value or math.isclose(decoded[key], value, rel_tol=1e-6), key
