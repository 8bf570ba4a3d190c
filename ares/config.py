"""Configuration files: the stack defaults, vehicle profiles and tours.

Packaged YAML lives in ares/config/. A run's effective configuration (defaults plus the
command line's choices) is written once by `ares run` to a JSON file whose path reaches every
child process through ARES_RUN_CONFIG, so all processes of a run agree on it.
"""
from __future__ import annotations

import copy
import json
import os
from pathlib import Path
from typing import Any

import yaml

CONFIG_DIR = Path(__file__).parent / "config"
RUN_CONFIG_ENV = "ARES_RUN_CONFIG"


class ConfigError(ValueError):
    pass


def _load_yaml(path: Path) -> dict:
    try:
        with path.open() as f:
            data = yaml.safe_load(f)
    except FileNotFoundError:
        raise ConfigError(f"no such configuration file: {path}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    return data


def _named(kind: str, name: str) -> dict:
    candidate = Path(name)
    if candidate.suffix in (".yaml", ".yml") and candidate.exists():
        return _load_yaml(candidate)
    path = CONFIG_DIR / kind / f"{name}.yaml"
    if not path.exists():
        known = sorted(p.stem for p in (CONFIG_DIR / kind).glob("*.yaml"))
        raise ConfigError(f"unknown {kind[:-1]} {name!r}; known: {', '.join(known)}")
    return _load_yaml(path)


def load_vehicle(name: str) -> dict:
    return _named("vehicles", name)


def load_tour(name: str) -> dict:
    return _named("tours", name)


def deep_merge(base: dict, override: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def stack_defaults() -> dict:
    return _load_yaml(CONFIG_DIR / "stack.yaml")


def build_run_config(overrides: dict | None = None) -> dict:
    """Defaults merged with overrides, with the vehicle profile resolved into `vehicle_profile`."""
    cfg = deep_merge(stack_defaults(), overrides or {})
    cfg["vehicle_profile"] = load_vehicle(cfg["vehicle"])
    return cfg


def write_run_config(cfg: dict, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(cfg, indent=1))
    return path


def current() -> dict:
    """The run's configuration in a child process (or the defaults when run standalone)."""
    path = os.environ.get(RUN_CONFIG_ENV)
    if path:
        return json.loads(Path(path).read_text())
    return build_run_config()


def get(cfg: dict, dotted: str, default: Any = None) -> Any:
    node: Any = cfg
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return default
        node = node[part]
    return node
