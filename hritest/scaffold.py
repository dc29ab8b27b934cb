"""``hritest new``: a minimal working domain to start from, a spec and its plugin file.

The two files are templates (``hritest/templates/``) filled in with the domain's name. They
follow the plugin contract of :mod:`hritest.protocols` and pass ``hritest check`` as written,
so a new user edits a domain that works rather than writing one from a blank page.
"""

from __future__ import annotations

import re
from importlib import resources
from pathlib import Path
from string import Template

from hritest.errors import HritestError

NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")  # a spec's name (hritest.spec.models.Name), and an identifier


class ScaffoldError(HritestError):
    """A domain that cannot be written: a bad name, or files that exist already."""


def write_domain(name: str, *, folder: Path) -> tuple[Path, Path]:
    """Writes ``NAME.yaml`` and ``NAME_plugins.py`` into ``folder`` (made if missing).

    Returns:
        The spec's path and the plugin file's path.

    Raises:
        ScaffoldError: ``name`` is not an identifier that starts with a letter, or either file
            exists already (then neither is written: nobody's work is overwritten).
    """
    if not NAME.match(name):
        raise ScaffoldError(
            f"{name!r} cannot name a domain: use letters, digits and '_', starting with a "
            f"letter (it names the spec and the module {name}_plugins), e.g. {suggest(name)}"
        )
    folder = Path(folder)
    files = {folder / f"{name}.yaml": "spec.yaml.tmpl", folder / f"{name}_plugins.py": "plugins.py.tmpl"}
    existing = [str(path) for path in files if path.exists()]
    if existing:
        raise ScaffoldError(
            f"{' and '.join(existing)} exist{'s' if len(existing) == 1 else ''} already; choose "
            "another NAME or --dir, or move the file away (hritest new never overwrites)"
        )
    values = {"name": name, "Name": "".join(part[:1].upper() + part[1:] for part in name.split("_"))}
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for path, template in files.items():
            text = Template((resources.files("hritest") / "templates" / template).read_text()).substitute(values)
            with open(path, "x", encoding="utf-8") as file:  # "x": fail rather than overwrite, even in a race
                file.write(text)
    except OSError as exc:
        raise ScaffoldError(
            f"cannot write the domain into {folder}: {exc.strerror or exc}; choose another --dir"
        ) from None
    spec, plugins = files
    return spec, plugins


def suggest(name: str) -> str:
    """A valid name close to ``name``: its words joined by '_', lower case, starting with a letter."""
    words = "_".join(re.findall(r"[A-Za-z0-9]+", name)).lower()
    if not words:
        return "my_domain"
    return words if words[0].isalpha() else f"domain_{words}"


__all__ = ["ScaffoldError", "suggest", "write_domain"]
