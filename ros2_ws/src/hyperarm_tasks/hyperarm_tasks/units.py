"""Quantities in task files: a number (SI) or a string "<number> <unit>" (no ROS).

Each field has a dimension; a unit of another dimension (``"2 kg"`` for a length) is an
error. Results are SI floats: m, rad, s, N, N·m, m/s, rad/s, m/s².
"""
from __future__ import annotations

import math
import re

__all__ = ["UNITS", "UnitError", "to_si", "QUANTITY_PATTERN"]

UNITS: dict[str, dict[str, float]] = {
    "length": {"m": 1.0, "cm": 0.01, "mm": 0.001},
    "angle": {"rad": 1.0, "deg": math.pi / 180.0},
    "time": {"s": 1.0, "ms": 0.001, "min": 60.0},
    "force": {"N": 1.0},
    "torque": {"N·m": 1.0, "N*m": 1.0, "Nm": 1.0},
    "speed": {"m/s": 1.0, "cm/s": 0.01, "mm/s": 0.001},
    "angular_speed": {"rad/s": 1.0, "deg/s": math.pi / 180.0},
    "acceleration": {"m/s^2": 1.0, "m/s²": 1.0, "cm/s^2": 0.01, "cm/s²": 0.01},
    "stiffness": {"N/m": 1.0},
    "frequency": {"Hz": 1.0},
}

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
QUANTITY_PATTERN = rf"^\s*{_NUMBER}\s*[^\s\d].*$"
_QUANTITY = re.compile(rf"^\s*({_NUMBER})\s*(\S+)\s*$")


class UnitError(ValueError):
    """A quantity with a unit of the wrong dimension, an unknown unit or a bad number."""


def to_si(value: object, dimension: str) -> float:
    """``value`` (number or "<number> <unit>") in SI units of ``dimension``."""
    table = UNITS[dimension]
    if isinstance(value, bool):
        raise UnitError(f"expected a {dimension}, got {value!r}")
    if isinstance(value, (int, float)):
        out = float(value)
    elif isinstance(value, str):
        m = _QUANTITY.match(value)
        if not m:
            raise UnitError(f"{value!r} is not '<number> <unit>' "
                            f"({dimension} units: {', '.join(table)})")
        unit = m.group(2)
        if unit not in table:
            other = [d for d, t in UNITS.items() if unit in t]
            hint = f" (that is a {other[0]} unit)" if other else ""
            raise UnitError(f"bad unit {unit!r} for a {dimension}{hint}; "
                            f"use one of {', '.join(table)}")
        out = float(m.group(1)) * table[unit]
    else:
        raise UnitError(f"expected a {dimension} (number or '<number> <unit>'), got {value!r}")
    if not math.isfinite(out):
        raise UnitError(f"{value!r} is not finite")
    return out
