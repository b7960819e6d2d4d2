"""imudiag fleet: many logs diagnosed on Dask, per-vehicle trends, a report to open in a
browser (docs/fleet.md). A face of the house: it maps the library's :func:`imudiag.diagnose`
over the logs (:mod:`.task`) on Dask's distributed scheduler (:mod:`.runner`) and reduces
per vehicle (:mod:`.trends`); the extra ``[fleet]`` (dask[distributed], pyarrow) is
imported only when a run starts.

    import imudiag.fleet

    table = imudiag.fleet.run(["flights/"], "fleet-out", workers=2)
"""

from __future__ import annotations

from .runner import rebuild, run

__all__ = ["rebuild", "run"]
