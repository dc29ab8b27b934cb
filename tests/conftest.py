"""Shared test helpers: paths to fixtures and a writer for spec variants."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

FIXTURES = Path(__file__).parent / "fixtures"
SPECS = Path(__file__).parent.parent / "specs"


@pytest.fixture(autouse=True, scope="session")
def signing_key_home(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """A config folder of the session's own, so that run directories are signed with a key made for
    the tests (never the user's), shared by every fixture and every process the tests start."""
    home = tmp_path_factory.mktemp("config")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("XDG_CONFIG_HOME", str(home))
        yield home


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
