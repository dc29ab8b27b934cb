"""Loads a spec file: safe YAML, pydantic validation, cross-reference checks, positions on errors."""

from __future__ import annotations

import copy
import functools
from pathlib import Path
from typing import Any, get_args

import pydantic

from hritest.errors import SpecError
from hritest.spec.models import Spec
from hritest.spec.references import check_references
from hritest.spec.source import SourceMap, read_yaml, shown


def load_spec(path: str | Path) -> Spec:
    """Reads and validates the spec at ``path``.

    Raises:
        SpecError: every problem found, each with file, line, column and field path.
    """
    data, source = read_yaml(path)
    issues = list(source.problems)
    try:
        spec = Spec.model_validate(data)
    except pydantic.ValidationError as exc:
        issues += _pydantic_issues(exc, data, source)
        spec = _without_unknown_keys(exc, data)
    if spec is not None:
        issues += [source.issue(path, message) for path, message in check_references(spec)]
    if issues:
        raise SpecError(issues, file=source.file)
    spec._source = source
    return spec


def _without_unknown_keys(exc: pydantic.ValidationError, data: Any) -> Spec | None:
    """The spec without its unknown keys, when they are its only problem; else ``None``.

    An unknown key is ignored by nothing else, so the names can still be checked and every
    independent problem reported in one run; other schema errors leave no spec to check.
    """
    errors = exc.errors(include_url=False)
    if any(error["type"] != "extra_forbidden" for error in errors):
        return None
    pruned = copy.deepcopy(data)
    for error in errors:
        path = _data_path(error["loc"], data)
        parent = functools.reduce(lambda node, part: node[part], path[:-1], pruned)
        parent.pop(path[-1], None)
    try:
        return Spec.model_validate(pruned)
    except pydantic.ValidationError:
        return None


def source_of(spec: Spec) -> SourceMap:
    """The positions of ``spec``'s values in its file (an empty map for specs built in code)."""
    return spec._source or SourceMap("<spec>", None)


def _pydantic_issues(exc: pydantic.ValidationError, data: Any, source: SourceMap) -> list:
    messages: dict[tuple, list[str]] = {}
    for error in exc.errors(include_url=False):
        path = _data_path(error["loc"], data)
        message = _reword(error, path, data)
        if message not in messages.setdefault(path, []):
            messages[path].append(message)
    return [source.issue(path, " or ".join(texts)) for path, texts in messages.items()]


def _data_path(loc: tuple, data: Any) -> tuple:
    """Drops the parts of pydantic's location that are not in the data (union and validator tags)."""
    path: list[str | int] = []
    node = data
    for part in loc:
        if (isinstance(node, dict) and part in node) or (
            isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node)
        ):
            node = node[part]
        else:
            continue
        path.append(part)
    return tuple(path)


def _reword(error: dict, path: tuple, data: Any) -> str:
    kind = error["type"]
    if kind == "extra_forbidden":
        allowed = _allowed_keys(path[:-1], data)
        hint = f"; allowed here: {', '.join(allowed)}" if allowed else ""
        return f"unknown key {shown(path[-1])}{hint}"
    if kind == "missing":
        return f"missing required key {error['loc'][-1]!r}"
    value = error.get("input")
    if isinstance(value, bool) and kind in ("float_type", "int_type"):
        return f"expected a number, not {str(value).lower()}; write the number itself"
    if kind == "finite_number":
        return f"expected a finite number, not {value}; write a number (not .nan or .inf)"
    msg = error["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    if kind not in ("value_error", "missing", "union_tag_invalid", "union_tag_not_found"):
        msg = f"{msg} (got {shown(value)})"
    return msg


def _allowed_keys(path: tuple, data: Any) -> list[str]:
    """The field names of the model at ``path``, found by walking the model classes."""
    annotation: Any = Spec
    node = data
    for part in path:
        node = node[part]
        if isinstance(part, int):
            continue
        model = _model_of(annotation, node)
        field = model.model_fields.get(part) if model is not None else None
        if field is None:
            return []
        annotation = field.annotation
    model = _model_of(annotation, node)
    return list(model.model_fields) if model is not None else []


def _model_of(annotation: Any, node: Any) -> Any:
    """The pydantic model inside an annotation (list items, optional, tagged unions) for ``node``."""
    if isinstance(annotation, type) and issubclass(annotation, pydantic.BaseModel):
        return annotation
    candidates = [c for c in (_model_of(arg, node) for arg in get_args(annotation)) if c is not None]
    if isinstance(node, dict) and "type" in node:
        for candidate in candidates:
            tag = candidate.model_fields.get("type")
            if tag is not None and node["type"] in get_args(tag.annotation):
                return candidate
    return candidates[0] if candidates else None
