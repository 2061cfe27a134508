"""Field types of the TOML config: pydantic annotated types with the config's own error text.

The config's section models (jaxplan/config/schema.py) and the scenario generators' parameter
models (jaxplan/scenarios/generators.py) declare their fields with these types, so that a value is
checked the same way wherever it appears.  A check that pydantic's own constraints
cannot word the way docs/DESIGN.md's config errors read raises :class:`FieldProblem`;
jaxplan/config/errors.py turns every validation error into one line ``<file>: <key>: <problem>``.

Vectors (:data:`Position`) take their expected length from the validation context
``{"dim": N}`` when given (a config uses one N throughout).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Any, get_args

from pydantic import AfterValidator, BeforeValidator, Field, Strict, ValidationInfo

from jaxplan.vehicles import ROBOTS

__all__ = [
    "FieldProblem",
    "Range",
    "range_of",
    "show",
    "one_of",
    "number",
    "auto_or_number",
    "integer",
    "string",
    "END_STATES",
    "MAX_ROBOTS",
    "MAX_COORD",
    "MAX_TRIES",
    "Count",
    "Tries",
    "Dimension",
    "PositiveLength",
    "NonNegativeLength",
    "Coordinate",
    "Position",
    "Corners",
    "VehicleName",
    "VehicleNames",
    "EndState",
]

END_STATES = ("free", "rest", "auto")
MAX_ROBOTS = 1024          # largest fleet a config or generator builds
MAX_COORD = 1e6            # m or m/s: larger coordinates are a typo, not a plan
MAX_TRIES = 1_000_000      # rejection-sampling budget per point


class FieldProblem(ValueError):
    """A failed check: ``message`` is the problem as the config error shows it; ``key``
    (e.g. "control_hz", "[1]") is appended to the key path of the value checked."""

    def __init__(self, message: str, key: str = ""):
        super().__init__(message)
        self.key = key


def show(v: Any) -> str:
    """A value as an error message shows it: its repr on one line, at most 60 characters."""
    try:
        s = repr(v)
    except Exception:  # noqa: BLE001 - a hostile __repr__ must not escape
        s = f"<{type(v).__name__}>"
    s = " ".join(s.split())
    return s if len(s) <= 60 else s[:57] + "..."


def one_of(choices: Sequence[str]) -> AfterValidator:
    """A string check: the value must be one of ``choices`` (with a did-you-mean hint)."""
    choices = tuple(choices)

    def check(v: str) -> str:
        if v not in choices:
            near = difflib.get_close_matches(v, list(choices), n=1, cutoff=0.6)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise FieldProblem(f"unknown value {show(v)}{hint}; choose one of "
                               f"{', '.join(repr(c) for c in choices)}")
        return v

    return AfterValidator(check)


@dataclass(frozen=True)
class Range:
    """A numeric field's bounds as declared (None: none on that side; multiple_of: an
    integer's step), read back by :func:`range_of`: the one declaration that the
    checks, the [tune] ranges (jaxplan.config.weight_bounds) and the tests use."""

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    multiple_of: int | None = None

    def __contains__(self, x: float) -> bool:
        return ((self.gt is None or x > self.gt) and (self.ge is None or x >= self.ge)
                and (self.lt is None or x < self.lt) and (self.le is None or x <= self.le)
                and (self.multiple_of is None or x % self.multiple_of == 0))


def range_of(tp: Any) -> Range | None:
    """The :class:`Range` of a field type made by :func:`number`, :func:`integer` or
    :func:`auto_or_number` (None for any other type)."""
    return next((m for m in get_args(tp)[1:] if isinstance(m, Range)), None)


def number(**bounds: float) -> Any:
    """A finite float (an integer is taken too, a boolean is not) within ``bounds``
    (gt, ge, lt, le; give them as floats: messages print them with ``:g``)."""
    return Annotated[float, Strict(), Field(allow_inf_nan=False, **bounds), Range(**bounds)]


def auto_or_number(gt: float, le: float) -> Any:
    """"auto" (a default that depends on the fleet, resolved where it is used) or a
    finite number in (gt, le] (an integer is taken too, a boolean is not)."""
    def check(v: Any) -> Any:
        if isinstance(v, str) and v == "auto":
            return v
        if (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                or not gt < v <= le):
            raise FieldProblem(f'expected "auto" or a number > {gt:g} and <= {le:g}, '
                               f"got {show(v)}")
        return float(v)

    return Annotated[Any, BeforeValidator(check), Range(gt=gt, le=le)]


def integer(**bounds: int) -> Any:
    """An integer (not a boolean, not a float) within ``bounds`` (ge, le, multiple_of)."""
    return Annotated[int, Strict(), Field(**bounds), Range(**bounds)]


def string(*validators: Any) -> Any:
    """A string, then ``validators`` (e.g. :func:`one_of`)."""
    return Annotated[str, Strict(), *validators]


Count = integer(ge=1, le=MAX_ROBOTS)
Tries = integer(ge=1, le=MAX_TRIES)
Dimension = integer(ge=2, le=3)
PositiveLength = number(gt=0.0, le=MAX_COORD)
NonNegativeLength = number(ge=0.0, le=MAX_COORD)
Coordinate = number(ge=-MAX_COORD, le=MAX_COORD)


def _vector_shape(v: Any, info: ValidationInfo) -> tuple:
    """2 or 3 entries (exactly the context's dim when it has one); the entries are checked
    by :data:`Coordinate`."""
    if not isinstance(v, (list, tuple)):
        raise FieldProblem(f"expected an array of 2 or 3 numbers, got {show(v)}")
    dim = (info.context or {}).get("dim")
    if dim is not None and len(v) != dim:
        raise FieldProblem(f"expected {dim} coordinates (the config is {dim}-D; mixing 2-D "
                           f"and 3-D positions is not allowed), got {len(v)}")
    if len(v) not in (2, 3):
        raise FieldProblem(f"expected 2 or 3 coordinates, got {len(v)}")
    return tuple(v)


Position = Annotated[tuple[Coordinate, ...], BeforeValidator(_vector_shape)]


def _corners_shape(v: Any) -> tuple:
    if not isinstance(v, (list, tuple)) or len(v) != 2:
        raise FieldProblem(f"expected [[lower corner], [upper corner]], got {show(v)}")
    return tuple(v)


def _corners_order(v: tuple) -> tuple:
    lo, hi = v
    if len(hi) != len(lo):  # only without a dim in the context
        raise FieldProblem(f"expected {len(lo)} coordinates (the config is {len(lo)}-D; mixing "
                           f"2-D and 3-D positions is not allowed), got {len(hi)}", key="[1]")
    for d in range(len(lo)):
        if hi[d] < lo[d]:
            raise FieldProblem(f"upper corner {show(hi)} is below lower corner {show(lo)} on "
                               f"axis {d}")
    return v


Corners = Annotated[tuple[Position, Position], BeforeValidator(_corners_shape),
                    AfterValidator(_corners_order)]

VehicleName = string(one_of(ROBOTS))


def _name_list(v: Any) -> tuple:
    if isinstance(v, str):
        v = [v]
    if not isinstance(v, (list, tuple)) or not v:
        raise FieldProblem(f"expected a non-empty array of names, got {show(v)}")
    return tuple(v)


VehicleNames = Annotated[tuple[VehicleName, ...], BeforeValidator(_name_list)]
EndState = string(one_of(END_STATES))
