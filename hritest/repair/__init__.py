"""Repairs scenario parameters so that object placements satisfy their constraints.

Two repairs, as in the reference (``dsas``):

* :func:`repair` moves object centres as little as possible (sum of squared displacements, each
  over its scale: in metres, or as a fraction of the coordinate's range) so that each centre lies
  in one of its allowed regions and within its bounds, no two footprints overlap and separated
  pairs are far enough apart: the paper's repair MIP, solved with OR-Tools CP-SAT on an integer
  lattice.
* :func:`clip_repair` clips a box-bounded parameter vector (the teleoperation domain).

Everything here is pure computation: no I/O, no printing, no global state. The modules: the
problem and result types (``problem``), exact validity (``validity``), the lattice program
(``lattice``), the staged repair (``solve``), infeasibility cores (``feasibility``) and clipping
(``clip``).
"""

from hritest.repair.clip import clip_repair
from hritest.repair.feasibility import check_feasible
from hritest.repair.lattice import LATTICE_BITS
from hritest.repair.problem import InfeasibleConstraints, Region, RepairProblem, RepairResult
from hritest.repair.solve import repair
from hritest.repair.validity import is_valid, violations

__all__ = [
    "LATTICE_BITS",
    "InfeasibleConstraints",
    "Region",
    "RepairProblem",
    "RepairResult",
    "check_feasible",
    "clip_repair",
    "is_valid",
    "repair",
    "violations",
]
