"""The machinery every configuration section uses: `Params` (unknown keys refused, values
validated, read-only), `param` (a field with its default, unit, range and meaning), YAML files,
the packaged files of this folder (vehicles/, tours/), merging, and validation errors
as one sentence that names the file, the key and what is allowed (`ConfigError`).
"""

from __future__ import annotations

import copy
import difflib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from pydantic.config import JsonDict
from pydantic_core import ErrorDetails

CONFIG_DIR = Path(__file__).parent  # the packaged files: vehicles/, tours/

Model = TypeVar("Model", bound=BaseModel)


class ConfigError(ValueError):
    """A configuration that cannot be used; the message names the file, the key and why."""


class Params(BaseModel):
    """Base of every configuration section: unknown keys are errors, values are validated,
    instances are read-only (a node's parameters do not change under it)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False, validate_default=True)


def param(
    default: Any = ...,
    doc: str = "",
    *,
    unit: str | None = None,
    factory: Callable[[], Any] | None = None,
    **constraints: Any,
) -> Any:
    """A configuration field: its default (or `factory` for mutable ones), what it means, its
    unit and its range (ge, gt, le, lt, pattern, ...), as `ares describe` shows them."""
    extra: JsonDict | None = {"unit": unit} if unit else None
    if factory is not None:
        return Field(default_factory=factory, description=doc, json_schema_extra=extra, **constraints)
    return Field(default, description=doc, json_schema_extra=extra, **constraints)


def load_yaml(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"no such configuration file: {path}") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of sections at the top level, got {type(data).__name__}")
    return data


def packaged_file(kind: str, name: str, folder: Path = CONFIG_DIR) -> Path:
    """Where a packaged file of <folder>/<kind>/ by that name is (it may not exist); the folder is
    this one's unless a package above keeps its own files (the simulator's scenarios)."""
    return folder / kind / f"{name}.yaml"


def named_file(kind: str, name: str, folder: Path = CONFIG_DIR) -> Path:
    """A packaged file of <folder>/<kind>/ by name, or a YAML file given by path."""
    candidate = Path(name)
    if candidate.suffix in (".yaml", ".yml") and candidate.exists():
        return candidate
    path = packaged_file(kind, name, folder)
    if not path.exists():
        known = sorted(p.stem for p in (folder / kind).glob("*.yaml"))
        raise ConfigError(f"unknown {kind[:-1]} {name!r}; known: {', '.join(known)} (or a path to a .yaml file)")
    return path


# ---- merging and validation -------------------------------------------------------------------


def deep_merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def validated(model: type[Model], data: Mapping[str, Any], source: str) -> Model:
    """`model` validated from `data`; a ConfigError naming `source`, the key and what is allowed."""
    try:
        return model.model_validate(dict(data))
    except ValidationError as exc:
        raise ConfigError(describe_errors(model, exc, source)) from None


def describe_errors(model: type[BaseModel], exc: ValidationError, source: str, prefix: str = "") -> str:
    return sentence(source, [error_line(model, err, prefix) for err in exc.errors(include_url=False)])


def sentence(source: str, lines: list[str]) -> str:
    return f"{source}: " + ("; ".join(lines) if len(lines) == 1 else "\n  " + "\n  ".join(lines))


def error_line(model: type[BaseModel], err: ErrorDetails, prefix: str = "") -> str:
    """One validation error as `key: what is wrong; what is allowed` (prefix: where model sits)."""
    loc = [str(p) for p in err["loc"]]
    key = prefix + ".".join(loc) or "<top level>"
    if err["type"] == "extra_forbidden":
        allowed = _fields_at(model, loc[:-1])
        hint = difflib.get_close_matches(loc[-1], allowed, n=1)
        maybe = f" (did you mean {hint[0]!r}?)" if hint else ""
        return f"{key}: unknown key{maybe}; allowed here: {', '.join(allowed) or '(none)'}"
    if err["type"] == "missing":
        return f"{key}: required, missing"
    return f"{key}: {err['msg']} (got {err.get('input')!r:.80})"


def _fields_at(model: type[BaseModel], loc: list[str]) -> list[str]:
    """Field names of the (nested) model at loc, or [] where it is not a model. Parts that name
    no field (list indices, mapping keys, union tags) are stepped over: the model stays the same."""
    current: Any = model
    for part in loc:
        fields = getattr(current, "model_fields", None)
        if not fields:
            return []
        if part in fields:
            current = model_in(fields[part].annotation)
    return sorted(getattr(current, "model_fields", {}) or {})


def model_in(annotation: Any) -> Any:
    """The BaseModel class inside an annotation such as `Foo | None`, if any."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()) or ():
        found = model_in(arg)
        if found is not None:
            return found
    return None


def read_secret(path: str, setting: str) -> str:
    """A secret from its file (a compose secret: docs/deploy.md), stripped; the setting that named
    the file is in the error, so that a missing secret says where it was configured."""
    try:
        return Path(path).expanduser().read_text().strip()
    except OSError as exc:
        raise ConfigError(f"{setting} {path}: {exc.strerror}") from None
