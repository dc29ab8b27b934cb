"""Shared test helpers: paths to fixtures and a writer for spec variants."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

FIXTURES = Path(__file__).parent / "fixtures"
SPECS = Path(__file__).parent.parent / "specs"


@pytest.fixture
def toy_spec(tmp_path: Path):
    """Writes a variant of the toy spec beside a copy of its plugin file; returns a writer.

    ``toy_spec(old, new)`` replaces the text ``old`` with ``new`` (which must occur exactly once)
    and returns the path of the written spec.
    """
    shutil.copy(FIXTURES / "toy_plugins.py", tmp_path / "toy_plugins.py")
    base = (FIXTURES / "toy.yaml").read_text()

    def write(old: str = "", new: str = "", *, text: str | None = None) -> Path:
        if text is None:
            assert base.count(old) == 1 or old == "", f"{old!r} must occur once in toy.yaml"
            text = base.replace(old, new) if old else base
        path = tmp_path / "spec.yaml"
        path.write_text(text)
        return path

    return write
