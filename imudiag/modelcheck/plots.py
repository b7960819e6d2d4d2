"""Optional PNG figures of a model check (needs matplotlib; ``--plots DIR``).

- ``allan_<sensor>.png``: Allan deviation measured against the simulation of the
  certificate's model and of the extended model;
- ``residuals_<channel>.png``: chunk residuals against time and against the variable
  that explains a named effect (temperature, specific force), before and after;
- ``psd_<sensor>.png``: the spectrum with the named lines;
- ``noise_model_<sensor>.png``: the Allan deviation of the longest still stretch against
  the closed form of the chosen noise model and of the extended certificate, with their
  ratio (the 1.5x band shaded).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plots import available, save, subplots
from .check import ALL_SENSORS, ModelCheckResult

#: Resolution of the model check's PNG files, dots per inch (its figures are small)
DPI = 90


def write_plots(result: ModelCheckResult, directory: str | Path) -> list[Path]:
    """Write the figures into ``directory`` (created); returns the files written."""
    out_dir = Path(directory)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    meas = result.measured
    if meas is not None:
        tau, adev_m, ind = meas.allan("baseline")
        _t2, adev_e, _i2 = meas.allan("extended")
        sims = result.simulated
        for j, s in enumerate(ALL_SENSORS):
            fig, ax = subplots(figsize=(6, 4), dpi=DPI)
            ok = ind >= 4
            ax.loglog(tau[ok], adev_m[ok, j], "k.-", label="measured")
            if sims.get("baseline"):
                a = np.sqrt(
                    np.mean([x.allan("baseline")[1][:, j] ** 2 for x in sims["baseline"]], axis=0)
                )
                ax.loglog(tau[ok], a[ok], "b-", label="simulated: certificate model")
            if sims.get("extended") and any(e.sensor == s for e in result.effects):
                a = np.sqrt(
                    np.mean([x.allan("extended")[1][:, j] ** 2 for x in sims["extended"]], axis=0)
                )
                ax.loglog(tau[ok], adev_e[ok, j], "g.", label="measured, effects removed")
                ax.loglog(tau[ok], a[ok], "g-", label="simulated: extended model")
            ax.set_xlabel("tau [s]")
            ax.set_ylabel("Allan deviation [output units]")
            ax.set_title(f"{s}")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
            written.append(save(fig, out_dir, f"allan_{s}.png", dpi=DPI))
        for half in (0, 1):
            f, p, k = meas.psd("baseline", half)
            if k == 0:
                continue
            for j, s in enumerate(ALL_SENSORS):
                lines = [ln for ln in result.lines if ln.sensor == s]
                if half == 1 and not lines:
                    continue
                fig, ax = subplots(figsize=(6, 4), dpi=DPI)
                ax.semilogy(f[1:], p[1:, j], "k-", lw=0.7, label=f"measured, half {half + 1}")
                for ln in lines:
                    ax.axvline(
                        ln.frequency,
                        color="r",
                        alpha=0.5,
                        label=f"line {ln.frequency:.3g} Hz, A={ln.amplitude:.3g}",
                    )
                ax.set_xlabel("frequency [Hz]")
                ax.set_ylabel("PSD [output units^2/Hz]")
                ax.set_title(s)
                ax.legend(fontsize=7)
                written.append(save(fig, out_dir, f"psd_{s}_half{half + 1}.png", dpi=DPI))
    nm = result.report.get("noise_model") or {}
    for s, entry in (nm.get("sensors") or {}).items():
        if "allan" not in entry:  # untestable: the output did not vary
            continue
        allan = entry["allan"]
        tau = np.asarray(allan["tau"])
        if tau.shape[0] == 0:
            continue
        fig, (ax, ax2) = subplots(
            2, 1, figsize=(6, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]}, dpi=DPI
        )
        adev = np.asarray(allan["measured"])
        err = np.asarray(allan["relative_error"])
        ax.fill_between(tau, adev * (1 - err), adev * (1 + err), color="k", alpha=0.15)
        ax.loglog(tau, adev, "k.-", label="measured")
        ax.loglog(tau, allan["predicted"], "b-", label=f"model: {entry['model']}")
        if "extended_certificate" in allan:
            ax.loglog(tau, allan["extended_certificate"], "g--", label="extended certificate")
            ax2.semilogx(tau, allan["ratio_extended_certificate"], "g.-")
        ax2.semilogx(tau, allan["ratio"], "b.-")
        ax2.axhspan(1 / 1.5, 1.5, color="g", alpha=0.1)
        ax2.set_ylabel("measured / predicted")
        ax2.set_xlabel("tau [s]")
        ax.set_ylabel(f"Allan deviation [{entry['allan_unit']}]")
        ax.set_title(f"{s}: noise model, still stretch {nm['run_s']:.0f} s")
        ax.grid(True, which="both", alpha=0.3)
        ax2.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
        written.append(save(fig, out_dir, f"noise_model_{s}.png", dpi=DPI))
    c = result.session.chunks
    for res in result.channels:
        ch = res.channel
        fig, axes = subplots(1, 2, figsize=(10, 4), dpi=DPI)
        y = ch.y * ch.to_input
        after = y
        if res.selected:
            cols = [cc for s in res.selected for cc in s.cols]
            beta = np.concatenate([s.value for s in res.selected])
            after = (ch.y - res.design[:, cols] @ beta) * ch.to_input
        axes[0].plot(ch.t, y, "k.", ms=2, label="certificate model")
        if res.selected:
            axes[0].plot(ch.t, after, "g.", ms=2, label="after the named effects")
        axes[0].set_xlabel("t [s]")
        unit = ch.y_unit if ch.triad == "accel" or ch.label == "rotation" else ("input units")
        axes[0].set_ylabel(f"residual [{unit}]")
        axes[0].legend(fontsize=7)
        names = {s.candidate.name for s in res.selected}
        if ch.label == "rotation":
            x, xlabel = np.arange(len(ch)) // 2, "turn"
        elif result.session.has_temp and (
            not names or names & {"temperature_bias", "temperature_scale"}
        ):
            x, xlabel = c.temp, "temperature [degC]"
        elif "g_sensitivity" in names:
            g = next(s for s in res.selected if s.candidate.name == "g_sensitivity")
            k = int(np.argmax(np.abs(g.value)))
            g_columns = g.candidate.columns
            assert g_columns is not None  # a g-sensitivity candidate has regressor columns
            x, xlabel = g_columns[:, k], f"specific force {'xyz'[k]} [accel input]"
        else:
            x, xlabel = np.arange(len(ch)), "chunk"
        axes[1].plot(x, y, "k.", ms=2, label="certificate model")
        if res.selected:
            axes[1].plot(x, after, "g.", ms=2, label="after the named effects")
        axes[1].set_xlabel(xlabel)
        axes[1].set_title(ch.label)
        written.append(save(fig, out_dir, f"residuals_{ch.label}.png", dpi=DPI))
    return written


__all__ = ["available", "write_plots"]
