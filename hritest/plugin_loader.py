"""Finds robot policies, human policies and tasks: one mechanism for built-ins and users' plugins.

A spec names a plugin in one of three ways:

* a registered name (``hindsight``): an entry point in the ``hritest.plugins`` group. hritest's own
  plugins in ``plugins/`` are registered there by its ``pyproject.toml``, exactly as a user's
  package would register its own;
* ``package.module:Class``: imported from the Python path;
* ``path/to/file.py:Class``: a file beside the spec (relative paths are taken from the spec's folder).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
import traceback
from functools import cache
from importlib.metadata import entry_points
from pathlib import Path

from hritest.errors import PluginError

GROUP = "hritest.plugins"


@cache
def registered() -> dict[str, str]:
    """Registered plugin names and their ``module:Class`` targets."""
    return {ep.name: ep.value for ep in entry_points(group=GROUP)}


def resolve(ref: str, *, kind: str, base: Path | None = None) -> type:
    """The class that ``ref`` names, checked to be a plugin of ``kind`` (task, robot or human).

    Raises:
        PluginError: the name is unknown, the module does not import, the class is missing,
            or the class is a plugin of another kind; the message says what to change.
    """
    target = registered().get(ref, ref)
    if ":" not in target:
        names = ", ".join(sorted(registered())) or "none installed"
        raise PluginError(
            f"unknown {kind} plugin {ref!r}: use a registered name ({names}), 'package.module:Class' "
            "or 'path/to/file.py:Class'"
        )
    module_ref, _, class_name = target.rpartition(":")
    module = _import(module_ref, base)
    cls = getattr(module, class_name, None)
    if not isinstance(cls, type):
        public = sorted(n for n, v in vars(module).items() if isinstance(v, type) and not n.startswith("_"))
        raise PluginError(
            f"{kind} plugin {ref!r}: {module_ref!r} has no class {class_name!r}; it defines {', '.join(public)}"
        )
    declared = getattr(cls, "kind", None)
    if declared != kind:
        raise PluginError(
            f"{kind} plugin {ref!r}: {cls.__qualname__} declares kind={declared!r}; a {kind} plugin class "
            f"sets the class attribute kind = {kind!r}"
        )
    return cls


def _import(module_ref: str, base: Path | None):  # noqa: ANN202 - a module
    try:
        if module_ref.endswith(".py"):
            return _import_file(Path(module_ref) if base is None else base / module_ref)
        return importlib.import_module(module_ref)
    except PluginError:
        raise
    except SystemExit as exc:  # would end hritest itself, as if it had succeeded
        raise PluginError(
            f"plugin module {module_ref!r} called sys.exit({exc.code!r}) while being imported; a plugin "
            "module must only define its classes (move that code under 'if __name__ == \"__main__\":')"
        ) from None
    except (Exception, KeyboardInterrupt) as exc:
        last = traceback.format_exception_only(exc)[-1].strip()
        raise PluginError(f"plugin module {module_ref!r} does not import: {last}") from exc


def _import_file(path: Path):  # noqa: ANN202 - a module
    path = path.resolve()
    if not path.is_file():
        raise PluginError(f"plugin file {str(path)!r} does not exist; paths are relative to the spec's folder")
    # A stable name, so worker processes and pickles agree on where the class lives.
    name = "hritest_user_plugin_" + hashlib.sha1(str(path).encode()).hexdigest()[:12]
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module
