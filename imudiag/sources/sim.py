"""``sim://SCENARIO?seed=N``: the simulated board, through the real wire codec.

The simulated board's byte stream (:class:`imudiag.sim.board.SimulatedBoard`:
sample frames, a device-info frame after power-up and every 1000 frames) is
decoded by the same :class:`~imudiag.drivers.wire.Decoder` as a real port, so
the daemon sees exactly what a board would send, counters included.

URL::

    sim://                                   the static scenario (also sim://default)
    sim://static?seed=1&fault=bias:ax:30:150
    sim://multiposition?seed=3&speed=0&n=14
    sim://turntable?turn_rate=60&axis=x
    sim://vehicle?effect=bias_drift:gz:0.5,g_sensitivity:gz:0:0:1.3

Query keys:

- ``seed`` (0): random seed; the same URL gives the same samples.
- ``speed`` (1): pace relative to real time; ``0`` generates as fast as it is read.
- ``rate`` (the certificate's ``sample_rate``): samples per second, Hz.
- ``duration``: end the session after this many seconds (then EndOfStream).
- ``chunk`` (0.05): seconds of samples generated per step with ``speed=0``.
- ``fault``: ``kind:sensor:t_s[:value]``, comma-separated or repeated; kinds bias
  (output units), scale_factor (output per input unit), misalignment (pair like
  ``ax/ay``, rad), stuck, noise (sigma multiplier), dead. ``bias:ax:30:150`` is a
  +150 count bias on ax from t = 30 s.
- ``effect``: effects in the text form of :mod:`imudiag.sim.scenarios`
  (``board`` by default: white noise, whole counts, range 0..65535).
- scenario parameters (:mod:`imudiag.sim.scenarios`), e.g. ``n``, ``dwell``, ``turn``.

Options (keyword): ``certificate`` (default: the bundled one), ``effects`` (an
:class:`~imudiag.sim.Effects`, replaces ``effect=``), ``faults`` (extra
:class:`~imudiag.sim.Fault` objects). Commands: ``INFO`` is answered with a
device-info frame; ``START``, ``STOP`` and ``RATE`` are ignored (allowed by the spec).
"""

from __future__ import annotations

import math
import time
from typing import Any
from urllib.parse import parse_qs, urlsplit

from imudiag.argtypes import rate_problem
from imudiag.certificate import Certificate, load_default
from imudiag.drivers.base import EndOfStream, SourceError, SourceURL, register
from imudiag.drivers.bytesource import ByteSource
from imudiag.sim.board import SimulatedBoard
from imudiag.sim.scenarios import (
    canonical_scenario,
    parse_effects,
    parse_faults,
    scenario_motion,
    scenario_params,
    split_list,
)

_OWN_KEYS = ("seed", "speed", "rate", "duration", "chunk", "fault", "effect")
_MAX_CATCH_UP_S = 2.0  #: seconds of samples generated per read at most when behind


@register("sim")
class SimSource(ByteSource):
    """The simulated board as a source (see the module docstring for the URL)."""

    def __init__(self, url: SourceURL, **options: Any) -> None:
        super().__init__(url, **options)
        try:
            self.scenario = canonical_scenario(url.target.strip("/"))
        except ValueError as exc:
            raise SourceError(f"{url.url}: {exc}") from None
        lists = parse_qs(urlsplit(url.url).query, keep_blank_values=True)
        allowed = _OWN_KEYS + scenario_params(self.scenario)
        for key in lists:
            if key not in allowed:
                raise SourceError(
                    f"{url.url}: unknown query key {key!r} for sim://{self.scenario}; "
                    f"expected {', '.join(allowed)}"
                )
        self.seed = int(url.get("seed", 0, int))
        self.speed = float(url.get("speed", 1.0, float))
        duration = url.get("duration", None, float)
        self.chunk_s = float(url.get("chunk", 0.05, float))
        for key, v in (("speed", self.speed), ("chunk", self.chunk_s)):
            if not math.isfinite(v) or v < 0 or (key == "chunk" and v == 0):
                raise SourceError(f"{url.url}: bad value for {key!r}: {v}")
        if duration is not None and not (duration > 0 and math.isfinite(duration)):
            raise SourceError(f"{url.url}: bad value for 'duration': {duration}")
        cert = options.get("certificate")
        self.certificate: Certificate = cert if cert is not None else load_default()
        rate = float(url.get("rate", self.certificate.sample_rate, float))
        if not (rate > 0 and math.isfinite(rate)) or rate_problem(rate):
            raise SourceError(f"{url.url}: bad value for 'rate': {rate_problem(rate) or rate}")
        scen_params = {k: v[-1] for k, v in lists.items() if k not in _OWN_KEYS}
        try:
            motion = scenario_motion(self.scenario, self.seed, scen_params)
            effects = options.get("effects")
            if effects is None:
                effects = parse_effects(split_list(lists.get("effect", [])))
            faults = parse_faults(split_list(lists.get("fault", [])))
        except ValueError as exc:
            raise SourceError(f"{url.url}: {exc}") from None
        faults.extend(options.get("faults", ()))
        self.board = SimulatedBoard(
            self.certificate,
            motion,
            rate,
            self.seed,
            effects,
            faults,
            duration,
            info={"scenario": self.scenario, "seed": self.seed},
        )
        self.rate_hz = rate
        self._t0: float | None = None
        #: CPU time, s, spent making the simulated board's frames: the board's cost, not the
        #: monitor's (a real board makes its frames on its own processor)
        self.board_cpu_s = 0.0

    def _open_transport(self) -> None:
        # (re)anchor the pace so that the samples already sent are due now
        done = self.board.next_index
        self._t0 = time.monotonic() - (done / (self.rate_hz * self.speed) if self.speed else 0)

    def _due(self) -> int:
        assert self._t0 is not None
        elapsed = time.monotonic() - self._t0
        return int(math.floor(elapsed * self.speed * self.rate_hz)) + 1 - self.board.next_index

    def _read_bytes(self, timeout_s: float) -> bytes:
        board = self.board
        if board.exhausted:
            raise EndOfStream(f"{self.url.url}: the simulated session has ended")
        if self.speed == 0:
            return self._generate(max(1, int(round(self.chunk_s * self.rate_hz))))
        due = self._due()
        if due <= 0:
            wait = (1 - due) / (self.rate_hz * self.speed)
            time.sleep(max(0.0, min(timeout_s, wait)))
            due = self._due()
            if due <= 0:
                return b""
        return self._generate(min(due, max(1, int(_MAX_CATCH_UP_S * self.rate_hz * self.speed))))

    def _generate(self, n: int) -> bytes:
        """The next ``n`` frames' bytes, the CPU time they took counted in board_cpu_s."""
        start = time.thread_time()
        try:
            return self.board.generate(n)[0]
        finally:
            self.board_cpu_s += time.thread_time() - start

    def _close_transport(self) -> None:
        self._t0 = None

    def _write_bytes(self, data: bytes) -> bool:
        for line in data.decode("ascii", "replace").splitlines():
            if line.strip() == "INFO":
                self.board.request_info()
        return True
