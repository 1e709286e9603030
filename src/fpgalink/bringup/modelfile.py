"""A fitted plant as a small TOML file (``fpgalink-cli identify --save-model``), read back by
``autotune --model`` to design without identifying again::

    # fpgalink plant model: …
    [plant]
    ts = 0.01                 # s
    b = [0.0012, 0.0009]      # B(q) = b1 q^-nk + b2 q^-(nk+1)
    f = [-2.65, 2.35, -0.69]  # F(q) = 1 + f1 q^-1 + …
    nk = 1
    offset = 0.0              # deg/s
    [fit]                     # how it was found (read for information only)
    fit_percent = 99.6

Sans-I/O: text in, text out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from fpgalink.bringup.plant import DiscreteModel, FitError
from fpgalink.protocol.tomlfile import TomlFileError, parse_toml

__all__ = ["model_from_toml", "model_to_toml"]


def _number(value: float) -> str:
    return repr(float(value))


def model_to_toml(model: DiscreteModel, comment: str, about: Mapping[str, float | str]
                  ) -> str:
    lines = [f"# fpgalink plant model: {' '.join(comment.split())}", "", "[plant]",
             f"ts = {_number(model.ts)}  # s",
             f"b = [{', '.join(_number(v) for v in model.b)}]  # B(q) = b1 q^-nk + …",
             f"f = [{', '.join(_number(v) for v in model.f)}]  # F(q) = 1 + f1 q^-1 + …",
             f"nk = {model.nk}", f"offset = {_number(model.offset)}  # deg/s", "", "[fit]"]
    for key, value in about.items():
        text = f'"{value}"' if isinstance(value, str) else _number(value)
        lines.append(f"{key} = {text}")
    return "\n".join(lines) + "\n"


def model_from_toml(text: str, source: str) -> DiscreteModel:
    """The model in ``text``; ``FitError`` naming ``source`` and the key when it is not
    one."""
    try:
        document = parse_toml(text, source)
    except TomlFileError as exc:
        raise FitError(str(exc)) from None
    plant = document.get("plant")
    if not isinstance(plant, dict):
        raise FitError(f"{source}: no [plant] table")

    def numbers(key: str, low: int, high: int) -> tuple[float, ...]:
        values = plant.get(key)
        if not (isinstance(values, list) and low <= len(values) <= high and all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in values)):
            raise FitError(f"{source}: plant.{key} must be a list of {low}..{high} finite "
                           "numbers")
        return tuple(float(v) for v in values)

    ts, nk, offset = plant.get("ts"), plant.get("nk", 1), plant.get("offset", 0.0)
    if not (isinstance(ts, int | float) and not isinstance(ts, bool) and math.isfinite(ts)
            and 0 < ts <= 10):
        raise FitError(f"{source}: plant.ts must be a sample time in s (0..10)")
    if not (isinstance(nk, int) and not isinstance(nk, bool) and 1 <= nk <= 50):
        raise FitError(f"{source}: plant.nk must be a whole number of samples, 1..50")
    if not (isinstance(offset, int | float) and not isinstance(offset, bool)
            and math.isfinite(offset)):
        raise FitError(f"{source}: plant.offset must be a finite number")
    model = DiscreteModel(float(ts), numbers("b", 1, 8), numbers("f", 1, 8), nk, float(offset))
    model.continuous()  # stable, distinct poles: FitError otherwise
    return model
