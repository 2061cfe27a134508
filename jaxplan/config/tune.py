"""[tune] (read by `jaxplan tune`, jaxplan/tune/): the weights to tune and their
ranges, the scenarios and seeds, the objective and constraints, validated into a
resolved :class:`TuneConfig`.

A weight's range ``{low, high, log = false}`` must lie within the [planner] key's own
range (:func:`jaxplan.config.schema.weight_bounds`, read from its one declaration).
The validation context gives ``seed`` (the default training seed) and ``source`` (the
config file, against which a scenario's TOML path is resolved).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Annotated, Any

from pydantic import BeforeValidator, Strict, ValidationInfo, model_validator
from pydantic.dataclasses import dataclass

from jaxplan.config.errors import sub_value, table_keys
from jaxplan.config.schema import (
    DEFAULT_TUNE_BATCH,
    DEFAULT_TUNE_MIN_SEPARATION_RATIO,
    DEFAULT_TUNE_MIN_SUCCESS_RATE,
    DEFAULT_TUNE_OBJECTIVE,
    DEFAULT_TUNE_SAMPLER,
    DEFAULT_TUNE_TRIALS,
    MAX_TUNE_TRIALS,
    SECTION_CONFIG,
    TUNABLE_WEIGHTS,
    TUNE_OBJECTIVES,
    TUNE_SAMPLERS,
    ConfigError,
    Seed,
    weight_bounds,
)
from jaxplan.config.sweep import Seeds, seed_list
from jaxplan.fields import FieldProblem, integer, number, one_of, show, string
from jaxplan.scenarios import SCENARIOS

__all__ = ["TUNE_KEYS", "TuneConfig", "WeightRange", "tune_scenario_path"]


@dataclass(frozen=True, config=SECTION_CONFIG, kw_only=True)
class WeightRange:
    """One tuned weight's search range: low < high, sampled on a log scale (low > 0)
    or a linear one."""

    low: number()
    high: number()
    log: Annotated[bool, Strict()] = False

    @model_validator(mode="after")
    def _ordered(self) -> WeightRange:
        if not self.high > self.low:
            raise FieldProblem(f"must be > low = {self.low:g}, got {show(self.high)}",
                               key="high")
        if self.log and self.low <= 0.0:
            raise FieldProblem(f"a log range needs low > 0, got {show(self.low)}", key="low")
        return self


def _weights(v: Any, info: ValidationInfo) -> dict:
    """[tune.weights]: {name: range}, each name in TUNABLE_WEIGHTS, each range within
    the [planner] key's."""
    if not isinstance(v, dict):
        raise FieldProblem(f"expected a table, got {show(v)}")
    table_keys(v, TUNABLE_WEIGHTS)
    if not v:
        raise FieldProblem("name at least one weight to tune, e.g. q_obs = {low = 1.0, high = "
                           f"100.0, log = true}}; tunable: {', '.join(TUNABLE_WEIGHTS)}")
    out = {}
    for name, raw in v.items():
        if not isinstance(raw, dict):
            raise FieldProblem(f"expected a table, got {show(raw)}", key=name)
        table_keys(raw)
        r = sub_value(WeightRange, raw, name, info, missing_first=True,
                      missing="missing; a range needs low and high (and log = false)")
        lo, hi = weight_bounds(name)
        if r.low < lo:
            raise FieldProblem(f"must be >= {lo:g} (planner.{name}'s range), got "
                               f"{show(r.low)}", key=f"{name}.low")
        if r.high > hi:
            raise FieldProblem(f"must be <= {hi:g} (planner.{name}'s range), got "
                               f"{show(r.high)}", key=f"{name}.high")
        out[name] = r
    return out


def _scenario_files(v: Any, info: ValidationInfo) -> tuple:
    """Registry names, or paths of TOML configs (relative to the config file; made
    absolute) whose fleet is used; each file must load."""
    if not isinstance(v, (list, tuple)):
        raise FieldProblem(f"expected an array of scenario names, got {show(v)}")
    names = list(sub_value(tuple[string(), ...], v, "", info))
    context = info.context or {}
    source = context.get("source", "<string>")
    # the parser passes its own load_config (a scenario file is a whole config); without
    # it (a section validated again on its own) a path is only resolved
    load_config = context.get("load_config")
    for i, name in enumerate(names):
        if name.endswith(".toml"):
            path = tune_scenario_path(name, source)
            try:
                if load_config is not None:
                    load_config(path)
            except ConfigError as e:
                raise FieldProblem(str(e), key=f"[{i}]") from None
            names[i] = os.path.abspath(path)  # resolved: config.toml loads anywhere
        elif name not in SCENARIOS:
            raise FieldProblem(f"unknown scenario {show(name)}; give a registry name "
                               f"({', '.join(SCENARIOS)}) or a .toml config path", key=f"[{i}]")
    if len(set(names)) != len(names):
        raise FieldProblem("a scenario is named twice")
    return tuple(names)


def _held_out(v: Any, info: ValidationInfo) -> tuple:
    """Held-out seeds: as the training seeds, or none ([])."""
    return () if isinstance(v, (list, tuple)) and not v else seed_list(v, info)


def tune_scenario_path(name: str, source: str) -> Path:
    """A [tune] scenarios entry that names a TOML file, resolved against the directory
    of the config file ``source`` (the working directory for a config from a string)."""
    p = Path(name)
    if p.is_absolute() or source.startswith("<"):
        return p
    return Path(source).parent / p


@dataclass(frozen=True, config=SECTION_CONFIG)
class TuneConfig:
    """[tune] (read by `jaxplan tune`, jaxplan/tune/), resolved.

    weights: {name: WeightRange} of [planner] weights in TUNABLE_WEIGHTS, in the order
    given.  scenarios: registry names or paths of TOML configs whose fleet is used
    (relative to the config file); empty = the config's own fleet.  seeds: the training
    seeds; holdout_seeds: the held-out ones (may be empty).  objective (to minimize,
    over the training runs, a run that did not succeed counting as sim.duration_s) in
    TUNE_OBJECTIVES; min_success_rate, min_separation_ratio: the constraints (a penalty,
    jaxplan/tune/trials.py).  trials: trials in all; batch: trials per batch; sampler in
    TUNE_SAMPLERS; enqueue_defaults: the [planner] weights are the first trial.
    """

    weights: Annotated[dict[str, WeightRange], BeforeValidator(_weights)]
    scenarios: Annotated[tuple[str, ...], BeforeValidator(_scenario_files)]
    seeds: Seeds
    holdout_seeds: Annotated[tuple[Seed, ...], BeforeValidator(_held_out)]
    objective: string(one_of(TUNE_OBJECTIVES)) = DEFAULT_TUNE_OBJECTIVE
    min_success_rate: number(ge=0.0, le=1.0) = DEFAULT_TUNE_MIN_SUCCESS_RATE
    min_separation_ratio: number(ge=0.0, le=100.0) = DEFAULT_TUNE_MIN_SEPARATION_RATIO
    trials: integer(ge=1, le=MAX_TUNE_TRIALS) = DEFAULT_TUNE_TRIALS
    batch: integer(ge=1, le=MAX_TUNE_TRIALS) = DEFAULT_TUNE_BATCH
    sampler: string(one_of(TUNE_SAMPLERS)) = DEFAULT_TUNE_SAMPLER
    enqueue_defaults: Annotated[bool, Strict()] = True

    @model_validator(mode="before")
    @classmethod
    def _defaults(cls, t: Any, info: ValidationInfo) -> Any:
        """A [tune] table with its defaults: the context's seed, no held-out seeds, the
        config's own fleet; weights required."""
        if not isinstance(t, dict):
            return t  # the constructor's arguments, or not a table (pydantic says so)
        table_keys(t, TUNE_KEYS)
        return {"weights": {}, "scenarios": [], "holdout_seeds": (),
                "seeds": ((info.context or {}).get("seed", 0),), **t}

    @model_validator(mode="after")
    def _held_out_seeds_are_others(self) -> TuneConfig:
        both = set(self.seeds) & set(self.holdout_seeds)
        if both:
            raise FieldProblem(f"seed {min(both)} is also a training seed; held-out seeds must "
                               "be others", key="holdout_seeds")
        return self

    def __hash__(self) -> int:  # weights is a dict
        return hash((tuple(self.weights.items()), self.scenarios, self.seeds,
                     self.holdout_seeds, self.objective, self.min_success_rate,
                     self.min_separation_ratio, self.trials, self.batch, self.sampler,
                     self.enqueue_defaults))


TUNE_KEYS = tuple(f.name for f in dataclasses.fields(TuneConfig))
