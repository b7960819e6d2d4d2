"""Fault onsets inside a moving-base window: a step in one parameter, and what is fitted.

A window of epochs that holds the moment a fault started mixes two units: the
epochs before the onset read the certificate, those after read the fault. The
single fit of the window (and the isolation, :mod:`.isolation`) then explains
the mixture, and on a car more than the faulted parameter moves: on the bench's
highway drive with a mid-drive az bias the windows straddling the onset also
fitted "ax bias or ax/az misalignment", and two such windows in a row made it
a fault by persistence (docs/moving-base.md). This is the moving-base
counterpart of the static windows' change-point test
(:mod:`imudiag.diagnosis.changepoint`): there a few precise intervals and the
median prediction error of the later ones; here many noisy epochs, so the
evidence of all epochs after a candidate onset is summed.

The test, on the whitened residuals at the certificate linearised as in the
isolation (r_w + J_w delta): the window's common fit (all 9 parameters, prior
at the certificate, ``prior_factor`` limits) against the same fit plus a step
of one parameter i from epoch k on. The chi^2 the step removes is

    D(k, i) = (z^T M r_w)^2 / (z^T M z),  z = J_w[:, i] * [t >= t_k],
    M = I - J_w (J_w^T J_w + P)^-1 J_w^T

(the common fit profiled out), evaluated for every k with at least
``min_side`` epochs on each side and every i, divided by the scatter left
beyond the noise model (chi^2/dof after the best step, at least 1). The window
holds an onset when the largest exceeds :data:`ONSET_CHI2`. A fault that was
already there before the window is absorbed by the common fit (a constant
shift), so only changes inside the window count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..certificate import TriadModel
from ..diagnosis.params import CAUSES, TriadForm, sensor_of
from .isolation import Isolation, isolate, linearised_at_certificate

#: chi^2 (inflated by the scatter beyond the noise model) that a step of one parameter at
#: one epoch must remove for a window to hold an onset. Under no change each D(k, i) is a
#: chi^2 with 1 dof; the largest of ~9 x 160 correlated ones was 17.0 at most over 334
#: windows of clean simulated drives (docs/moving-base.md, "Fault onsets inside a window").
ONSET_CHI2 = 25.0
#: epochs each side of a candidate onset (s at 1 s epochs)
ONSET_MIN_SIDE = 10


@dataclass
class Onset:
    """The onset test of one window: ``index`` is the first epoch after the change (None:
    no step beyond the threshold), ``parameter`` the one whose step explains it best."""

    index: int | None
    parameter: int
    chi2: float  #: the best step's chi^2 reduction, inflated (0 with too few epochs)
    t: float | None  #: time of the first epoch after the change, s (None: no step)
    triad: str = "accel"
    threshold: float = ONSET_CHI2  #: the chi^2 the test required

    def to_json(self) -> dict:
        return {
            "found": self.index is not None,
            "t": None if self.t is None else round(self.t, 3),
            "chi2": round(self.chi2, 2),
            "threshold": self.threshold,
            "step_of": f"{sensor_of(self.triad, self.parameter)} {CAUSES[self.parameter]}",
        }


def find_onset(
    triad: TriadModel | TriadForm,
    means: np.ndarray,
    mean_var: np.ndarray,
    magnitude: np.ndarray,
    t: np.ndarray,
    prior_factor: float = 10.0,
    min_side: int = ONSET_MIN_SIDE,
    threshold: float = ONSET_CHI2,
) -> Onset:
    """The onset test (module doc) over epochs in time order: means (K, 3), output units,
    their variances, magnitudes (K,), input units, and times ``t`` (K,), s."""
    jw, rw, lim, _ = linearised_at_certificate(triad, means, mean_var, magnitude)
    k = jw.shape[0]
    if k < 2 * min_side + 1:
        return Onset(None, 0, 0.0, None, triad.name, threshold)
    prior = np.diag(1.0 / (prior_factor * lim) ** 2)
    hat = jw @ np.linalg.solve(jw.T @ jw + prior, jw.T)
    m = np.eye(k) - hat
    mr = m @ rw
    chi_common = float(rw @ mr)
    best = (-1.0, 0, 0)
    cand = np.arange(min_side, k - min_side + 1)
    # for the step z = a (column i of jw) from epoch s on, every parameter at once:
    # z^T M r, and z^T M z = sum over j, l >= s of a_j M_jl a_l, as the sums from the last
    # epoch back of each epoch's terms with the later ones (M's upper and lower triangles
    # and its diagonal): O(K^2) per parameter instead of the K x K table of tail sums
    num = np.cumsum((jw * mr[:, None])[::-1], axis=0)[::-1]  # (K, 9)
    later = np.triu(m, 1) @ jw + np.tril(m, -1).T @ jw + np.diagonal(m)[:, None] * jw
    den = np.cumsum((jw * later)[::-1], axis=0)[::-1]  # (K, 9)
    for i in range(9):
        with np.errstate(divide="ignore", invalid="ignore"):
            drop = np.where(den[cand, i] > 1e-12, num[cand, i] ** 2 / den[cand, i], 0.0)
        j = int(np.argmax(drop))
        if drop[j] > best[0]:
            best = (float(drop[j]), i, int(cand[j]))
    drop_best, i_best, k_best = best
    dof = max(k - float(np.trace(hat)) - 1.0, 1.0)
    infl = max(1.0, (chi_common - drop_best) / dof)
    chi2 = drop_best / infl
    if chi2 <= threshold:
        return Onset(None, i_best, chi2, None, triad.name, threshold)
    return Onset(k_best, i_best, chi2, float(t[k_best]), triad.name, threshold)


@dataclass
class WindowIsolation:
    """A window's isolation after the onset test: ``iso`` over the epochs from ``first``
    on (all when no onset), or None and the reason when the window is withheld."""

    onset: Onset
    first: int  #: first epoch fitted
    iso: Isolation | None
    withheld: str  #: "" or why the window names nothing

    def to_json(self) -> dict:
        out = dict(self.onset.to_json(), epochs_fitted_from=self.first)
        if self.withheld:
            out["withheld"] = self.withheld
        return out


def isolate_window(
    triad: TriadModel | TriadForm,
    means: np.ndarray,
    mean_var: np.ndarray,
    magnitude: np.ndarray,
    t: np.ndarray,
    min_after: int,
    k_sigma: float = 4.0,
    prior_factor: float = 10.0,
) -> WindowIsolation:
    """The isolation of one window (epochs in time order, times ``t`` in s): when the onset
    test finds a change, only the epochs after it are isolated, and with fewer than
    ``min_after`` of them the window is withheld (it names nothing and must not count
    for or against persistence)."""
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    on = find_onset(triad, means, mean_var, magnitude, t, prior_factor=prior_factor)
    if on.index is None:
        return WindowIsolation(on, 0, isolate(triad, means, mean_var, magnitude, k_sigma), "")
    after = means.shape[0] - on.index
    if after < min_after:
        why = (
            f"the window holds a change at t = {on.t:.1f} s (a step explains chi^2 "
            f"{on.chi2:.0f}), and only {after} epochs follow it (fewer than {min_after}): "
            "a window mixing the unit before and after a fault onset can name a wrong "
            "parameter, so it names nothing"
        )
        return WindowIsolation(on, on.index, None, why)
    sl = slice(on.index, None)
    iso = isolate(triad, means[sl], np.asarray(mean_var)[sl], np.asarray(magnitude)[sl], k_sigma)
    return WindowIsolation(on, on.index, iso, "")


__all__ = [
    "ONSET_CHI2",
    "ONSET_MIN_SIDE",
    "Onset",
    "WindowIsolation",
    "find_onset",
    "isolate_window",
]
