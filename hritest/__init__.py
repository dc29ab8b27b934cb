"""hritest: find where a robot policy fails with people, and keep those failures as tests.

The names a user's code and tests need, importable from ``hritest`` itself::

    from hritest import load_domain, evaluate_with_rollout

    domain = load_domain("specs/teleop.yaml")
    evaluation, rollout = evaluate_with_rollout(domain, domain.nominal, seed=0)
    print(evaluation.status, evaluation.objective, [str(c) for c in evaluation.fired])

They are imported on first use (PEP 562), so ``import hritest``, which the pytest plugin does at
start-up, stays cheap. A name that is also a module's (``evaluate``, ``shrink``,
``counterfactual``) is not exported here: import it from its module. Plugins implement
:mod:`hritest.protocols`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

# name -> the module that defines it
_EXPORTS = {
    "load_domain": "hritest.domain",
    "Domain": "hritest.domain",
    "evaluate_with_rollout": "hritest.evaluate",
    "Evaluation": "hritest.records",
    "EvaluationRecord": "hritest.records",
    "Clause": "hritest.records",
    "Status": "hritest.records",
    "Observation": "hritest.protocols",
    "Rollout": "hritest.protocols",
    "TaskContext": "hritest.protocols",
    "check_spec": "hritest.check",
    "HritestError": "hritest.errors",
    "SpecError": "hritest.errors",
}

__all__ = [
    "Clause",
    "Domain",
    "Evaluation",
    "EvaluationRecord",
    "HritestError",
    "Observation",
    "Rollout",
    "SpecError",
    "Status",
    "TaskContext",
    "__version__",
    "check_spec",
    "evaluate_with_rollout",
    "load_domain",
]

if TYPE_CHECKING:
    from hritest.check import check_spec
    from hritest.domain import Domain, load_domain
    from hritest.errors import HritestError, SpecError
    from hritest.evaluate import evaluate_with_rollout
    from hritest.protocols import Observation, Rollout, TaskContext
    from hritest.records import Clause, Evaluation, EvaluationRecord, Status


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'hritest' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
