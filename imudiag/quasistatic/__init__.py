"""Quasi-static detection: which samples were taken while the IMU was still.

The algorithm reads in :mod:`.detector` (:class:`QuasiStaticDetector`, its module doc
states every test); the speed machinery sits beside it, one concern a module:

- :mod:`.windows`: each trailing window's means, variances and rates from prefix sums
  carried across blocks (:class:`WindowStage`);
- :mod:`.spread`: the drift tests' trailing spreads (:class:`TrailingSpread`);
- :mod:`.sharing`, :mod:`.pool`: one detector run for the consumers of one stream
  (``imudiag diagnose``: the monitor and the interval collector), bit for bit what
  separate detectors give (:class:`DetectorPool`).

``tests/test_quasistatic_paths.py`` checks the fast paths against plain definitions.
"""

from __future__ import annotations

from .detector import QuasiStaticDetector, static_mask
from .pool import DetectorPool, SharedDetectorReader
from .sharing import RunReader
from .spread import TrailingSpread
from .windows import BAD_FLAGS, WindowStage, WindowStats

__all__ = [
    "BAD_FLAGS",
    "DetectorPool",
    "QuasiStaticDetector",
    "RunReader",
    "SharedDetectorReader",
    "TrailingSpread",
    "WindowStage",
    "WindowStats",
    "static_mask",
]
