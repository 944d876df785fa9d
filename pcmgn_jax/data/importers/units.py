"""Unit names -> SI factors (lengths, times, velocities, stresses) and MAPDL /UNITS systems."""
from __future__ import annotations

from pcmgn_jax.data.importers.errors import InputFileError

LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "\u00b5m": 1e-6, "\u03bcm": 1e-6, "cm": 1e-2,
                "nm": 1e-9, "in": 0.0254, "ft": 0.3048}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "\u00b5s": 1e-6, "\u03bcs": 1e-6}
STRESS_UNITS = {"pa": 1.0, "kpa": 1e3, "mpa": 1e6, "gpa": 1e9, "psi": 6894.757293168361,
                "n/m^2": 1.0, "n/m\u00b2": 1.0, "n/mm^2": 1e6, "n/mm\u00b2": 1e6}
# MAPDL /UNITS systems -> length unit (BIN/BFT are inch/foot systems)
ANSYS_UNIT_SYSTEMS = {"SI": "m", "MKS": "m", "MPA": "mm", "UMKS": "um", "CGS": "cm", "BIN": "in", "BFT": "ft"}


def length_factor(unit: str, where: str) -> float:
    """SI factor of a length unit (m, mm, µm, ...); InputFileError naming ``where`` if unknown."""
    f = LENGTH_UNITS.get(unit.strip())
    if f is None:
        raise InputFileError(f"{where}: unknown length unit {unit!r}; known: {sorted(LENGTH_UNITS)}")
    return f


def time_factor(unit: str, where: str) -> float:
    f = TIME_UNITS.get(unit.strip())
    if f is None:
        raise InputFileError(f"{where}: unknown time unit {unit!r}; known: {sorted(TIME_UNITS)}")
    return f


def velocity_factor(unit: str, where: str) -> float:
    u = unit.strip()
    if "/" in u:
        num, den = u.split("/", 1)
        if num in LENGTH_UNITS and den in TIME_UNITS:
            return LENGTH_UNITS[num] / TIME_UNITS[den]
    raise InputFileError(f"{where}: unknown velocity unit {unit!r}; expected <length>/<time> with "
                         f"length in {sorted(LENGTH_UNITS)} and time in {sorted(TIME_UNITS)}")


def stress_factor(unit: str, where: str) -> float:
    f = STRESS_UNITS.get(unit.strip().lower())
    if f is None:
        raise InputFileError(f"{where}: unknown stress unit {unit!r}; known: Pa, kPa, MPa, GPa, psi, N/mm^2")
    return f
