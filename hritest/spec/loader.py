"""Loads a spec file: safe YAML, pydantic validation, cross-reference checks, positions on errors."""

from __future__ import annotations

from pathlib import Path
from typing import Any, get_args

import pydantic

from hritest.errors import SpecError
from hritest.spec.models import Spec
from hritest.spec.references import check_references
from hritest.spec.source import SourceMap, read_yaml


def load_spec(path: str | Path) -> Spec:
    """Reads and validates the spec at ``path``.

    Raises:
        SpecError: every problem found, each with file, line, column and field path.
    """
    data, source = read_yaml(path)
    try:
        spec = Spec.model_validate(data)
    except pydantic.ValidationError as exc:
        raise SpecError(_pydantic_issues(exc, data, source), file=source.file) from None
    found = check_references(spec)
    if found:
        raise SpecError([source.issue(path, message) for path, message in found], file=source.file)
    spec._source = source
    return spec


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
        if (isinstance(node, dict) and part in node) or (isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node)):
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
        return f"unknown key {path[-1]!r}{hint}"
    if kind == "missing":
        return f"missing required key {error['loc'][-1]!r}"
    msg = error["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, ") :]
    if kind not in ("value_error", "missing", "union_tag_invalid", "union_tag_not_found"):
        msg = f"{msg} (got {error.get('input')!r})"
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
