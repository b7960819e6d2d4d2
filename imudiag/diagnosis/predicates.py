"""Predicates F1..F9 per triad (the paper's eqs. 13 and 27), made statistical.

Parameter i of a triad is a *candidate* in a window when its deviation from
the certificate exceeds both the limit lambda_i and ``k_sigma`` standard
deviations of the deviation: the estimate's std and the certificate's own (its
stated ``uncertainty``, a calibration's) combined, sqrt(std^2 + cert_std^2), so
a certificate that is itself uncertain is not taken as exact. Where that std
holds a scatter the fit measured on its own residuals (few points, an excess
variance or a Birge ratio), ``k_sigma`` is the Student-t quantile of the same
two-sided tail at the std's effective degrees of freedom
(:attr:`~.params.TriadFit.deviation_dof`): 4 sigma of a normal is 5.5 at 15
degrees of freedom and 17 at 4, where a std measured on 4 residuals is itself
uncertain by a third. It becomes a
*fault* when it stays a candidate (with the same sign) in ``persist``
consecutive windows that estimated it, and stays active until it has not been
a candidate for ``persist`` consecutive windows. Undetermined windows neither
confirm nor clear a fault.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..stats import t_equivalent
from .params import CAUSES, TriadFit, sensor_of


def critical_sigma(fit: TriadFit, k_sigma: float, only: np.ndarray | None = None) -> np.ndarray:
    """(9,) how many of its std a deviation must exceed: ``k_sigma`` where the std is
    known, its Student-t equivalent at :attr:`~.params.TriadFit.deviation_dof` where the fit
    estimated part of it (module doc). ``only`` (9,) bool: the parameters to work it out
    for (the others keep ``k_sigma``, a bound below it)."""
    nu = fit.deviation_dof
    out = np.full(9, float(k_sigma))
    for i in np.flatnonzero(np.isfinite(nu) & (True if only is None else only)):
        out[i] = t_equivalent(k_sigma, float(nu[i]))
    return out


def _beyond(dev: np.ndarray, fit: TriadFit, k_sigma: float) -> np.ndarray:
    dstd = fit.deviation_std
    with np.errstate(invalid="ignore"):
        out = (np.abs(dev) > fit.limit) & (np.abs(dev) > k_sigma * dstd)
        # the Student-t threshold (never below k_sigma) only where the normal one passed
        need = out if out.ndim == 1 else out.any(axis=0)
        if need.any():
            out &= np.abs(dev) > critical_sigma(fit, k_sigma, need) * dstd
    return out


def _eligible(fit: TriadFit, k_sigma: float) -> np.ndarray:
    """(9,) bool: beyond the limit and k_sigma std, judged and well determined."""
    dev = fit.deviation
    return _beyond(dev, fit, k_sigma) & np.isfinite(fit.std) & fit.judged & fit.determined


@dataclass(frozen=True)
class Judgement:
    """What :func:`candidates` and :func:`held_back` both work out of one fit at one
    ``k_sigma`` (:func:`judge`), made once for a window's fit as the window left it
    (:func:`imudiag.diagnosis.window.diagnose_window`) and passed to both."""

    k_sigma: float
    eligible: np.ndarray  #: (9,) bool, :func:`_eligible`
    #: (G, 9) bool, :func:`_stable_rows`; None where the fit has no point left out
    rows: np.ndarray | None


def judge(fit: TriadFit, k_sigma: float) -> Judgement:
    """The fit's :class:`Judgement` at ``k_sigma``."""
    loo = fit.loo_deviation
    has_rows = loo is not None and loo.shape[0] > 0
    rows = _stable_rows(fit, k_sigma) if has_rows else None
    return Judgement(float(k_sigma), _eligible(fit, k_sigma), rows)


def _judged(fit: TriadFit, k_sigma: float, judgement: Judgement | None) -> Judgement:
    """``judgement`` where it is of ``k_sigma``, else the fit judged now."""
    if judgement is not None and judgement.k_sigma == float(k_sigma):
        return judgement
    return judge(fit, k_sigma)


def candidates(fit: TriadFit, k_sigma: float, judgement: Judgement | None = None) -> np.ndarray:
    """Signs (9,) of the parameters beyond their limit and k_sigma std (0 where not).

    A candidate must be well determined (``fit.determined``: its std at most the
    configured fraction of its limit), judged (the fit had redundancy), and
    stable: still beyond, with the same sign, with any single point of the fit
    left out (``fit.loo_deviation``, :mod:`.robust`), so one interval or motion
    cannot make a fault. ``judgement``: the fit's, made once (:func:`judge`).
    """
    j = _judged(fit, k_sigma, judgement)
    beyond = j.eligible if j.rows is None else j.eligible & np.all(j.rows, axis=0)
    return np.where(beyond, np.sign(fit.deviation), 0.0)


def _stable_rows(fit: TriadFit, k_sigma: float) -> np.ndarray:
    """(G, 9) bool: with point g left out, parameter i is still beyond, with its sign.

    A point the parameter cannot be seen without (NaN: an essential point, such as
    the only hold with an axis down) cannot be contradicted by the others: it
    counts as stable."""
    loo = fit.loo_deviation
    assert loo is not None
    sign = np.sign(fit.deviation)
    with np.errstate(invalid="ignore"):
        ok = _beyond(loo, fit, k_sigma) & (np.sign(loo) == sign[None, :])
    return ok | ~np.isfinite(loo)


def stable(fit: TriadFit, k_sigma: float) -> np.ndarray:
    """(9,) bool: no single point of the fit, left out, brings the parameter back within
    its limit or k_sigma std, or flips its sign (True where the fit gives no such figure)."""
    if fit.loo_deviation is None or fit.loo_deviation.shape[0] == 0:
        return np.ones(9, dtype=bool)
    return np.all(_stable_rows(fit, k_sigma), axis=0)


def held_back(
    fit: TriadFit, k_sigma: float, labels: list[str], judgement: Judgement | None = None
) -> list[dict]:
    """Parameters that would be fault candidates but for one point (the first such point):
    ``sensor``, ``cause``, ``estimate``, the estimate without that ``point`` and the
    reason. ``judgement``: the fit's, made once (:func:`judge`)."""
    loo = fit.loo_deviation
    if loo is None or loo.shape[0] == 0:
        return []
    j = _judged(fit, k_sigma, judgement)
    would, rows = j.eligible, j.rows
    assert rows is not None
    out = []
    for i in np.flatnonzero(would & ~np.all(rows, axis=0)):
        g = int(np.flatnonzero(~rows[:, i])[0])
        out.append(
            {
                "sensor": sensor_of(fit.triad, int(i)),
                "cause": CAUSES[int(i)],
                "estimate": float(fit.estimate[i]),
                "without_point": float(fit.certificate[i] + loo[g, i]),
                "point": labels[g] if g < len(labels) else f"point {g}",
                "reason": "not a fault candidate: one point makes it (left out, the "
                "estimate is within its limit or its noise, or changes sign)",
            }
        )
    return out


@dataclass
class _State:
    streak: int = 0
    sign: float = 0.0
    t_first: float | None = None
    clear_streak: int = 0
    active: bool = False
    raised: bool = False
    fault: dict | None = None


class PredicateTracker:
    """Persistence of the predicates of both triads across windows."""

    def __init__(self, k_sigma: float = 4.0, persist: int = 2) -> None:
        self.k_sigma = float(k_sigma)
        self.persist = int(persist)
        self._state: dict[tuple[str, int], _State] = {}
        self.raised: list[dict] = []  #: every fault raised, in order (latched)
        #: faults withdrawn by :meth:`restart`, each with its ``reason``
        self.withdrawn: list[dict] = []

    def update(self, fit: TriadFit, t: float, judgement: Judgement | None = None) -> list[dict]:
        """Judge one window's fit at time ``t`` (s); returns this window's candidates.
        ``judgement``: the fit's, made once (:func:`judge`)."""
        sign_arr = candidates(fit, self.k_sigma, judgement)
        # informative: judged, a finite std, and determined or a candidate (all 9 at once)
        informative_all = (
            np.asarray(fit.judged, dtype=bool)
            & np.isfinite(fit.std)
            & (np.asarray(fit.determined, dtype=bool) | (sign_arr != 0))
        ).tolist()
        signs = sign_arr.tolist()
        out = []
        for i in range(9):
            st = self._state.setdefault((fit.triad, i), _State())
            informative = informative_all[i]
            if signs[i] != 0:
                entry = self._entry(fit, i, t)
                out.append(entry)
                if st.streak and st.sign == signs[i]:
                    st.streak += 1
                else:
                    st.streak, st.sign, st.t_first = 1, float(signs[i]), t
                st.clear_streak = 0
                if st.streak >= self.persist:
                    if not st.active:
                        st.active = True
                        # t_in_force: the window (its end, s) that completed the persistence
                        st.fault = dict(entry, t_first=st.t_first, t_last=t, t_in_force=t)
                        self.raised.append(st.fault)
                    elif st.fault is not None:
                        st.fault.update(estimate=entry["estimate"], std=entry["std"], t_last=t)
            elif informative:
                st.streak = 0
                if st.active:
                    st.clear_streak += 1
                    if st.clear_streak >= self.persist:
                        st.active = False
                        st.clear_streak = 0
        return out

    def restart(self, triad: str, t_step: float) -> list[dict]:
        """A step change of ``triad`` at ``t_step`` (s, the start of the first interval of
        the unit as it is now) found after the fact: every window since held intervals
        from both sides of it, a mixture no parameter set describes. The faults of the
        triad those windows raised (first candidate at or after ``t_step``) are withdrawn
        with the reason, and the streaks they began forgotten; the windows after the step
        raise again what is really there. Faults raised before the step stay. Returns the
        withdrawn faults."""
        reason = (
            f"raised by windows mixing intervals from before and after a step change at "
            f"t = {t_step:.2f} s"
        )
        mixed = [f["triad"] == triad and f["t_first"] >= t_step for f in self.raised]
        out = [
            dict(_public(f), reason=reason) for f, m in zip(self.raised, mixed, strict=True) if m
        ]
        self.raised = [f for f, m in zip(self.raised, mixed, strict=True) if not m]
        for (tri, _), st in self._state.items():
            if tri != triad:
                continue
            if st.fault is not None and st.fault["t_first"] >= t_step:
                st.active, st.fault, st.clear_streak = False, None, 0
            if st.t_first is not None and st.t_first >= t_step:
                st.streak, st.sign, st.t_first = 0, 0.0, None
        self.withdrawn.extend(out)
        return out

    @staticmethod
    def _entry(fit: TriadFit, i: int, t: float) -> dict:
        return {
            "triad": fit.triad,
            "sensor": sensor_of(fit.triad, i),
            "cause": CAUSES[i],
            "estimate": float(fit.estimate[i]),
            "certificate": float(fit.certificate[i]),
            "limit": float(fit.limit[i]),
            "std": float(fit.std[i]) if np.isfinite(fit.std[i]) else None,
            "t": float(t),
            # the certificate's own std, when it states one (a calibration's)
            **(
                {"certificate_std": float(fit.certificate_std[i])} if fit.certificate_std[i] else {}
            ),
            # a gyro bias taken after a step of its rest rate in the window
            **_step_of(fit, i),
        }

    def active(self) -> list[dict]:
        """Faults active now (reports.md ``faults`` entries plus ``std``, ``t_last`` and
        ``t_in_force``: the sample time, s, of the window that completed the persistence)."""
        return [
            dict(_public(st.fault), t_in_force=st.fault["t_in_force"])
            for st in self._state.values()
            if st.active and st.fault is not None
        ]

    def all_raised(self) -> list[dict]:
        """Every fault raised so far, latched, in the order raised."""
        return [_public(f) for f in self.raised]


def _step_of(fit: TriadFit, i: int) -> dict:
    """``{"step": ...}`` when the window took bias ``i`` after a step of its rest rate (the
    window's ``rest_step`` entry for that sensor: ``t_after`` s, ``before``, ``after``
    output units, ``sigma``), else empty."""
    if i >= 3:
        return {}
    sensor = sensor_of(fit.triad, i)
    for step in fit.extra.get("rest_step", ()):
        if step["sensor"] == sensor:
            return {"step": {k: v for k, v in step.items() if k != "sensor"}}
    return {}


def _public(f: dict) -> dict:
    keys = (
        "triad",
        "sensor",
        "cause",
        "estimate",
        "certificate",
        "limit",
        "t_first",
        "t_last",
        "std",
        "certificate_std",
        "step",
    )
    return {k: f[k] for k in keys if k in f}


__all__ = ["Judgement", "PredicateTracker", "candidates", "held_back", "judge", "stable"]
