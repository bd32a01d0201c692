"""Reading TOML configuration into validated, frozen pydantic models.

Only entry points call these; library code takes the typed models. A bad file or value raises
:class:`~colcommon.errors.ConfigError` naming the file, the key and what is expected.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

import tomllib
from pydantic import BaseModel, ConfigDict, ValidationError

from colcommon.errors import ConfigError

M = TypeVar("M", bound=BaseModel)


class Section(BaseModel):
    """Base for config sections: immutable, unknown keys are errors (catches typos)."""

    model_config = ConfigDict(frozen=True, extra="forbid")


def read_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file, turning I/O and syntax errors into ConfigError."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError as exc:
        raise ConfigError(f"config file {p} does not exist; pass an existing .toml file") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {p} is not valid TOML: {exc}") from exc


def build(model: type[M], data: dict[str, Any], source: str = "config") -> M:
    """Validate ``data`` into ``model``; errors list every bad key with its dotted path."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        lines = []
        for err in exc.errors():
            where = ".".join(str(p) for p in err["loc"]) or "(top level)"
            lines.append(f"  {where}: {err['msg']} (got {err.get('input')!r})")
        raise ConfigError(f"invalid {source}:\n" + "\n".join(lines)) from None


def section(data: dict[str, Any], *path: str) -> dict[str, Any]:
    """The nested table at ``path`` (empty if absent); a non-table is a ConfigError."""
    node: Any = data
    for key in path:
        node = node.get(key, {}) if isinstance(node, dict) else None
        if not isinstance(node, dict):
            raise ConfigError(f"[{'.'.join(path)}] must be a TOML table")
    return node


def with_experiment_task(data: dict[str, Any], tables: dict[str, Any],
                         task: dict[tuple[str, str], object]) -> dict[str, Any]:
    """``tables`` (the ``[companion]`` or ``[sitl]`` part of ``data``) with ``task``'s settings
    filled in where an experiment file (one with an ``[experiment]`` table) does not name them:
    settings added after the experiments were designed, at the values their task was run with."""
    if "experiment" not in data:
        return tables
    out = {name: dict(values) if isinstance(values, dict) else values for name, values in tables.items()}
    for (table, key), value in task.items():
        out.setdefault(table, {}).setdefault(key, value)
    return out
