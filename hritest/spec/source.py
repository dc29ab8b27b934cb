"""Reading spec YAML safely while remembering where every value stands in the file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from hritest.errors import Issue, Location, SpecError


class SourceMap:
    """Maps a field path such as ``("measures", 1, "range")`` to its line and column.

    Built from the YAML node tree (``yaml.compose``), so errors found at any later stage,
    by pydantic or by the compiler, can point at the exact place in the user's file.
    """

    def __init__(self, file: str, root: yaml.Node | None):
        self.file = file
        self._root = root

    def locate(self, path: tuple[str | int, ...]) -> Location | None:
        """The deepest node on ``path`` (a missing key points at its parent mapping)."""
        node = self._root
        if node is None:
            return None
        for part in path:
            child = _child(node, part)
            if child is None:
                break
            node = child
        mark = node.start_mark
        return Location(self.file, mark.line + 1, mark.column + 1)

    def issue(self, path: tuple[str | int, ...], message: str) -> Issue:
        return Issue(path=tuple(path), message=message, location=self.locate(path))

    def error(self, path: tuple[str | int, ...], message: str) -> SpecError:
        return SpecError([self.issue(path, message)], file=self.file)


def _child(node: yaml.Node, part: str | int) -> yaml.Node | None:
    if isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            if key.value == str(part):
                # An unknown key is best shown at the key itself; a value at its value.
                return value
        return None
    if isinstance(node, yaml.SequenceNode) and isinstance(part, int) and 0 <= part < len(node.value):
        return node.value[part]
    return None


def read_yaml(path: str | Path) -> tuple[dict[str, Any], SourceMap]:
    """Reads a spec file with ``yaml.safe_load`` semantics and its node positions.

    Raises:
        SpecError: the file is missing, unreadable, empty, not YAML, or not a mapping.
    """
    file = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SpecError(Issue((), f"no such file; check the path ({Path(path).resolve()})"), file=file) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(Issue((), f"cannot be read as UTF-8 text: {exc}"), file=file) from None
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = Location(file, mark.line + 1, mark.column + 1) if mark else None
        what = ": ".join(str(x) for x in (exc.context, exc.problem) if x)
        raise SpecError(Issue((), f"is not valid YAML: {what}", where), file=file) from None
    except yaml.YAMLError as exc:
        raise SpecError(Issue((), f"is not valid YAML: {exc}"), file=file) from None
    if data is None:
        raise SpecError(
            Issue(
                (),
                "is empty; a spec needs at least task, workspace, objects, parameters, "
                "robot, human, objective, measures and failure (see specs/teleop.yaml)",
            ),
            file=file,
        )
    if not isinstance(data, dict):
        kind = type(data).__name__
        raise SpecError(
            Issue(
                (),
                f"is not a hritest spec: the top level is a {kind}, expected a mapping of "
                "keys such as 'task:' and 'objects:'",
                Location(file, 1, 1),
            ),
            file=file,
        )
    return data, SourceMap(file, root)
