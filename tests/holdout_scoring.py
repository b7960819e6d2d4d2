"""An evaluator's scoring of calibrations, independent of imudiag and of imu_tk (tests only).

- Its own still detector (:func:`still_runs`): a sample is still when, over a centred window
  of ``window_s``, every accelerometer axis keeps its standard deviation below ``factor``
  times that axis's noise and every gyro axis below ``gyro_factor`` times (hand-held holds
  sway), the noise being the 5th percentile of the windows'
  standard deviations over the record; runs of at least ``min_s`` are trimmed by ``trim_s``
  at both ends and reduced to their mean.
- Attitudes: runs whose raw accelerometer means point within ``separation_deg`` of each
  other (through the ``--like`` scale factors) share one.
- Out of sample: each attitude in turn is left out of the calibration (imudiag's fit on its
  own intervals, the imu_tk reference on its own points, both less those near that
  attitude), and the left-out attitude's runs are scored by |a| - g of their calibrated
  means (m/s^2).
- Fold plausibility: the largest change, over the scored folds, of an angle between two
  attitudes' calibrated gravity directions against the ``--like`` certificate's (deg); |a|
  alone cannot see a fold that maps every attitude near one vector of length g.
- In sample: |a| - g over every run with the calibration from the whole record, against an
  independent 9-parameter least-squares fit to the same runs (imu_tk's cost on the run
  means).

``python tests/holdout_scoring.py`` prints the table of docs/diagnosis.md.
"""

from __future__ import annotations

import copy
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

import imu_tk_reference as ref  # noqa: E402

from imudiag.certificate import Certificate, load  # noqa: E402
from imudiag.diagnosis.calibrate import calibrate  # noqa: E402
from imudiag.diagnosis.config import DiagnosisConfig  # noqa: E402
from imudiag.diagnosis.session import collect_intervals  # noqa: E402
from imudiag.logs import read_log  # noqa: E402
from imudiag.samples import SampleBlock  # noqa: E402

DATA = Path(__file__).parent / "data"

#: every real multi-position recording the project ships, with its --like certificate and
#: the initial still period imu_tk's threshold is measured on (s)
RECORDINGS = [
    ("xsens-mti-multiposition/session.csv.gz", "like-xsens.yaml", 50.0),
    ("imucal-ferraris/session.csv.gz", "like-imucal.yaml", 5.0),
    ("mpu6050/calibration.csv.gz", "like-mpu6050.yaml", 30.0),
]


def _moving_std(x: np.ndarray, w: int) -> np.ndarray:
    v = ref.local_variance(x, w)
    return np.sqrt(np.maximum(v, 0.0))


def still_runs(
    block: SampleBlock,
    window_s: float = 0.3,
    factor: float = 3.0,
    gyro_factor: float = 6.0,
    min_s: float = 0.5,
    trim_s: float = 0.1,
) -> list[tuple[int, int]]:
    """The evaluator's still runs (start, stop sample indices, stop exclusive)."""
    dt = float(np.median(np.diff(block.t)))
    w = max(11, int(round(window_s / dt)) | 1)
    sd = np.concatenate([_moving_std(block.accel, w), _moving_std(block.gyro, w)], axis=1)
    ok = np.all(np.isfinite(sd), axis=1)
    noise = np.percentile(sd[ok], 5, axis=0)
    lim = np.concatenate([np.full(3, factor), np.full(3, gyro_factor)]) * noise
    still = ok & np.all(sd <= lim, axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(np.int8), [0]])))
    trim = int(round(trim_s / dt))
    out = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        a, b = int(a) + trim, int(b) - trim
        if (b - a) * dt >= min_s:
            out.append((a, b))
    return out


def attitude_labels(ups: np.ndarray, separation_deg: float = 10.0) -> np.ndarray:
    """Attitude number (K,) of unit directions ``ups`` (K, 3): greedy, in time order."""
    centres: list[np.ndarray] = []
    labels = np.zeros(ups.shape[0], dtype=int)
    cos = math.cos(math.radians(separation_deg))
    for i, u in enumerate(ups):
        for j, c in enumerate(centres):
            if float(u @ c) > cos:
                labels[i] = j
                break
        else:
            centres.append(u)
            labels[i] = len(centres) - 1
    return labels


def _up(like: Certificate, raw: np.ndarray) -> np.ndarray:
    f = like.accel.inverse(np.atleast_2d(raw))
    return f / np.linalg.norm(f, axis=1, keepdims=True)


@dataclass
class Scores:
    """Figures of one recording (m/s^2 unless said)."""

    name: str
    runs: int  #: the evaluator's still runs
    attitudes: int  #: ... in this many attitudes
    imudiag_out: float  #: rms |a| - g of the left-out attitudes' runs, imudiag
    imu_tk_out: float  #: ... the imu_tk reference (NaN: it refuses on the record)
    folds: int  #: attitudes left out and scored by both
    imudiag_in: float  #: rms |a| - g over every run, imudiag's calibration of the record
    lsq_in: float  #: ... an independent least-squares fit to the runs
    imu_tk_in: float  #: ... the imu_tk reference's calibration of the record
    imu_tk_note: str  #: why the imu_tk reference refuses or is relaxed, or ""
    #: largest change (deg) of an angle between two attitudes' calibrated gravity directions
    #: against the ``--like`` certificate's, over the scored folds' calibrations: a physical
    #: calibration moves them by its misalignment (mrad); a fold that maps every attitude
    #: near one vector of length g meets |a| = g on the left-out attitude trivially
    imudiag_fold_angle_deg: float = float("nan")
    imu_tk_fold_angle_deg: float = float("nan")  #: ... the imu_tk reference's folds


def _imudiag_accel(intervals: list, like: Certificate, rate: float):
    return calibrate(intervals, like, "exact", rate, config=DiagnosisConfig()).certificate.accel


def score_recording(
    recording: str, like_name: str, init_s: float, config: DiagnosisConfig | None = None
) -> Scores:
    """Score imudiag and the imu_tk reference on one shipped recording."""
    block = read_log(DATA / "real" / recording)
    like = load(DATA / "diagnosis" / like_name)
    cfg = config or DiagnosisConfig()
    g = like.gravity
    runs = still_runs(block)
    means = np.array([block.accel[a:b].mean(axis=0) for a, b in runs])
    ups = _up(like, means)
    labels = attitude_labels(ups)
    intervals, rate, _ = collect_intervals(block, like, cfg)
    iv_ups = _up(like, np.array([iv.accel_mean for iv in intervals]))

    acc_sf = like.accel.scale_factor
    scale0, bias0 = like.accel.unit_to_si / acc_sf, like.accel.bias.copy()
    note = ""
    tk = ref.calibrate_acc(block.t, block.accel, g, scale0, bias0, init_s)
    min_iv = ref.MIN_INTERVALS
    if tk is None:  # imu_tk refuses below 12 intervals: the reference relaxed to 9, said so
        min_iv = 9
        tk = ref.calibrate_acc(block.t, block.accel, g, scale0, bias0, init_s, min_iv)
        note = "imu_tk refuses (< 12 intervals); reference run with 9"
        if tk is None:
            note = "imu_tk refuses (< 9 intervals at every threshold)"
    tk_points = None
    tk_iv_ups = None
    if tk is not None:
        tk_points, _ = ref.interval_points(block.accel, tk.intervals)
        tk_iv_ups = _up(
            like, np.array([block.accel[a : b + 1].mean(axis=0) for a, b in tk.intervals])
        )

    def err(cal_apply, raw: np.ndarray) -> np.ndarray:
        return np.linalg.norm(cal_apply(raw), axis=1) - g

    def imudiag_apply(accel):
        return lambda raw: accel.inverse_si(raw)

    full = _imudiag_accel(intervals, like, rate)
    inside = err(imudiag_apply(full), means)
    if len(means) > 9:
        lsq, _ = ref.fit_acc(means, g, scale0, bias0)
        lsq_in = err(lsq.apply, means)
    else:  # fewer runs than parameters: no least-squares fit
        lsq_in = np.full(len(means), np.nan)
    tk_in = err(tk.apply, means) if tk is not None else np.full(len(means), np.nan)

    out_i, out_t = [], []
    ang_i, ang_t = [0.0], [0.0]
    centres = np.array([means[labels == k].mean(axis=0) for k in range(labels.max() + 1)])

    def pair_angles(cal_apply) -> np.ndarray:
        u = cal_apply(centres)
        u = u / np.linalg.norm(u, axis=1, keepdims=True)
        return np.degrees(np.arccos(np.clip(u @ u.T, -1.0, 1.0)))

    like_angles = pair_angles(lambda raw: like.accel.inverse(np.atleast_2d(raw)))
    cos = math.cos(math.radians(10.0))
    for k in range(labels.max() + 1):
        centre = ups[labels == k].mean(axis=0)
        centre /= np.linalg.norm(centre)
        sel = labels == k
        keep_iv = [iv for iv, u in zip(intervals, iv_ups, strict=True) if float(u @ centre) <= cos]
        if tk is None or len(keep_iv) < 3:
            continue
        n_tk = ref.INTERVAL_N
        keep_tk = np.repeat(tk_iv_ups @ centre <= cos, n_tk)
        if keep_tk.sum() // n_tk < 9:
            continue
        try:
            acc_k = _imudiag_accel(keep_iv, copy.deepcopy(like), rate)
        except ValueError:
            continue
        tk_k, _ = ref.fit_acc(tk_points[keep_tk], g, scale0, bias0)
        out_i.append(err(imudiag_apply(acc_k), means[sel]))
        out_t.append(err(tk_k.apply, means[sel]))
        ang_i.append(float(np.max(np.abs(pair_angles(imudiag_apply(acc_k)) - like_angles))))
        ang_t.append(float(np.max(np.abs(pair_angles(tk_k.apply) - like_angles))))

    def rms(x: list[np.ndarray] | np.ndarray) -> float:
        a = np.concatenate(x) if isinstance(x, list) else x
        return float(np.sqrt(np.mean(a**2))) if a.size else float("nan")

    return Scores(
        name=recording.split("/")[0],
        runs=len(runs),
        attitudes=int(labels.max() + 1),
        imudiag_out=rms(out_i),
        imu_tk_out=rms(out_t),
        folds=len(out_i),
        imudiag_in=rms(inside),
        lsq_in=rms(lsq_in),
        imu_tk_in=rms(tk_in),
        imu_tk_note=note,
        imudiag_fold_angle_deg=max(ang_i) if out_i else float("nan"),
        imu_tk_fold_angle_deg=max(ang_t) if out_t else float("nan"),
    )


def table() -> str:
    """The benchmark table (Markdown), mg = 1e-3 g of each recording's gravity."""
    lines = [
        "| recording | runs / attitudes | out of sample: imudiag | imu_tk reference | "
        "attitudes scored | in sample: imudiag | independent LSQ | imu_tk ref | "
        "folds' largest change of an angle between attitudes: imudiag / imu_tk ref | note |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for rec, like, init in RECORDINGS:
        s = score_recording(rec, like, init)
        g = load(DATA / "diagnosis" / like).gravity
        mg = 1000.0 / g
        lines.append(
            f"| {s.name} | {s.runs} / {s.attitudes} | {s.imudiag_out * mg:.3f} mg | "
            f"{s.imu_tk_out * mg:.3f} mg | {s.folds} | {s.imudiag_in * mg:.3f} mg | "
            f"{s.lsq_in * mg:.3f} mg | {s.imu_tk_in * mg:.3f} mg | "
            f"{s.imudiag_fold_angle_deg:.2f} / {s.imu_tk_fold_angle_deg:.2f} deg | "
            f"{s.imu_tk_note} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    print(table())
