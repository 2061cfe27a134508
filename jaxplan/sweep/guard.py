"""The config guard of sweep and tune directories (docs/DESIGN.md "A sweep directory",
"A tune directory"): a directory keeps the resolved config it was made with in
config.toml, whose first line names this version's behaviour revision, and a run with a
different config, or by a version of another behaviour revision, is refused rather than
resumed, so that rows of two different planners never mix.

    guard_config(out, config, kind="sweep")     keep config.toml; refuse another config
    BEHAVIOUR_REVISION, stamped(text), check_revision(path, text, kind)
    FREE                                        per kind: what may differ between runs

Both `jaxplan sweep` (kind "sweep") and `jaxplan tune` (kind "tune") call
:func:`guard_config`; they differ only in what may change between runs in one directory
(:data:`FREE`).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from jaxplan.config import Config, ConfigError, config_to_toml, parse_config
from jaxplan.files import atomic_write_text, file_lock
from jaxplan.sweep.table import SweepError

__all__ = ["BEHAVIOUR_REVISION", "FREE", "check_revision", "guard_config", "stamped"]

# What may differ between two runs in one directory, per kind of directory: top-level
# keys (None: the whole key or table) and, for a table, the keys of it (the rest of the
# table must be equal).  A sweep may grow its grid; a tune may grow its trials, change
# its batch and its held-out seeds, and never its search (weights, scenarios, objective).
FREE: dict[str, dict[str, tuple[str, ...] | None]] = {
    "sweep": {"sweep": None, "tune": None, "name": None, "description": None},
    "tune": {"sweep": None, "name": None, "description": None,
             "tune": ("trials", "batch", "holdout_seeds")},
}

# keys added later whose default changed what a run does: a config.toml without one was
# written by a version that behaved as this value (so resuming it under the new default
# is a different config, not the same one)
# (a 3-D fleet under "auto" then never sidestepped: 1e4 s, the longest wait, stands for
# that, so that such a directory is refused rather than resumed under the new rule)
_LEGACY_VALUES = {("planner", "coast_samples"): 0, ("planner", "deadlock"): "off",
                  ("planner", "sidestep_wait_3d_s"): 1e4,
                  ("planner", "sidestep_mutual_at_once"): False,
                  ("planner", "stall_window_mutual_s"): 1e4,
                  ("planner", "sidestep_hold_mutual_s"): 2.0}


# What a run does beyond what its config says.  Raise it with every change to the
# planner, the simulation or the metrics that changes a sweep's rows without a config
# key (a rule, a constant, a metric's definition): the sweep and tune directories carry
# it in config.toml's first line, and one made by another revision is refused rather
# than resumed with rows of two versions (one without the line counts as revision 0).
BEHAVIOUR_REVISION = 7
_REVISION = "# jaxplan behaviour revision: "


def stamped(text: str) -> str:
    """config.toml's text with this version's behaviour revision as its first line."""
    return f"{_REVISION}{BEHAVIOUR_REVISION}\n{text}"


def check_revision(path: Path, text: str, kind: str) -> None:
    """Raise SweepError when the config.toml ``text`` at ``path`` was written by another
    behaviour revision (:data:`BEHAVIOUR_REVISION`) than this version's."""
    first = text.split("\n", 1)[0].strip()
    rest = first[len(_REVISION):].strip() if first.startswith(_REVISION.strip()) else ""
    revision = int(rest) if rest.isdigit() else 0
    if revision != BEHAVIOUR_REVISION:
        raise SweepError(f"{path}: this {kind} directory was made by jaxplan behaviour "
                         f"revision {revision}, this version is {BEHAVIOUR_REVISION} (its "
                         "runs differ where no config key says so); use another --out")


def guard_config(out, config: Config, kind: str = "sweep") -> None:
    """Keep ``out``/config.toml (the resolved config, :func:`stamped`); raise SweepError
    when the directory was made with a different config (anything but :data:`FREE`
    ``[kind]``) or by another behaviour revision, or its config.toml cannot be read.
    Under the file's lock: shards of one sweep start side by side in one directory."""
    path = Path(out) / "config.toml"
    with file_lock(path):
        _check_and_write_config(path, config, kind)


def _strip(doc: dict, free: dict[str, tuple[str, ...] | None]) -> dict:
    """``doc`` without what may differ (:data:`FREE`)."""
    out = {k: v for k, v in doc.items() if k not in free}
    for table, keys in free.items():
        if keys is not None:
            out[table] = {k: v for k, v in doc.get(table, {}).items() if k not in keys}
    return out


def _check_and_write_config(path: Path, config: Config, kind: str) -> None:
    text = config_to_toml(config)
    if path.exists():
        try:
            raw = path.read_text("utf-8")
            old = tomllib.loads(raw)
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise SweepError(f"{path}: unreadable ({e}); use another --out") from None
        check_revision(path, raw, kind)
        # compare resolved configs: a key added later with its default (written by this
        # version, absent from an older config.toml) is no difference, unless the
        # default changed the behaviour (_LEGACY_VALUES)
        for (table, key), value in _LEGACY_VALUES.items():
            if isinstance(old.get(table, {}), dict) and key not in old.get(table, {}):
                old.setdefault(table, {})[key] = value
        try:
            old = tomllib.loads(config_to_toml(parse_config(old, source=str(path))))
        except ConfigError as e:
            raise SweepError(f"{path}: not a config this version reads ({e}); use another "
                             "--out") from None
        free = FREE[kind]
        old, new = _strip(old, free), _strip(tomllib.loads(text), free)
        if old != new:
            diff = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
            raise SweepError(f"{path}: this {kind} directory was made with a different "
                             f"config (differs in: {', '.join(diff)}); use another --out")
    atomic_write_text(path, stamped(text))
