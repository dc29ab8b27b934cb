"""The decorator for per-tick numeric code: numba's ``njit``, set up once for every caller.

A scenario runs hundreds to thousands of ticks, each a few small-array computations (a 6x6
solve, a handful of target poses), where numpy's per-call overhead would dominate
(docs/decisions.md, "Compiled per-tick code"). numba is already a dependency (pyribs uses it).
Kernels are:

* cached on disk beside their module (or in numba's user-wide cache where that is read-only),
  so only the first process on a machine pays the compilation (seconds);
* free of the GIL, so scenarios evaluated in threads run them in parallel.

Plugins may decorate their own per-tick code with :data:`kernel` too.
"""

from __future__ import annotations

import numba

kernel = numba.njit(cache=True, nogil=True)
