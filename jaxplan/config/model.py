"""The whole config: :class:`Config`, one field per TOML section (each a model of
schema.py, robots.py, scenario.py, sweep.py or tune.py), and its top-level keys."""

from __future__ import annotations

import dataclasses

from pydantic.dataclasses import dataclass

from jaxplan.config.robots import RobotConfig
from jaxplan.config.scenario import ScenarioConfig
from jaxplan.config.schema import (
    FaultsConfig,
    LimitsConfig,
    Name,
    ObstacleConfig,
    PlannerConfig,
    Seed,
    SimConfig,
    WorkspaceConfig,
)
from jaxplan.config.sweep import SweepConfig
from jaxplan.config.tune import TuneConfig

__all__ = ["TOP_KEYS", "Config"]


@dataclass(frozen=True)
class Config:
    """A whole experiment, validated and resolved.  ``source`` is where it came from
    (not part of equality)."""

    name: Name
    description: str
    seed: Seed
    planner: PlannerConfig
    limits: LimitsConfig
    sim: SimConfig
    robots: tuple[RobotConfig, ...]
    scenario: ScenarioConfig | None
    sweep: SweepConfig
    faults: FaultsConfig
    workspace: WorkspaceConfig = WorkspaceConfig()
    obstacles: tuple[ObstacleConfig, ...] = ()
    tune: TuneConfig | None = None  # None: no [tune] table
    source: str = dataclasses.field(default="<string>", compare=False)

    @property
    def dim(self) -> int:
        """N, the number of spatial dimensions."""
        if self.scenario is not None:
            return self.scenario.dim
        return len(self.robots[0].start)


TOP_KEYS = tuple(f.name for f in dataclasses.fields(Config) if f.name != "source")
