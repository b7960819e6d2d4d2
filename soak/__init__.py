"""Soak test: hours of 1 kHz data with injected faults through the daemon, as fast as possible.

``python -m soak --hours 24``; see :mod:`soak.run` for what is checked.
"""

from .run import SoakResult, run_soak

__all__ = ["SoakResult", "run_soak"]
