"""The spec language: YAML in, a validated :class:`Spec` out, or a :class:`SpecError` with positions."""

from hritest.spec.loader import load_spec, source_of
from hritest.spec.models import Spec

__all__ = ["Spec", "load_spec", "source_of"]
