"""Single-fault isolation on a moving base: which one parameter explains the misfit.

On a land vehicle the specific force stays within about 20 deg of the body
vertical, so several parameters leave the same trace in |f|: with f_z close
to -g, a bias of az and a scale-factor error of az shift |f| alike, and a
bias of ax looks like the ax/az misalignment (x reads f_x + delta f_z). The
full 9-parameter fit then leaves each of them undetermined, rightly. What the
drive *can* tell is which single parameter, moved from the certificate,
explains the epochs' residuals, and whether another one explains them as
well. For every parameter i alone (the others at the certificate), linearised
at the certificate with the weights of the means:

    delta_i = -(J_i^T W r) / (J_i^T W J_i),  std_i = (J_i^T W J_i)^-1/2,
    chi^2 reduction  D_i = (J_i^T W r)^2 / (J_i^T W J_i)

(r: normalised residuals |x| - mu at the certificate, J: their Jacobian).
The scatter left after the best single parameter, beyond the noise model,
inflates the standard deviations (chi^2 / dof). A fault needs the best
parameter beyond its limit and ``k_sigma`` std; it is *named* when no other
parameter explains the data within ``margin`` of chi^2, and reported as one of
a group otherwise, but only when every member of the group would be beyond its
limit (if an in-limit value of another parameter explains the data as well,
nothing can be said).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..certificate import TriadModel
from ..diagnosis.params import CAUSES, TriadForm, sensor_of, triad_form
from ..diagnosis.scalar_fit import (
    RESIDUAL_FLOOR,
    certificate_internal,
    residuals_and_jacobian,
)


@dataclass
class Finding:
    """One parameter group explaining part of the misfit (certificate units)."""

    best: int
    group: list[int]  #: parameters explaining it as well as the best
    deviation: np.ndarray  #: (9,) estimate - certificate of each candidate, given earlier findings
    std: np.ndarray  #: (9,)
    chi2_drop: np.ndarray  #: (9,) chi^2 reduction of each candidate, given earlier findings
    fault: bool  #: best beyond limit and k std, and every group member beyond its limit


@dataclass
class Isolation:
    """One window's fault isolation of a triad: findings in order of importance."""

    triad: str
    findings: list[Finding]
    limit: np.ndarray  #: (9,)
    certificate: np.ndarray  #: (9,)
    alone_std: np.ndarray  #: (9,) std of each parameter fitted alone
    correlation: np.ndarray  #: (9, 9) weighted correlation of the parameters' traces
    points: int

    @property
    def faults(self) -> list[Finding]:
        return [f for f in self.findings if f.fault]

    def entry(self, f: Finding, i: int) -> dict:
        return {
            "sensor": sensor_of(self.triad, i),
            "cause": CAUSES[i],
            "estimate": float(self.certificate[i] + f.deviation[i]),
            "std": float(f.std[i]),
        }

    def confused_with(self, i: int, threshold: float = 0.95) -> list[str]:
        """Parameters whose trace correlates with i's above ``threshold`` on these epochs."""
        return [
            f"{sensor_of(self.triad, j)} {CAUSES[j]}"
            for j in range(9)
            if j != i and abs(self.correlation[i, j]) > threshold
        ]


def _wls(jw: np.ndarray, rw: np.ndarray, cols: list[int]) -> tuple[np.ndarray, np.ndarray, float]:
    """Weighted LS of -r on columns ``cols``: (estimate, covariance, chi^2 left)."""
    a = jw[:, cols]
    info = a.T @ a
    cov = np.linalg.pinv(info)
    x = -cov @ (a.T @ rw)
    res = rw + a @ x
    return x, cov, float(res @ res)


def linearised_at_certificate(
    triad: TriadModel | TriadForm, means: np.ndarray, mean_var: np.ndarray, magnitude: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The epochs' weighted residual problem at the certificate: (J_w (K, 9), r_w (K,),
    limits (9,) and the factors to certificate units (9,)), both internal (dimensionless:
    the means, output units, and magnitudes, input units, are normalised by the median
    magnitude). r_w + J_w delta is the whitened residual after moving the parameters by
    delta (internal units) from the certificate, to first order."""
    triad = triad_form(triad)
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    mag = np.asarray(magnitude, dtype=float)
    m0 = float(np.median(mag))
    s = triad.scale_factor
    v = means / (s * m0)
    var_v = np.asarray(mean_var, dtype=float).reshape(-1, 3) / (s * m0) ** 2
    mu = mag / m0
    theta_c, _ = certificate_internal(triad, m0)
    r, jac, w = residuals_and_jacobian(theta_c, v, mu)
    sig2 = np.einsum("kj,kj->k", w * w, var_v) + RESIDUAL_FLOOR**2
    sw = 1.0 / np.sqrt(sig2)
    return jac * sw[:, None], r * sw, triad.internal_limits(m0), triad.scale(m0)


def isolate(
    triad: TriadModel | TriadForm,
    means: np.ndarray,
    mean_var: np.ndarray,
    magnitude: np.ndarray,
    k_sigma: float = 4.0,
    margin: float = 9.0,
    max_findings: int = 3,
) -> Isolation:
    """Fault isolation over epoch means (output units) with magnitudes (input units).

    Forward selection on the linearised model at the certificate: the parameter
    that alone removes most of the chi^2, then, given it, the next, while the
    next one removes more than ``k_sigma``^2 (module doc for groups and faults).
    """
    triad = triad_form(triad)
    jw, rw, lim, scale = linearised_at_certificate(triad, means, mean_var, magnitude)
    k = jw.shape[0]
    norms = np.maximum(np.linalg.norm(jw, axis=0), 1e-300)
    corr = (jw.T @ jw) / np.outer(norms, norms)
    chi_prev = float(rw @ rw)
    selected: list[int] = []
    explained: set[int] = set()  # members of earlier groups: not findings again
    findings: list[Finding] = []
    alone_std = np.full(9, np.inf)
    for _stage in range(max_findings):
        dev = np.zeros(9)
        var = np.full(9, np.inf)
        left = np.full(9, chi_prev)
        for i in range(9):
            if i in explained:
                continue
            x, cov, chi = _wls(jw, rw, selected + [i])
            dev[i], var[i], left[i] = x[-1], cov[-1, -1], chi
        drop = chi_prev - left
        if not selected:
            alone_std = np.sqrt(var)
        best = int(np.argmax(drop))
        # scatter beyond the noise model after this fit inflates the std (chi^2 / dof)
        dof = max(k - len(selected) - 1, 1)
        infl = max(1.0, left[best] / dof)
        std = np.sqrt(var * infl)
        drop_s = drop / infl
        if drop_s[best] < k_sigma**2:
            break
        group = [i for i in range(9) if i not in explained and drop_s[i] >= drop_s[best] - margin]
        cand = (np.abs(dev) > lim) & (np.abs(dev) > k_sigma * std)
        fault = bool(cand[best] and all(cand[i] for i in group))
        findings.append(Finding(best, group, dev * scale, std * scale, drop_s, fault))
        selected.append(best)
        explained.update(group)
        chi_prev = left[best]
    if not findings:
        # nothing significant: keep the single-parameter picture for the report
        dev = np.zeros(9)
        var = np.zeros(9)
        drop = np.zeros(9)
        for i in range(9):
            x, cov, chi = _wls(jw, rw, [i])
            dev[i], var[i], drop[i] = x[0], cov[0, 0], float(rw @ rw) - chi
        alone_std = np.sqrt(var)
    return Isolation(
        triad=triad.name,
        findings=findings,
        limit=lim * scale,
        certificate=triad.certificate.copy(),
        alone_std=alone_std * scale,
        correlation=corr,
        points=k,
    )


class IsolationTracker:
    """A fault is raised when findings whose groups overlap are faults in ``persist``
    consecutive windows; latched in :attr:`raised` (updated, not repeated)."""

    def __init__(self, persist: int = 2) -> None:
        self.persist = int(persist)
        self._streaks: list[tuple[set[int], int, float]] = []  # group, streak, t_first
        self.raised: list[dict] = []
        self._latched: list[tuple[set[int], dict]] = []

    def update(self, iso: Isolation, t: float) -> list[dict]:
        """Judge one window (time ``t``, s); returns its fault entries."""
        entries = []
        streaks = []
        for f in iso.faults:
            grp = set(f.group)
            prev = next((x for x in self._streaks if x[0] & grp), None)
            streak, t_first = (prev[1] + 1, prev[2]) if prev else (1, t)
            streaks.append((grp, streak, t_first))
            entry = self._entry(iso, f, t)
            entries.append(entry)
            if streak >= self.persist:
                old = next((d for g, d in self._latched if g & grp), None)
                if old is None:
                    old = dict(entry, t_first=t_first, t_last=t)
                    self._latched.append((grp, old))
                    self.raised.append(old)
                keep = old["t_first"]
                if (
                    old["named"]
                    and not entry["named"]
                    and (old["sensor"], old["cause"])
                    in [(o["sensor"], o["cause"]) for o in entry["one_of"]]
                ):
                    # a window that cannot separate the group does not undo a name
                    old["t_last"] = t
                else:
                    old.clear()
                    old.update(entry, t_first=keep, t_last=t)
        self._streaks = streaks
        return entries

    @staticmethod
    def _entry(iso: Isolation, f: Finding, t: float) -> dict:
        i = f.best
        named = len(f.group) == 1
        out: dict[str, Any] = {
            "triad": iso.triad,
            "sensor": sensor_of(iso.triad, i) if named else None,
            "cause": CAUSES[i] if named else None,
            "named": named,
            "estimate": float(iso.certificate[i] + f.deviation[i]) if named else None,
            "certificate": float(iso.certificate[i]) if named else None,
            "limit": float(iso.limit[i]) if named else None,
            "std": float(f.std[i]) if named else None,
            "t": float(t),
        }
        if not named:
            out["one_of"] = [iso.entry(f, j) for j in f.group]
            out["reason"] = (
                "these parameters leave the same trace in |f| on this drive: "
                "indistinguishable without other attitudes"
            )
        return out


__all__ = ["Finding", "Isolation", "IsolationTracker", "isolate", "linearised_at_certificate"]
