"""Run the soak: the real daemon over hours of 1 kHz data, as fast as it goes, and judge it.

The :class:`imudiag.service.daemon.Daemon` is built from the same
configuration as ``imudiag run`` (bundled config, a certificate at the
stream's rate) with the ``soak://`` source (:mod:`soak.source`) and status
going to a :class:`soak.status_check.StatusStream` through the real
JSON-lines sink. Only the reconnect back-off is shortened (1 ms), since a
replay at full speed cannot wait wall-clock seconds for each unplug.

Passes when: the daemon ran to the end of the stream without an exception;
the final counters equal the injected tally exactly (bytes, frames,
crc_errors, skipped_bytes, lost, duplicates), as do the monitor's ADC-error
count and the reconnects; the last status ``t`` is the last sample's time
(after every ``time_us`` wrap); every status line was well-formed with ``t``
and counters never going back; every sensor-fault episode was reported; and
the resident memory after the warm-up (``WARMUP_S`` or a tenth of the run,
whichever is longer) grew by at most ``rss_limit_mb``.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from imudiag.certificate import load_default
from imudiag.service.config import default_config, merge_cli
from imudiag.service.daemon import Daemon, settings_from_config
from imudiag.service.status import JsonLinesSink

from . import source as _source  # noqa: F401 - registers soak://
from .status_check import MONITOR_CAUSES, StatusStream
from .stream import Episode

RSS_LIMIT_MB = 5.0  #: resident growth allowed after the warm-up, MB
#: data time, s, before memory must be flat: the diagnosis fills its fixed-size window
#: (16 intervals, about 6 min of the static scenario) and buffers in the first ~13 min
WARMUP_S = 900.0
DETECT_MARGIN_S = 2.0  #: a fault must be reported by an episode's end plus this, s
CLEAR_MARGIN_S = 10.0  #: a monitor fault this long after an episode still belongs to it, s


_PAGE_BYTES = os.sysconf("SC_PAGE_SIZE")


def rss_bytes() -> int:
    """This process's resident set size now, bytes (Linux /proc)."""
    with open("/proc/self/statm", encoding="ascii") as fh:
        return int(fh.read().split()[1]) * _PAGE_BYTES


class RssProbe:
    """A status sink that samples this process's resident memory every ``every_s`` of data."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s
        self.samples: list[tuple[float, int]] = []  #: (sample time s, RSS bytes)
        self._next = 0.0

    def publish(self, status: dict[str, Any]) -> None:
        """Record RSS when the data time passed the next sampling point."""
        t = status.get("t")
        if t is not None and t >= self._next:
            self.samples.append((float(t), rss_bytes()))
            self._next = t + self.every_s

    def close(self) -> None:
        """Nothing to release."""


@dataclass
class SoakResult:
    """What a soak run measured and whether it passed."""

    hours: float
    rate_hz: float
    samples: int
    wall_s: float
    samples_per_s: float
    status_lines: int
    status_errors: list[str]
    counters: dict[str, int]
    expected_counters: dict[str, int]
    adc_errors: int
    expected_adc_errors: int
    reconnects: int
    expected_reconnects: int
    events: dict[str, int]
    t_last: float | None
    expected_t_last: float
    episodes: int
    episodes_detected: int
    monitor_false_alarms: int
    rss_mb_start: float
    rss_mb_end: float
    rss_growth_mb: float
    rss_slope_mb_per_h: float
    rss_samples: list[tuple[float, float]] = field(repr=False)
    failures: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        """True when every check held."""
        return not self.failures

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (RSS samples thinned to at most 200)."""
        d = asdict(self)
        step = max(1, len(self.rss_samples) // 200)
        d["rss_samples"] = [(round(t, 1), round(m, 2)) for t, m in self.rss_samples[::step]]
        d["passed"] = self.passed
        return d


def _fault_matches(ep: Episode, fault: dict[str, Any]) -> bool:
    if ep.kind == "bias":
        return fault.get("triad") == "accel" and fault.get("cause") == "f0"
    return fault.get("sensor") == "gx" and fault.get("cause") == "stuck"


class EpisodeJudge:
    """Judges the fault reports as they come (constant memory).

    An episode counts as reported when a status line with ``t`` in
    [start, end + DETECT_MARGIN_S] lists its fault; a *false alarm* is a
    monitor fault (cause f0, stuck, saturation) appearing at a ``t`` outside
    every [start, end + CLEAR_MARGIN_S].
    """

    def __init__(self, episodes: list[Episode]) -> None:
        self.episodes = episodes
        self.detected = [False] * len(episodes)
        self.false_alarms = 0
        self._active: set[tuple[str, str, str]] = set()

    def observe(self, t: float, faults: list[dict[str, Any]]) -> None:
        """A status line whose fault list changed, at sample time ``t`` s."""
        for i, ep in enumerate(self.episodes):
            if not self.detected[i] and ep.t_start <= t <= ep.t_end + DETECT_MARGIN_S:
                self.detected[i] = any(_fault_matches(ep, f) for f in faults)
        now = {
            (f["triad"], f.get("sensor", ""), f["cause"])
            for f in faults
            if f["cause"] in MONITOR_CAUSES
        }
        onsets = now - self._active
        self._active = now
        if onsets and not any(ep.t_start <= t <= ep.t_end + CLEAR_MARGIN_S for ep in self.episodes):
            self.false_alarms += len(onsets)


def run_soak(
    hours: float = 24.0,
    rate_hz: float = 1000.0,
    seed: int = 0,
    error_rate: float = 1.0,
    episode_every_s: float = 600.0,
    diagnosis: bool = True,
    rss_every_s: float = 60.0,
    rss_limit_mb: float = RSS_LIMIT_MB,
) -> SoakResult:
    """Replay ``hours`` of ``rate_hz`` data with injected faults through the daemon; judge it."""
    url = (
        f"soak://?hours={hours!r}&seed={seed}&rate={rate_hz!r}&errors={error_rate!r}"
        f"&episodes={episode_every_s!r}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        cert = load_default()
        cert.sample_rate = float(rate_hz)
        cert_path = Path(tmp) / "certificate.yaml"
        cert.save(cert_path)
        config = merge_cli(default_config(), {"source": url, "certificate": str(cert_path)})
        settings = settings_from_config(config)
        settings.reconnect_min_s = 0.001
        settings.reconnect_max_s = 0.01
        settings.diagnosis = diagnosis
        probe = RssProbe(rss_every_s)
        daemon = Daemon(settings, [])
        src = daemon.source.inner
        judge = EpisodeJudge(src.stream.episodes)  # type: ignore[attr-defined]
        lines = StatusStream(judge.observe)
        daemon.sinks = [JsonLinesSink(lines), probe]  # type: ignore[list-item]
        t0 = time.perf_counter()
        daemon.run()
        wall = time.perf_counter() - t0
    inj = src.injected  # type: ignore[attr-defined]
    stream = src.stream  # type: ignore[attr-defined]
    last = lines.last or {}
    counters = dict(last.get("counters", {}))
    expected = inj.counters()
    t_last_expected = (stream.total_samples - 1) / rate_hz
    failures: list[str] = []
    if lines.errors:
        failures.append(f"{len(lines.errors)} malformed status lines, first: {lines.errors[0]}")
    if counters != expected:
        diff = {k: (counters.get(k), v) for k, v in expected.items() if counters.get(k) != v}
        failures.append(f"counters differ from the injected tally (got, expected): {diff}")
    if daemon.monitor.adc_errors != inj.adc_errors:
        failures.append(f"adc_errors {daemon.monitor.adc_errors} != injected {inj.adc_errors}")
    reconnects = int(daemon.source.reconnects)
    if reconnects != inj.reconnects:
        failures.append(f"reconnects {reconnects} != injected unplugs {inj.reconnects}")
    t_last = last.get("t")
    if t_last is None or abs(t_last - t_last_expected) > 1e-6:
        failures.append(f"last status t {t_last} != last sample time {t_last_expected}")
    detected, false_alarms = sum(judge.detected), judge.false_alarms
    if detected != len(stream.episodes):
        failures.append(f"only {detected} of {len(stream.episodes)} fault episodes reported")
    mb = 1.0 / 2**20
    rss = [(t, r * mb) for t, r in probe.samples]
    warm_t = max(WARMUP_S, 0.1 * hours * 3600.0)
    after = [(t, m) for t, m in rss if t >= warm_t] or rss[-1:]
    start_mb = after[0][1] if after else float("nan")
    growth = max(m for _, m in after) - start_mb if after else float("nan")
    slope = 0.0
    if len(after) >= 3:
        ts = np.array([t for t, _ in after]) / 3600.0
        slope = float(np.polyfit(ts, np.array([m for _, m in after]), 1)[0])
    if not growth <= rss_limit_mb:
        failures.append(
            f"resident memory grew {growth:.2f} MB after the warm-up (limit {rss_limit_mb} MB)"
        )
    return SoakResult(
        hours=hours,
        rate_hz=rate_hz,
        samples=stream.total_samples,
        wall_s=wall,
        samples_per_s=stream.total_samples / wall,
        status_lines=lines.lines,
        status_errors=lines.errors[:10],
        counters=counters,
        expected_counters=expected,
        adc_errors=daemon.monitor.adc_errors,
        expected_adc_errors=inj.adc_errors,
        reconnects=reconnects,
        expected_reconnects=inj.reconnects,
        events=dict(inj.events),
        t_last=t_last,
        expected_t_last=t_last_expected,
        episodes=len(stream.episodes),
        episodes_detected=detected,
        monitor_false_alarms=false_alarms,
        rss_mb_start=start_mb,
        rss_mb_end=rss[-1][1] if rss else float("nan"),
        rss_growth_mb=growth,
        rss_slope_mb_per_h=slope,
        rss_samples=rss,
        failures=failures,
    )
