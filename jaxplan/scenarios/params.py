"""What the generators' parameter models share: :class:`GeneratorParams`, and
:func:`generates`, by which a generator function declares the model of its
``[scenario]`` keys.

A generator's keys are declared once, by the parameter model next to it (field types
from jaxplan/fields.py): the config (jaxplan/config/) validates a ``[scenario]`` table
with the model, the generator's own defaults are the model's, and the model builds its
scenario with the generator that declared it (:meth:`GeneratorParams.build`).  The
registry (jaxplan/scenarios/registry.py) maps the names to the models and generators;
nothing here or in the generators' modules imports it.
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Callable
from typing import Any, ClassVar

from jaxplan.scenarios.scenario import Scenario


class GeneratorParams:
    """What the generators' parameter models share.

    A model's fields are its generator's ``[scenario]`` keys, in the order the resolved
    config writes them.  A default of None is resolved from the other keys by
    :meth:`resolved` (``dim`` and ``end_state`` by the config: the N of the config's
    vectors, ``planner.end_state``).  ``generator``: the function that declared the model
    (:func:`generates`).
    """

    kind: ClassVar[str]
    generator: ClassVar[Callable[..., Scenario]]

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        """The ``[scenario]`` keys (besides ``kind``), in declaration order."""
        return tuple(f.name for f in dataclasses.fields(cls))

    def as_dict(self) -> dict[str, Any]:
        """The keys and their values, in declaration order."""
        return {k: getattr(self, k) for k in self.keys()}

    def resolved(self) -> GeneratorParams:
        """A copy with every None default filled in (needs ``dim`` set)."""
        return self

    def build(self, seed: int, validate: bool = True) -> Scenario:
        """The generator's scenario for these parameters (a key the generator does not
        take, random_box's dim, is left out: its box gives N)."""
        generator = self.generator
        taken = inspect.signature(generator).parameters
        args = {k: v for k, v in self.as_dict().items() if k in taken}
        return generator(seed=seed, validate=validate, **args)


def generates(params: type[GeneratorParams]):
    """Declare the decorated function ``params``' generator: ``params.build`` calls it.
    The function is returned unchanged."""

    def declare(fn: Callable[..., Scenario]) -> Callable[..., Scenario]:
        params.generator = staticmethod(fn)
        return fn

    return declare
