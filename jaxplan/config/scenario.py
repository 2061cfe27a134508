"""[scenario]: a generator's table (or one of the paper's four), validated into a
:class:`ScenarioConfig` holding the generator's parameter model with every default
filled in.  The keys and ranges are the parameter models' own
(jaxplan/scenarios/generators.py, worlds.py); this module infers the table's N and
passes [planner] end_state (the validation context's ``end_state``) as the default.
"""

from __future__ import annotations

import functools
import typing
from typing import Any, ClassVar

from pydantic import ValidationInfo, model_validator
from pydantic.dataclasses import dataclass

from jaxplan import scenarios
from jaxplan.config.errors import sub_value, table_keys
from jaxplan.config.schema import SECTION_CONFIG
from jaxplan.fields import MAX_ROBOTS, Corners, Dimension, FieldProblem, Position, one_of, string
from jaxplan.scenarios import GENERATOR_PARAMS, PAPER_SCENARIOS, SCENARIOS
from jaxplan.vehicles import GROUND_ROBOTS

__all__ = ["GENERATOR_KEYS", "ScenarioConfig", "ScenarioKind"]

ScenarioKind = string(one_of(tuple(SCENARIOS)))
# Each generator's keys, in the order they are written out (declared by its parameter
# model in jaxplan/scenarios/).
GENERATOR_KEYS: dict[str, tuple[str, ...]] = {
    kind: params.keys() for kind, params in GENERATOR_PARAMS.items()}


@dataclass(frozen=True, config=SECTION_CONFIG)
class ScenarioConfig:
    """[scenario], resolved: kind and, for a generator, its parameter model with every
    default filled in (None for the paper's four, which take no parameters)."""

    MISSING: ClassVar[dict[str, str]] = {"kind": f"missing; choose one of {', '.join(SCENARIOS)}"}

    kind: ScenarioKind
    params: scenarios.AnyGeneratorParams | None = None

    @model_validator(mode="before")
    @classmethod
    def _from_table(cls, t: Any, info: ValidationInfo) -> Any:
        """A [scenario] table -> kind and the generator's resolved parameters."""
        if not isinstance(t, dict):
            return t  # the constructor's arguments, or not a table (pydantic says so)
        table_keys(t)
        if "kind" not in t:
            raise FieldProblem(cls.MISSING["kind"], key="kind")
        kind = sub_value(ScenarioKind, t["kind"], "kind", info)
        if kind in PAPER_SCENARIOS:
            table_keys(t, ("kind",))
            return {"kind": kind}
        model = GENERATOR_PARAMS[kind]
        table_keys(t, ("kind", *model.keys()))
        values = {k: v for k, v in t.items() if k != "kind"}
        dim = _scenario_dim(model, values, info)
        if _ground_fleet(model, values):
            dim = 2  # ground robots move in the plane: no dim and no vector given means 2-D
        values["dim"] = dim
        values.setdefault("end_state", (info.context or {}).get("end_state", "free"))
        params = sub_value(model, values, "", info, dim=dim,
                           missing="missing; give a positive integer")
        if kind == "grid_swap" and params.rows * params.cols > MAX_ROBOTS:
            raise FieldProblem(f"rows * cols must be <= {MAX_ROBOTS}, got "
                               f"{params.rows * params.cols}", key="rows")
        return {"kind": kind, "params": params.resolved()}

    def as_dict(self) -> dict[str, Any]:
        return {} if self.params is None else self.params.as_dict()

    def get(self, key: str, default: Any = None) -> Any:
        return self.as_dict().get(key, default)

    @property
    def dim(self) -> int:
        return int(self.as_dict().get("dim", 3))


def _ground_fleet(model: type, values: dict[str, Any]) -> bool:
    """The table names only ground robots and gives neither ``dim`` nor a vector."""
    vehicles = values.get("vehicles")
    return ("dim" not in values and not any(k in values for k, _ in _vector_keys(model))
            and isinstance(vehicles, (list, tuple)) and len(vehicles) > 0
            and all(isinstance(v, str) and v in GROUND_ROBOTS for v in vehicles))


@functools.cache
def _vector_keys(model: type) -> tuple[tuple[str, Any], ...]:
    """The model's position and box keys, with their types, in declaration order."""
    hints = typing.get_type_hints(model, include_extras=True)
    return tuple((k, hints[k]) for k in model.keys()
                 if hints[k] is Position or hints[k] is Corners)


def _scenario_dim(model: type, values: dict[str, Any], info: ValidationInfo) -> int:
    """N of a generator's table: ``dim`` when given, else the length of its first vector,
    else 3.  Validates ``dim`` and the vectors (in place), in that order."""
    dim = sub_value(Dimension, values["dim"], "dim", info) if "dim" in values else None
    for k, schema in _vector_keys(model):
        if k not in values:
            continue
        raw = values[k]
        if schema is Corners and dim is None:  # the upper corner must match the lower one
            lower = raw[0] if isinstance(raw, (list, tuple)) and len(raw) == 2 else None
            if isinstance(lower, (list, tuple)) and len(lower) in (2, 3):
                dim = len(lower)
        v = sub_value(schema, raw, k, info, dim=dim)
        values[k] = v
        dim = len(v) if schema is Position else len(v[0])
    return 3 if dim is None else dim
