"""The per-sample monitor (:class:`Monitor`): certificate-corrected F0 checks, the MEMS
gyro rest-rate check, persistence, stuck outputs, excess noise and saturation.

One concern a module: :mod:`.checks` (the monitor, its checks in order), :mod:`.state`
(:class:`MonitorConfig`, the one definition of each default; :class:`TriadState`),
:mod:`.noise` (the excess-noise check), :mod:`.stuck` (stuck outputs), :mod:`.batching`
(the F0 screen that lets reads be checked in batches), :mod:`.trace` (every F0 check kept
for plots).
"""

from __future__ import annotations

from .checks import Monitor
from .noise import TRIADS_RING, NoiseCheck
from .state import MonitorConfig, TriadState
from .stuck import StuckCheck
from .trace import F0Trace

__all__ = [
    "TRIADS_RING",
    "F0Trace",
    "Monitor",
    "MonitorConfig",
    "NoiseCheck",
    "StuckCheck",
    "TriadState",
]
