"""The whole run configuration: the core sections and every process's own, one typed model.

The model is assembled from the process table: each node class brings its `Params` (its section,
named after the process) and the shared sections it reads; the supervisor, route import and the
release check at start add theirs. `build()` validates every file and override before any process is spawned, so a
misspelt key or a bad value is one clear error naming the file, the key and what is allowed.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cache
from pathlib import Path

from pydantic import create_model

from ares.app.processes import FLEET_SERVER, PROCESSES, Process
from ares.app.route_import import RouteImportSettings
from ares.app.supervisor import SupervisorSettings
from ares.core import config
from ares.core.config import CoreConfig, Params
from ares.core.manifest import ReleaseSettings

COMPOSITION_SECTIONS: dict[str, type[Params]] = {
    "supervisor": SupervisorSettings,
    "route_import": RouteImportSettings,
    "release": ReleaseSettings,
}


def sections(processes: tuple[Process, ...] = (*PROCESSES, *FLEET_SERVER)) -> dict[str, type[Params]]:
    """Every section beyond the core ones, with its model (a vehicle's and the fleet server's: one
    configuration format for both)."""
    found: dict[str, type[Params]] = dict(COMPOSITION_SECTIONS)
    for spec in processes:
        cls = spec.node_class()
        for name, model in {cls.section(): cls.Params, **cls.sections}.items():
            if found.setdefault(name, model) is not model:
                raise TypeError(f"section {name!r} is typed twice: {found[name].__name__} and {model.__name__}")
    return found


@cache
def stack_model() -> type[CoreConfig]:
    fields = {
        name: (model, config.param(doc=(model.__doc__ or name).strip().splitlines()[0], factory=model))
        for name, model in sections().items()
    }
    return create_model("StackConfig", __base__=CoreConfig, **fields)


def build(files: tuple[str | Path, ...] = (), overrides: Mapping | None = None) -> dict:
    """The validated run configuration (every default filled in) as a JSON-ready dict."""
    return config.build(stack_model(), files, overrides)
