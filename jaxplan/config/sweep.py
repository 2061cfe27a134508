"""[sweep] (read by `jaxplan sweep`): the weight grids, seeds, scenarios and engine,
validated into a resolved :class:`SweepConfig`.

A weight grid is a list or ``{log_min, log_max, num}`` (base-10 exponents); its values
must lie in the [planner] key's own range (the one declaration, on PlannerConfig).
Seeds are a list or ``{start = 0, num}`` (:data:`Seeds`, [tune]'s too).  The defaults
come from the validation context: ``planner`` (its weights) and ``seed``.
"""

from __future__ import annotations

import math
from typing import Annotated, Any

import numpy as np
from pydantic import (
    BeforeValidator,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic.dataclasses import dataclass

from jaxplan.config.errors import sub_value, table_keys
from jaxplan.config.scenario import ScenarioKind
from jaxplan.config.schema import (
    DEFAULT_SWEEP_ENGINE,
    MAX_SEED,
    MAX_SWEEP_POINTS,
    MAX_WEIGHT,
    SECTION_CONFIG,
    SWEEP_ENGINES,
    PlannerConfig,
    Seed,
    field_type,
)
from jaxplan.fields import FieldProblem, integer, number, one_of, range_of, show, string

__all__ = ["LogRange", "SeedRange", "Seeds", "SweepConfig", "seed_list", "weight_grid"]


_LOG_MAX = math.log10(MAX_WEIGHT)  # the largest exponent of a swept weight


@dataclass(frozen=True, config=SECTION_CONFIG)
class LogRange:
    """A weight grid ``{log_min, log_max, num}``: num values, log-spaced, base-10 exponents."""

    log_min: number(ge=-300.0, le=_LOG_MAX)
    log_max: number(le=_LOG_MAX)
    num: integer(ge=1, le=MAX_SWEEP_POINTS)

    @field_validator("log_max", mode="wrap")
    @classmethod
    def _not_below_log_min(cls, v: Any, handler: Any, info: ValidationInfo) -> float:
        x = handler(v)
        lo = info.data.get("log_min")
        if lo is not None and not x >= lo:
            raise FieldProblem(f"must be >= {lo:g}, got {show(v)}")
        return x

    @model_validator(mode="after")
    def _one_point_is_one_value(self) -> LogRange:
        if self.num == 1 and self.log_max != self.log_min:
            raise FieldProblem("num = 1 needs log_min == log_max", key="num")
        return self

    def values(self) -> tuple[float, ...]:
        return tuple(float(x) for x in np.logspace(self.log_min, self.log_max, self.num))


@dataclass(frozen=True, config=SECTION_CONFIG, kw_only=True)
class SeedRange:
    """Seeds ``{start, num}``: start, start + 1, ..., start + num - 1."""

    start: Seed = 0
    num: integer(ge=1, le=MAX_SWEEP_POINTS)

    @model_validator(mode="after")
    def _below_2_63(self) -> SeedRange:
        if self.start + self.num - 1 > MAX_SEED:
            raise FieldProblem("seeds must be < 2**63")
        return self


def _points(v: Any, what: str, table: str, limit_name: str) -> tuple:
    if not isinstance(v, (list, tuple)) or not v:
        raise FieldProblem(f"expected a non-empty array of {what} or a table {table}, got "
                           f"{show(v)}")
    if len(v) > MAX_SWEEP_POINTS:
        raise FieldProblem(f"at most {MAX_SWEEP_POINTS} {limit_name}, got {len(v)}")
    return tuple(v)


def weight_grid(name: str) -> Any:
    """The type of a [sweep] grid of [planner] ``name``: a list of values, or a log range
    (its values then), each within the planner key's range."""
    element = field_type(PlannerConfig, name)
    bounds = range_of(element)

    def grid(v: Any, info: ValidationInfo) -> tuple:
        if not isinstance(v, dict):
            return _points(v, "numbers", "{log_min, log_max, num}", "values")
        table_keys(v)
        values = sub_value(LogRange, v, "", info, missing_first=True,
                           missing="missing; a log range needs log_min, log_max, num "
                                   "(base-10 exponents)").values()
        for end, x in (("log_min", values[0]), ("log_max", values[-1])):
            if x not in bounds:
                raise FieldProblem(f"10**{end} = {x:g} is outside planner.{name}'s range "
                                   f"({_shown(bounds)})", key=end)
        return values

    return Annotated[tuple[element, ...], BeforeValidator(grid)]


def _shown(r) -> str:
    low = f">= {r.ge:g}" if r.ge is not None else f"> {r.gt:g}"
    return f"{low} and <= {r.le:g}"


def seed_list(v: Any, info: ValidationInfo) -> tuple:
    """Seeds given as a non-empty list, or a table {start = 0, num}: the list."""
    if not isinstance(v, dict):
        return _points(v, "integers", "{start, num}", "seeds")
    table_keys(v)
    seeds = sub_value(SeedRange, v, "", info, missing_first=True,
                      missing="missing; a seed range needs num (and start = 0)")
    return tuple(range(seeds.start, seeds.start + seeds.num))


def _scenario_names(v: Any) -> tuple:
    if not isinstance(v, (list, tuple)):
        raise FieldProblem(f"expected an array of scenario names, got {show(v)}")
    return tuple(v)


Seeds = Annotated[tuple[Seed, ...], BeforeValidator(seed_list)]
ScenarioNames = Annotated[tuple[ScenarioKind, ...], BeforeValidator(_scenario_names)]


@dataclass(frozen=True, config=SECTION_CONFIG)
class SweepConfig:
    """[sweep], resolved: q_obs, q_lim weight grids; seeds; scenarios (registry names,
    empty = the config's own fleet); engine ("local": this process; "ray": Ray tasks).
    Defaults: the planner's weights, the seed and the local engine."""

    q_obs: weight_grid("q_obs")
    q_lim: weight_grid("q_lim")
    seeds: Seeds
    scenarios: ScenarioNames = ()
    engine: string(one_of(SWEEP_ENGINES)) = DEFAULT_SWEEP_ENGINE

    @model_validator(mode="before")
    @classmethod
    def _defaults(cls, t: Any, info: ValidationInfo) -> Any:
        """A [sweep] table with the defaults of the context's planner and seed."""
        if not isinstance(t, dict):
            return t  # the constructor's arguments, or not a table (pydantic says so)
        table_keys(t)
        context = info.context or {}
        planner = context.get("planner") or PlannerConfig()
        return {"q_obs": (planner.q_obs,), "q_lim": (planner.q_lim,),
                "seeds": (context.get("seed", 0),), **t}
