"""GNSS from the log itself: the IMU clock tied to GNSS time by a fitted mapping with drift.

A flight controller stamps its samples with its boot clock, and its GPS messages with both
the boot clock (when logged) and the receiver's GPS time. A boot clock is not a GNSS clock:
one real log ran 8.3 % slow against GPS time, so a constant offset is wrong. The mapping
``t_gnss = offset + rate * t_log`` is fitted by least squares over the fixes that carry both
times; its residual (rms and largest, s) is reported. A mapping that cannot be fitted (too
few fixes with a GNSS time, too short a span, a rate no clock runs at, or residuals that
jump: a clock reset or a corrupt time) is a refusal naming the reason, never a guess.
Logs whose GNSS fixes are stamped in the samples' own clock (a ROS bag's header stamps)
need no mapping: the identity, stated as such.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import BadInput
from ..logs.gnss_fixes import GnssFixes
from ..samples import SampleBlock
from ..units import conform_meta
from .tpv import GnssTrack

#: Fewest fixes with both times for a fit (offset and rate, and a residual to judge).
MIN_FIXES = 5
#: Shortest span of the fixes used, s of the log's clock.
MIN_SPAN_S = 2.0
#: Clock rates (GNSS s per log s) outside this range are not a clock's drift.
RATE_RANGE = (0.5, 2.0)
#: Largest residual, s, for the mapping to be used (a GPS message is logged within a few
#: tens of ms of its fix; a larger step is a reset or a corrupt time).
MAX_RESIDUAL_S = 0.25


@dataclass
class ClockMap:
    """``t_gnss = offset_s + rate * t_log`` (s), and how well it fits."""

    offset_s: float
    rate: float  #: GNSS s per log s (1.083: the log's clock runs 8.3 % slow)
    fixes: int  #: fixes fitted
    span_s: float  #: their span in the log's clock, s
    residual_rms_s: float
    residual_max_s: float
    how: str  #: ``fitted`` or ``same clock``
    source: str = ""

    def to_gnss(self, t_log: np.ndarray) -> np.ndarray:
        """Times of the log's clock as GNSS (UTC Unix) s."""
        return self.offset_s + self.rate * np.asarray(t_log, dtype=float)

    def to_json(self) -> dict:
        """The report's ``clock`` entry (units in the names)."""
        return {
            "how": self.how,
            "offset_s": self.offset_s,
            "rate": self.rate,
            "drift_ppm": round((self.rate - 1.0) * 1e6, 3),
            "fixes": self.fixes,
            "span_s": round(self.span_s, 3),
            "residual_rms_s": self.residual_rms_s,
            "residual_max_s": self.residual_max_s,
            "source": self.source,
        }


def fit_clock(fixes: GnssFixes, where: str = "log") -> ClockMap:
    """The mapping from the log's clock to GNSS time (module doc); BadInput with the reason
    when it cannot be fitted. Fixes without a GNSS time (NaN) are not used."""
    if not np.any(np.isfinite(fixes.t_gnss)):
        if fixes.clock.startswith("same clock"):
            return ClockMap(0.0, 1.0, len(fixes), _span(fixes.t_log), 0.0, 0.0,
                            "same clock", fixes.clock)  # fmt: skip
        raise BadInput(f"{where}: cannot tie the IMU clock to GNSS time: no GNSS fix carries "
                       f"a GNSS time ({fixes.clock or fixes.source})")  # fmt: skip
    ok = np.isfinite(fixes.t_gnss) & np.isfinite(fixes.t_log)
    x, y = fixes.t_log[ok], fixes.t_gnss[ok]
    span = _span(x)
    if x.shape[0] < MIN_FIXES or span < MIN_SPAN_S:
        raise BadInput(
            f"{where}: cannot tie the IMU clock to GNSS time: {x.shape[0]} fixes with a GNSS "
            f"time over {span:.3g} s of the log (a fit of offset and rate needs at least "
            f"{MIN_FIXES} over {MIN_SPAN_S:g} s)"
        )
    x0 = float(np.mean(x))
    a = np.column_stack([np.ones_like(x), x - x0])
    coef, *_ = np.linalg.lstsq(a, y - y[0], rcond=None)
    rate = float(coef[1])
    res = (y - y[0]) - a @ coef
    rms, worst = float(np.sqrt(np.mean(res**2))), float(np.max(np.abs(res)))
    if not (RATE_RANGE[0] <= rate <= RATE_RANGE[1]):
        raise BadInput(
            f"{where}: cannot tie the IMU clock to GNSS time: the fitted rate is {rate:.6g} "
            f"GNSS s per log s (a clock runs between {RATE_RANGE[0]:g} and {RATE_RANGE[1]:g})"
        )
    if worst > MAX_RESIDUAL_S:
        k = int(np.argmax(np.abs(res)))
        raise BadInput(
            f"{where}: cannot tie the IMU clock to GNSS time: the fix at t = {x[k]:.3f} s of "
            f"the log is {res[k]:+.3f} s off the fitted offset and rate (largest allowed "
            f"{MAX_RESIDUAL_S:g} s: a clock reset or a corrupt GNSS time)"
        )
    offset = float(y[0] + coef[0] - rate * x0)
    return ClockMap(offset, rate, int(x.shape[0]), span, rms, worst, "fitted", fixes.clock)


def _span(t: np.ndarray) -> float:
    t = t[np.isfinite(t)]
    return float(t[-1] - t[0]) if t.shape[0] > 1 else 0.0


def track_of_fixes(fixes: GnssFixes, clock: ClockMap) -> GnssTrack:
    """The fixes as a :class:`.tpv.GnssTrack` in GNSS time: each fix at its own GNSS time
    where it has one, else at its log time mapped."""
    t = np.where(np.isfinite(fixes.t_gnss), fixes.t_gnss, clock.to_gnss(fixes.t_log))
    keep = np.isfinite(t)
    order = np.argsort(t[keep], kind="stable")
    t = t[keep][order]
    uniq = np.concatenate(([True], np.diff(t) > 0))  # one fix per GNSS time

    def col(v: np.ndarray) -> np.ndarray:
        return v[keep][order][uniq]

    return GnssTrack(
        t=t[uniq],
        mode=col(fixes.mode),
        status=col(fixes.status),
        lat_deg=col(fixes.lat_deg),
        lon_deg=col(fixes.lon_deg),
        alt_m=col(fixes.alt_m),
        vel_ned=col(fixes.vel_ned),
        eps=col(fixes.eps),
        epc=np.full(int(np.sum(uniq)), math.nan),
        device=fixes.source,
    )


def block_in_gnss_time(block: SampleBlock, clock: ClockMap) -> SampleBlock:
    """The samples with ``t`` mapped to GNSS time (the outputs unchanged)."""
    return SampleBlock(
        t=clock.to_gnss(block.t), gyro=block.gyro, accel=block.accel, temp=block.temp,
        flags=block.flags, seq=block.seq, meta=block.meta,
    )  # fmt: skip


#: What ``gnss=`` / ``--gnss`` accept besides a gpsd log's path or a track.
GNSS_CHOICES = ("auto", "log", "none")


def moving_base_for_recording(
    block: SampleBlock,
    cert: object,
    gnss: object,
    fixes: GnssFixes | None,
    cfg: object = None,
    rate_hz: float | None = None,
    where: str = "log",
) -> dict | None:
    """The ``moving_base`` report section of a recording, or None when there is no GNSS.

    ``gnss``: ``"auto"`` (the log's own fixes where it has them; a clock that cannot be
    tied to GNSS time is then reported, with the reason, instead of the section), ``"log"``
    (the log's own fixes, a refusal when it has none or its clock cannot be tied),
    ``"none"`` / None (no moving-base diagnosis), a gpsd TPV log's path (``gpspipe -w``;
    both in UTC Unix time), or a :class:`.tpv.GnssTrack` in the samples' clock.
    ``fixes``: the log's own (``reader.gnss()``). ``cfg``: a
    :class:`.moving.MovingConfig`. ``rate_hz``: the samples' rate in the log's clock.
    """
    from .moving import MovingConfig, moving_base_diagnosis
    from .tpv import read_gpspipe_log

    if gnss is None or gnss == "none":
        return None
    clock: ClockMap | None = None
    source: str
    if isinstance(gnss, GnssTrack):
        track, source = gnss, "GnssTrack"
    elif gnss in ("auto", "log"):
        if fixes is None or len(fixes) == 0:
            if gnss == "log":
                raise BadInput(f"{where}: --gnss log: the log holds no GNSS fixes")
            return None
        try:
            clock = fit_clock(fixes, where)
        except BadInput as exc:
            if gnss == "log":
                raise
            return {
                "verdict": "unknown",
                "reason": f"not run: {exc}",
                "gnss": {"source": fixes.source, "fixes": len(fixes)},
            }
        track, source = track_of_fixes(fixes, clock), f"the log itself: {fixes.source}"
        block = block_in_gnss_time(block, clock)
        rate_hz = rate_hz / clock.rate if rate_hz else None
    else:
        track = read_gpspipe_log(str(gnss))
        source = str(gnss)
        if len(track) and (track.t[-1] < block.t[0] or track.t[0] > block.t[-1]):
            raise BadInput(
                f"{gnss}: the GNSS log ({track.t[0]:.3f} .. {track.t[-1]:.3f} s) does not "
                f"overlap the sample log ({block.t[0]:.3f} .. {block.t[-1]:.3f} s): both need "
                "UTC Unix time"
            )
    mcfg = cfg if isinstance(cfg, MovingConfig) else MovingConfig()
    section = moving_base_diagnosis(block, cert, track, mcfg, rate_hz=rate_hz)  # type: ignore[arg-type]
    section["gnss"]["source"] = source
    section["gnss"]["clock"] = (
        clock.to_json()
        if clock is not None
        else {"how": "given: the GNSS and the samples are in one clock (UTC Unix s)"}
    )
    section["log"] = source
    return section


def gnss_section_of(
    data: object,
    cert: object,
    gnss: object = "auto",
    cfg: object = None,
    rate_hz: float | None = None,
    options: object = None,
    block_size: int | None = None,
) -> dict | None:
    """The ``moving_base`` section of a recording, or None (no GNSS): ``data`` a log's
    path (read again, with its own GNSS fixes) or a :class:`~imudiag.samples.SampleBlock`;
    ``gnss`` as :func:`moving_base_for_recording`, or a
    :class:`~imudiag.logs.gnss_fixes.GnssFixes` (fixes of the samples' clock, tied as a
    log's own)."""
    from ..logs import DEFAULT_BLOCK_SIZE, lookup, open_log

    if gnss is None or gnss == "none":
        return None
    fixes: GnssFixes | None = None
    if isinstance(gnss, GnssFixes):
        fixes, gnss = gnss, "log"
    if isinstance(data, SampleBlock):
        block, where = data, "(samples)"
    else:
        where = str(data)
        if gnss == "auto" and fixes is None and not lookup(data).may_carry_gnss:  # type: ignore[arg-type]
            return None  # a format without GNSS of its own (CSV, NPZ, a wire capture): not opened
        with open_log(data, block_size=block_size or DEFAULT_BLOCK_SIZE, options=options) as r:  # type: ignore[arg-type]
            fixes = fixes or r.gnss()
            if gnss == "auto" and fixes is None:
                return None  # a log without GNSS of its own: read once only
            to_cert = conform_meta(r.meta, cert, where)  # type: ignore[arg-type]
            blocks = [to_cert.apply(b) for b in r]  # in the certificate's units
        block = SampleBlock.concat(blocks)  # the flags kept: the aiding leaves flagged out
    return moving_base_for_recording(block, cert, gnss, fixes, cfg, rate_hz, where=where)


__all__ = [
    "GNSS_CHOICES",
    "MAX_RESIDUAL_S",
    "MIN_FIXES",
    "ClockMap",
    "block_in_gnss_time",
    "fit_clock",
    "gnss_section_of",
    "moving_base_for_recording",
    "track_of_fixes",
]
