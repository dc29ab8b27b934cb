"""Reading spec YAML safely while remembering where every value stands in the file."""

from __future__ import annotations

import reprlib
from pathlib import Path
from typing import Any

import yaml

from hritest.errors import Issue, Location, SpecError


class SourceMap:
    """Maps a field path such as ``("measures", 1, "range")`` to its line and column.

    Built from the YAML node tree (``yaml.compose``), so errors found at any later stage,
    by pydantic or by the compiler, can point at the exact place in the user's file.
    """

    def __init__(self, file: str, root: yaml.Node | None) -> None:
        self.file = file
        self._root = root
        # Problems in the file that did not stop it from being read (duplicate keys).
        self.problems: list[Issue] = []

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


# A spec nests a handful of levels and holds hundreds of values. The limits leave room for
# generous plugin params while refusing input that would exhaust the stack or memory: YAML
# aliases share one node between many places, so a few kilobytes can expand to gigabytes.
MAX_DEPTH = 50
MAX_VALUES = 100_000


def read_yaml(path: str | Path) -> tuple[dict[str, Any], SourceMap]:
    """Reads a spec file with ``yaml.safe_load`` semantics and its node positions.

    Duplicate keys do not stop the reading: they are in the returned map's ``problems``.

    Raises:
        SpecError: the file is missing, unreadable, empty, not YAML, not a mapping, nested
            deeper than :data:`MAX_DEPTH` levels, expanding to more than :data:`MAX_VALUES`
            values through aliases, or holding an alias to itself.
    """
    file = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SpecError(Issue((), f"no such file; check the path ({Path(path).resolve()})"), file=file) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(Issue((), f"cannot be read as UTF-8 text: {exc}"), file=file) from None
    data, root, problems = parse_yaml(text, file=file)
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
    source = SourceMap(file, root)
    source.problems = problems
    return data, source


def parse_yaml(text: str, *, file: str) -> tuple[Any, yaml.Node | None, list[Issue]]:
    """Parses YAML text once into its data, its node tree and the duplicate keys found.

    The node tree is checked before any value is built: its depth, its size with aliases
    expanded, and aliases that contain themselves, so hostile input fails fast with a short message.

    Raises:
        SpecError: the text is not YAML or breaks one of the limits above.
    """
    loader = yaml.SafeLoader(text)
    try:
        root = loader.get_single_node()
        problems = [] if root is None else _check_tree(root, file)
        data = None if root is None else loader.construct_document(root)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = Location(file, mark.line + 1, mark.column + 1) if mark else None
        what = ": ".join(str(x) for x in (exc.context, exc.problem) if x)
        raise SpecError(Issue((), f"is not valid YAML: {what}", where), file=file) from None
    except yaml.YAMLError as exc:
        raise SpecError(Issue((), f"is not valid YAML: {exc}"), file=file) from None
    except RecursionError:
        raise SpecError(Issue((), _too_deep()), file=file) from None
    except ValueError as exc:  # a value YAML parses but Python refuses, such as an integer of 5,000 digits
        what = str(exc).split(";")[0]  # Python's own advice after the ';' is not for spec writers
        raise SpecError(
            Issue((), f"holds a value that cannot be read ({what}); write a shorter number"), file=file
        ) from None
    finally:
        loader.dispose()
    return data, root, problems


def _too_deep() -> str:
    return f"nests more than {MAX_DEPTH} levels deep; a spec needs a few, so flatten the structure"


def _check_tree(root: yaml.Node, file: str) -> list[Issue]:
    """Walks the node graph without recursion; returns the duplicate keys, raises on the limits."""

    def where(node: yaml.Node) -> Location:
        return Location(file, node.start_mark.line + 1, node.start_mark.column + 1)

    sizes: dict[int, int] = {}  # values below each finished node, aliases expanded
    open_nodes: set[int] = set()  # the nodes being walked: the ancestors of the current one
    problems: list[Issue] = []
    stack: list[tuple[yaml.Node, tuple, bool]] = [(root, (), False)]
    while stack:
        node, path, finished = stack.pop()
        children = _children(node)
        if finished:
            open_nodes.discard(id(node))
            sizes[id(node)] = 1 + sum(sizes[id(child)] for _, child in children)
            if sizes[id(node)] > MAX_VALUES:
                raise SpecError(
                    Issue(
                        path,
                        f"expands to more than {MAX_VALUES:,} values through YAML aliases (*name); "
                        "write the values out or share fewer of them",
                        where(node),
                    ),
                    file=file,
                )
            continue
        if id(node) in sizes:
            continue
        if id(node) in open_nodes:
            raise SpecError(
                Issue(path, "is a YAML alias that contains itself; remove the alias (*name)", where(node)),
                file=file,
            )
        if len(path) >= MAX_DEPTH:
            raise SpecError(Issue(path, _too_deep(), where(node)), file=file)
        open_nodes.add(id(node))
        stack.append((node, path, True))
        if isinstance(node, yaml.MappingNode):
            problems += _duplicate_keys(node, path, where)
        stack += [(child, (*path, part), False) for part, child in children]
    return problems


def _children(node: yaml.Node) -> list[tuple[str | int, yaml.Node]]:
    if isinstance(node, yaml.MappingNode):
        return [
            (key.value if isinstance(key, yaml.ScalarNode) else i, value) for i, (key, value) in enumerate(node.value)
        ]
    if isinstance(node, yaml.SequenceNode):
        return list(enumerate(node.value))
    return []


def _duplicate_keys(node: yaml.MappingNode, path: tuple, where) -> list[Issue]:  # noqa: ANN001 - node -> Location
    seen: dict[tuple[str, str], yaml.Node] = {}
    problems = []
    for key, _ in node.value:
        if not isinstance(key, yaml.ScalarNode) or key.tag == "tag:yaml.org,2002:merge":
            continue
        first = seen.setdefault((key.tag, key.value), key)
        if first is not key:
            problems.append(
                Issue(
                    (*path, key.value),
                    f"duplicate key {shown(key.value)} (first at line {first.start_mark.line + 1}): YAML keeps only "
                    "the last one without a word; remove one of them or merge them",
                    where(key),
                )
            )
    return problems


_SHORT = reprlib.Repr()
_SHORT.maxstring = _SHORT.maxother = 60
_SHORT.maxlist = _SHORT.maxtuple = _SHORT.maxdict = 6
_SHORT.maxlevel = 2


def shown(value: Any) -> str:
    """``repr(value)`` cut short, for echoing user input in a message however large it is."""
    return _SHORT.repr(value)
