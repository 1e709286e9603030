"""SPEC §2/§7 wire arithmetic, including the seed's two slips."""

from __future__ import annotations

import pytest

from fpgalink.protocol import encode_frame
from fpgalink.protocol.wire import (
    TM_CONTENT_BYTES,
    Flow,
    bytes_per_second,
    frame_wire_bytes,
    largest_frame_wire_bytes,
    plan,
    wire_bytes,
    worst_case_wire_bytes,
)


def test_line_capacity_is_100k_bytes_per_second_at_1_mbd() -> None:
    assert bytes_per_second(1_000_000) == 100_000  # not the seed's 131,072
    assert largest_frame_wire_bytes(1_000_000, 0.001) == 100


def test_200_byte_frames_every_1_ms_do_not_fit() -> None:
    report = plan(1_000_000, 0.001, [Flow("big", 200, 1.0)])
    assert not report.fits
    assert report.to_host.typical == 202
    text = "\n".join(report.explain())
    assert "needs 2.02 ms of wire time" in text
    assert "largest frame that fits one period is 100 wire bytes" in text


def test_tm_plus_host_traffic_fits_at_1_ms() -> None:
    flows = [
        Flow("TM", TM_CONTENT_BYTES, 1.0, escapes=1),
        Flow("E", 1, 1 / 300),
        Flow("RV", 18, 1.0, to_board=True, escapes=0),
        Flow("RE", 2, 0.01, to_board=True),
    ]
    report = plan(1_000_000, 0.001, flows)
    assert report.fits
    assert report.to_host.typical == pytest.approx(55 + 3 / 300)
    assert report.to_host.utilisation == pytest.approx(0.55, abs=0.001)
    # Worst-case escaping of a TM (106 wire bytes) does not fit a 1 ms period.
    assert worst_case_wire_bytes(TM_CONTENT_BYTES) == 106
    assert not report.to_host.fits_worst_case


def test_exact_wire_bytes_match_the_encoder() -> None:
    for content in (b"", b"abc", b"S\\P", b"TM00001" + bytes(range(256))[:150]):
        assert wire_bytes(content) == len(encode_frame(content))
    assert frame_wire_bytes(52, 3) == 57
    with pytest.raises(ValueError):
        frame_wire_bytes(2, 3)
