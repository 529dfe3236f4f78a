"""Units of scene values: pint's registry, with angle a dimension of its own.

Scene files and ``--set`` give values with any unit pint knows (``mm``, ``um``, ``µm``, ``GPa``,
``g/cm^3``, ``kN``, ``N m``, ``MPa/mm``, ``deg/s``, ``rpm``, ``rad/min``, ...); each parameter
is stored in the SI unit of its dimension (:data:`SI_UNITS`). Two changes to pint's own
definitions (Debian's ``python3-pint``):

* the radian is a base dimension, ``[angle]``, not a pure number: with pint's default a
  rotation rate in ``rpm`` (revolutions per minute) did not convert to ``rad/s`` and an angle
  in ``deg`` would be accepted for a dimensionless parameter (a Poisson's ratio of 30 deg);
* the hertz is a cycle per second (``2 π rad/s``), the reading a spin rate in ``Hz`` has;
  ``1/s`` is refused for a rotation rate rather than read as 1 rad/s.

The Hounsfield unit ``HU`` (CT numbers) is a dimension of its own, ``[ct_number]``.
"""

from __future__ import annotations

import functools
import re
from pathlib import Path

__all__ = ["SI_UNITS", "UnitError", "registry", "si_unit", "to_si"]

#: The SI unit of every dimension a parameter may have (as parameters record it).
SI_UNITS = (
    "1",
    "m",
    "m^2",
    "s",
    "kg",
    "N",
    "Pa",
    "N*m",
    "N/m",
    "Pa/m",
    "kg/m^3",
    "kg/m^3/HU",
    "rad",
    "rad/s",
    "rad/s^2",
    "m/s",
    "m/s^2",
)


class UnitError(ValueError):
    """A unit pint does not know, or one of another dimension than wanted."""


@functools.cache
def registry():
    """The unit registry: pint's, with the changes of the module doc (built once)."""
    import pint

    folder = Path(pint.__file__).parent
    text = (folder / "default_en.txt").read_text()
    text = text.replace("@import constants_en.txt", (folder / "constants_en.txt").read_text())
    for old, new in (
        ("radian = [] = rad", "radian = [angle] = rad"),
        ("hertz = 1 / second = Hz", "hertz = turn / second = Hz"),
    ):
        text, n = re.subn(rf"^{re.escape(old)}$", new, text, flags=re.M)
        if n != 1:  # pint's definitions changed: the module doc no longer holds
            raise RuntimeError(f"pint's default_en.txt has no line {old!r}")
    ureg = pint.UnitRegistry(None, on_redefinition="raise")
    ureg.load_definitions(text.splitlines())
    ureg.define("hounsfield_unit = [ct_number] = HU")
    return ureg


def _quantity(unit: str):
    import pint

    ureg = registry()
    try:
        return ureg.Quantity(1.0, unit)
    except (pint.errors.PintError, ValueError, AttributeError, TypeError):
        raise UnitError(f"unknown unit '{unit}' (pint cannot read it)") from None


@functools.cache
def si_unit(unit: str) -> tuple[str, float]:
    """(SI unit of ``unit``'s dimension, factor from ``unit`` to it).

    Raises:
        UnitError: ``unit`` is unknown, or of a dimension no parameter has.
    """
    q = _quantity(unit)
    for si in SI_UNITS:
        if q.dimensionality == _quantity(si).dimensionality:
            return si, float(q.to(_quantity(si).units).magnitude)
    raise UnitError(f"unit '{unit}' ({q.dimensionality}) is of no dimension a parameter has")


def to_si(value: float, unit: str, si: str, what: str = "") -> float:
    """``value`` in ``unit`` converted to the SI unit ``si`` (of ``what``, for messages).

    Raises:
        UnitError: ``unit`` is unknown or not of ``si``'s dimension.
    """
    q, target = _quantity(unit), _quantity(si)
    if q.dimensionality != target.dimensionality:
        dims = "dimensionless" if q.dimensionless else str(q.dimensionality)
        whose = f", the unit of {what}" if what else ""
        raise UnitError(f"unit '{unit}' ({dims}) does not convert to {si}{whose}")
    return value * float(q.to(target.units).magnitude)
