"""Still detectors shared by the consumers of one stream (``imudiag diagnose``: the monitor
and the interval collector): identical detectors run once, detectors that differ only in
their noise figures share the window statistics. Results are those of separate detectors,
bit for bit, whatever the pace of each consumer."""

from __future__ import annotations

import inspect
from typing import Any

import numpy as np

from ..certificate import Certificate
from ..samples import SampleBlock
from .detector import QuasiStaticDetector
from .sharing import RunReader, SharedRun
from .windows import WindowStage, WindowStats


class _Flags:
    """A detector as a runner: its flags and noise variances after each block."""

    def __init__(self, detector: QuasiStaticDetector) -> None:
        self.detector = detector

    def run(self, block: SampleBlock) -> tuple[np.ndarray, dict[str, np.ndarray | None]]:
        flags = self.detector.update(block)
        return flags, dict(self.detector._noise_var)

    def copy(self) -> _Flags:
        return _Flags(self.detector.copy())


class SharedDetectorReader:
    """One consumer's view of a detector shared through a :class:`DetectorPool`: the
    :meth:`update` and :meth:`noise_sigma` of :class:`QuasiStaticDetector`, each as that
    consumer's own detector would give them at its own place in the stream (see
    :class:`RunReader`)."""

    def __init__(self, shared: SharedRun[tuple[np.ndarray, dict[str, np.ndarray | None]]]):
        self.reader = RunReader(shared)  #: its place in the shared run
        runner = shared.runner
        assert isinstance(runner, _Flags)
        self._noise = dict(runner.detector._noise_var)

    @property
    def shared(self) -> SharedRun[tuple[np.ndarray, dict[str, np.ndarray | None]]]:
        """The run it reads (shared with the readers of an identical detector)."""
        return self.reader.shared

    @property
    def window_run(self) -> SharedRun[Any] | None:
        """The run of window sums its detector shares with one that differs only in its
        noise figures (None: its own)."""
        runner = self.reader.shared.runner
        assert isinstance(runner, _Flags)
        stage = runner.detector._stage
        return stage.shared if isinstance(stage, RunReader) else None

    @property
    def alone(self) -> bool:
        """Whether it went on with a detector of its own (it cut the stream differently)."""
        return self.reader.own is not None

    @property
    def explain(self) -> dict[str, Any]:
        """As :attr:`QuasiStaticDetector.explain` (of the detector whose flags this reader
        gets; a reader behind the others sees the figures of the blocks run so far)."""
        runner = self.reader.own if self.reader.own is not None else self.reader.shared.runner
        assert isinstance(runner, _Flags)
        return runner.detector.explain

    def noise_sigma(self, triad: str) -> np.ndarray | None:
        """As :meth:`QuasiStaticDetector.noise_sigma` after this reader's last block."""
        v = self._noise[triad]
        return None if v is None else np.sqrt(v)

    def update(self, block: SampleBlock) -> np.ndarray:
        """As :meth:`QuasiStaticDetector.update`: static flags (N,) bool of ``block``, the
        next samples of the stream every reader feeds."""
        if len(block) == 0:
            return np.zeros(0, dtype=bool)
        flags, self._noise = self.reader.run(block)
        return flags.copy()  # a consumer may write into its flags


class DetectorPool:
    """Hands out still detectors for consumers of one stream (``imudiag diagnose``: the
    monitor's and the interval collector's). Identical detectors (the same certificate
    object, rate, window and options, the same noise fixed by the certificate) share one,
    run once per block; detectors that differ only in their noise figures (the monitor's
    trusts the certificate's, the collector's measures the data's) share the window sums,
    means, variances and rates of every block, and each decides on its own. Every consumer
    must ask before any of them feeds a block, and feed the same stream; one that asks
    later gets a detector of its own."""

    _SIGNATURE = inspect.signature(QuasiStaticDetector)

    def __init__(self) -> None:
        self._detectors: dict[tuple[Any, ...], SharedRun[Any]] = {}
        self._stages: dict[tuple[Any, ...], QuasiStaticDetector | SharedRun[Any]] = {}

    def detector(
        self, certificate: Certificate, rate_hz: float | None = None, **options: Any
    ) -> SharedDetectorReader:
        """A reader of the detector ``QuasiStaticDetector(certificate, rate_hz, **options)``
        would be, sharing what it can with the earlier ones."""
        det = QuasiStaticDetector(certificate, rate_hz, **options)
        bound = self._SIGNATURE.bind(certificate, rate_hz, **options)
        bound.apply_defaults()
        args = dict(bound.arguments)
        args["certificate"] = id(certificate)  # the detector keeps it alive
        args["rate_hz"] = det.rate_hz
        args["certificate_noise"] = (det._noise_fixed["gyro"], det._noise_fixed["accel"])
        key = tuple((name, repr(value)) for name, value in sorted(args.items()))
        shared = self._detectors.get(key)
        if shared is not None and not shared.fed:
            return SharedDetectorReader(shared)
        # a new detector: its window sums from those of an earlier one when alike
        stage = det._stage
        assert isinstance(stage, WindowStage)
        skey = stage.key()
        earlier = self._stages.get(skey)
        if isinstance(earlier, QuasiStaticDetector):  # its first partner: share its stage
            if isinstance(earlier._stage, WindowStage) and not earlier._stage.prefix._rows:
                run: SharedRun[WindowStats] = SharedRun(earlier._stage)
                earlier._stage = RunReader(run)
                earlier = self._stages[skey] = run
        if isinstance(earlier, SharedRun) and not earlier.fed:
            det._stage = RunReader(earlier)
        else:
            self._stages[skey] = det
        shared = self._detectors[key] = SharedRun(_Flags(det))
        return SharedDetectorReader(shared)
