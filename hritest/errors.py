"""The exceptions hritest raises on purpose, all under one root."""

from __future__ import annotations

from dataclasses import dataclass


class HritestError(Exception):
    """Root of every error hritest raises on purpose: the CLI turns these into exit code 2."""


@dataclass(frozen=True)
class Location:
    """Where a value came from in a spec file: 1-based line and column."""

    file: str
    line: int
    column: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}"


@dataclass(frozen=True)
class Issue:
    """One thing wrong with a spec: the field's path, what is wrong, and where it stands."""

    path: tuple[str | int, ...]
    message: str
    location: Location | None = None

    @property
    def field(self) -> str:
        """The path as a user writes it: ``measures[1].range``."""
        return format_path(self.path)

    def __str__(self) -> str:
        where = f"{self.location}: " if self.location else ""
        field = f"{self.field}: " if self.path else ""
        return f"{where}{field}{self.message}"


def format_path(path: tuple[str | int, ...]) -> str:
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out


class SpecError(HritestError):
    """A spec that cannot be used, with every issue found and where it stands in the file."""

    def __init__(self, issues: list[Issue] | Issue, *, file: str | None = None) -> None:
        self.issues = [issues] if isinstance(issues, Issue) else list(issues)
        self.file = file
        super().__init__(str(self))

    def __str__(self) -> str:
        lines = [str(issue) for issue in self.issues]
        if self.file and not any(issue.location for issue in self.issues):
            lines = [f"{self.file}: {line}" for line in lines]
        return "\n".join(lines)


class PluginError(HritestError):
    """A plugin that cannot be found, imported or constructed."""
