"""Figures of ``imudiag diagnose --plots DIR``.

- ``estimates_accel.png``, ``estimates_gyro.png``: one per triad, 9 panels (rows: the 3
  biases, the 3 scale-factor errors, the 3 misalignment differences; columns: x, y, z or
  the pairs). Each window's estimate at the window's end with its 1-sigma error bar
  (determined parameters; the others hollow grey, without bars), the certificate's value
  and its +/- limit band. Certificate units; misalignment in mrad.
- ``f0_trace.png``: every F0 check of each triad (|F0|, log scale) against the F0 limit over
  time, failures marked; for a MEMS gyro the rest-rate check (mean rate / threshold).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..certificate import MISALIGNMENT_PAIRS, SENSOR_NAMES, Certificate, TriadModel
from ..diagnosis.params import certificate_vector, limit_vector
from ..diagnosis.session import DiagnosisTrace
from . import TITLE_ROOM, pyplot, save, subplots

#: The files written, in order.
FILES = ("estimates_accel.png", "estimates_gyro.png", "f0_trace.png")

_ROWS = ("bias", "scale-factor error", "misalignment")


def _labels(triad: TriadModel) -> list[tuple[str, str, float]]:
    """(panel title, y label with unit, factor from certificate units) of the 9 parameters."""
    out_u, in_u = triad.output_unit, triad.input_unit
    sensors = SENSOR_NAMES[triad.name]
    pairs = MISALIGNMENT_PAIRS[triad.name]
    rows: list[tuple[str, str, float]] = []
    for s in sensors:
        rows.append((f"{s} bias", f"B [{out_u}]", 1.0))
    for s in sensors:
        rows.append((f"{s} scale-factor error", f"E [{out_u} per {in_u}]", 1.0))
    for k, pair in enumerate(pairs):
        rows.append((f"{pair} misalignment (d{k + 1})", "d [mrad]", 1e3))
    return rows


def _time(t: np.ndarray, t0: float) -> np.ndarray:
    return t - t0 if np.isfinite(t0) else t


#: :func:`~imudiag.plots.save`'s layout box of the estimates figure: its title on top, its
#: legend below the axes (figure fractions: left, bottom, right, top)
ESTIMATES_ROOM = (0.0, 0.04, 1.0, 0.97)


def _estimates_figure(trace: DiagnosisTrace, triad: TriadModel, cert_source: str) -> Any:
    plt = pyplot()
    fits = [w.fit(triad.name) for w in trace.windows]
    t = _time(np.array([w.t_end for w in trace.windows], dtype=float), trace.t0)
    est = np.array([f.estimate for f in fits]).reshape(-1, 9)
    std = np.array([f.std for f in fits]).reshape(-1, 9)
    det = np.array([f.determined for f in fits], dtype=bool).reshape(-1, 9)
    cert = certificate_vector(triad)
    lim = limit_vector(triad)
    fig, axes = subplots(3, 3, figsize=(13, 9.5), sharex=True)
    for i, (title, ylabel, k) in enumerate(_labels(triad)):
        ax = axes[i // 3, i % 3]
        c, lo, hi = cert[i] * k, (cert[i] - lim[i]) * k, (cert[i] + lim[i]) * k
        ax.axhspan(lo, hi, color="tab:green", alpha=0.12, lw=0)
        ax.axhline(lo, color="tab:green", ls="--", lw=0.8)
        ax.axhline(hi, color="tab:green", ls="--", lw=0.8)
        ax.axhline(c, color="k", lw=1.0)
        e, s, d = est[:, i] * k, std[:, i] * k, det[:, i]
        finite = np.isfinite(e)
        beyond = d & finite & (np.abs(e - c) > lim[i] * k)
        ok = d & finite & ~beyond
        span = [lo - 0.3 * (hi - lo) / 2, hi + 0.3 * (hi - lo) / 2]
        if np.any(d & finite):
            bars = np.where(np.isfinite(s), s, 0.0)
            ax.errorbar(t[ok], e[ok], yerr=bars[ok], fmt="o", ms=3.5, color="tab:blue",
                        ecolor="tab:blue", elinewidth=0.8, capsize=2)  # fmt: skip
            ax.errorbar(t[beyond], e[beyond], yerr=bars[beyond], fmt="o", ms=4.5, color="tab:red",
                        ecolor="tab:red", elinewidth=0.8, capsize=2)  # fmt: skip
            shown = d & finite & (bars <= 3 * lim[i] * k)
            span += [float(np.min(e[d & finite])), float(np.max(e[d & finite]))]
            if np.any(shown):
                span += [float(np.min((e - bars)[shown])), float(np.max((e + bars)[shown]))]
        y0, y1 = min(span), max(span)
        pad = 0.06 * (y1 - y0) or abs(c) * 0.01 or 1.0
        y0, y1 = y0 - pad, y1 + pad
        und = ~d & finite
        if np.any(und):
            # not determined: their value says little; drawn hollow and held inside the axes
            ax.plot(t[und], np.clip(e[und], y0, y1), "o", ms=3.5, mfc="none", color="0.55")
        ax.set_ylim(y0, y1)
        ax.set_title(title, fontsize=10)
        ax.set_ylabel(ylabel, fontsize=9)
        ax.tick_params(labelsize=8)
        ax.grid(True, alpha=0.3)
        if i >= 6:
            ax.set_xlabel("time since the log's first sample [s] (window end)", fontsize=9)
        ax.ticklabel_format(axis="y", style="sci", scilimits=(-3, 6), useOffset=False)
    handles = [
        plt.Line2D([], [], color="k", lw=1.0, label="certificate"),
        plt.Rectangle((0, 0), 1, 1, color="tab:green", alpha=0.25, label="certificate ± limit"),
        plt.Line2D(
            [],
            [],
            color="tab:blue",
            marker="o",
            ls="-",
            ms=4,
            label="window estimate ± 1 std (determined)",
        ),  # fmt: skip
        plt.Line2D(
            [], [], color="tab:red", marker="o", ls="-", ms=4, label="estimate beyond the limit"
        ),  # fmt: skip
        plt.Line2D(
            [],
            [],
            color="0.55",
            marker="o",
            mfc="none",
            ls="",
            ms=4,
            label="not determined by the window (clipped to the axes)",
        ),  # fmt: skip
    ]
    fig.legend(handles=handles, loc="lower center", ncol=5, fontsize=8, frameon=False)
    n = len(trace.windows)
    fig.suptitle(
        f"{triad.name}: {n} window estimate{'s' if n != 1 else ''} against the certificate "
        f"({cert_source})" + ("" if n else ": no window could be diagnosed"),
        fontsize=12,
    )
    return fig


def _f0_figure(trace: DiagnosisTrace) -> Any:
    fig, axes = subplots(2, 1, figsize=(13, 7.5), sharex=True)
    for ax, name in zip(axes, ("accel", "gyro"), strict=True):
        tr = trace.f0.get(name)
        if tr is None:
            ax.text(0.5, 0.5, "not checked", ha="center", va="center", transform=ax.transAxes)
            continue
        tp, vp = tr.passed.arrays()
        tf, vf = tr.failed.arrays()
        floor = tr.limit * 1e-4  # |F0| drawn no lower (log axis)
        if tr.check == "rest_rate":
            what = "rest-rate check: worst axis' mean rate / its threshold"
            ylabel = "mean rate / threshold [dimensionless]"
        else:
            magnitude = "g" if name == "accel" else "Earth rate"
            what = f"F0 = (|u|²/{magnitude}² - 1)/2 per check"
            ylabel = "|F0| [dimensionless]"
        thin = max(tr.passed.stride, tr.failed.stride)
        if tr.check == "f0":
            ax.set_yscale("log")  # F0 of a good unit is orders of magnitude below its limit
            vp, vf = np.maximum(np.abs(vp), floor), np.maximum(np.abs(vf), floor)
        if tp.size + tf.size == 0:
            # no point: the limit line alone spans no height, and matplotlib warns of
            # identical low and high y limits when it scales to it: a range around it, set
            # before anything is drawn (which would ask for that scaling)
            ax.set_ylim(*((floor, 10 * tr.limit) if tr.check == "f0" else (0, 2 * tr.limit)))
        ax.plot(_time(tp, trace.t0), vp, ".", ms=2, color="tab:blue",
                label=f"passed ({tr.passed.seen} checks)")  # fmt: skip
        if tf.size:
            ax.plot(_time(tf, trace.t0), vf, "x", ms=5, color="tab:red",
                    label=f"failed ({tr.failed.seen} checks)")  # fmt: skip
        ax.axhline(tr.limit, color="tab:red", ls="--", lw=1.2, label=f"limit {tr.limit:g}")
        if tr.checks == 0:
            ax.text(0.5, 0.35, "no check applied (the unit was never still long enough)",
                    ha="center", va="center", transform=ax.transAxes)  # fmt: skip
        title = f"{name}: {what}"
        if thin > 1:
            title += f" (every {thin}th check drawn)"
        ax.set_title(title, fontsize=10)
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.005, 1.0))
    axes[-1].set_xlabel("time since the log's first sample [s]")
    fig.suptitle("Per-check F0 against the certificate's F0 limit (quasi-static samples only)")
    return fig


def write_diagnosis_plots(
    trace: DiagnosisTrace, cert: Certificate, directory: str | Path
) -> list[Path]:
    """Write :data:`FILES` into ``directory`` (created); returns the paths written."""
    source = cert.source or "bundled certificate"
    written = [
        save(
            _estimates_figure(trace, cert.triad(name), Path(source).name),
            directory,
            file,
            rect=ESTIMATES_ROOM,
        )
        for name, file in (("accel", FILES[0]), ("gyro", FILES[1]))
    ]
    written.append(save(_f0_figure(trace), directory, FILES[2], rect=TITLE_ROOM))
    return written


__all__ = ["FILES", "write_diagnosis_plots"]
