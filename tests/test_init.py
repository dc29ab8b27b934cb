"""``hritest``'s curated names: each resolves, and importing the package loads nothing heavy
(the pytest plugin imports it at every pytest start-up)."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest

import hritest


@pytest.mark.parametrize("name", [n for n in hritest.__all__ if n != "__version__"])
def test_each_exported_name_resolves_to_what_its_module_defines(name):
    module = importlib.import_module(hritest._EXPORTS[name])
    assert getattr(hritest, name) is getattr(module, name)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'evaluate_everything'"):
        hritest.evaluate_everything  # noqa: B018 - the access is the test


def test_importing_hritest_loads_no_heavy_module():
    code = "import sys, hritest; print(sorted(m for m in ('numpy', 'torch', 'mujoco', 'pydantic') if m in sys.modules))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "[]"
