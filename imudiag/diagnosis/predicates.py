"""Predicates F1..F9 per triad (the paper's eqs. 13 and 27), made statistical.

Parameter i of a triad is a *candidate* in a window when its deviation from
the certificate exceeds both the limit lambda_i and ``k_sigma`` standard
deviations of the estimate; it becomes a *fault* when it stays a candidate
(with the same sign) in ``persist`` consecutive windows that estimated it, and
stays active until it has not been a candidate for ``persist`` consecutive
windows. Undetermined windows neither confirm nor clear a fault.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .params import CAUSES, TriadFit, sensor_of


def candidates(fit: TriadFit, k_sigma: float) -> np.ndarray:
    """Signs (9,) of the parameters beyond their limit and k_sigma std (0 where not)."""
    dev = fit.deviation
    beyond = (
        (np.abs(dev) > fit.limit)
        & (np.abs(dev) > k_sigma * fit.std)
        & np.isfinite(fit.std)
        & fit.judged
    )
    return np.where(beyond, np.sign(dev), 0.0)


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

    def update(self, fit: TriadFit, t: float) -> list[dict]:
        """Judge one window's fit at time ``t`` (s); returns this window's candidates."""
        signs = candidates(fit, self.k_sigma)
        out = []
        for i in range(9):
            st = self._state.setdefault((fit.triad, i), _State())
            informative = bool(
                fit.judged[i] and np.isfinite(fit.std[i]) and (fit.determined[i] or signs[i] != 0)
            )
            entry = self._entry(fit, i, t)
            if signs[i] != 0:
                out.append(entry)
                if st.streak and st.sign == signs[i]:
                    st.streak += 1
                else:
                    st.streak, st.sign, st.t_first = 1, float(signs[i]), t
                st.clear_streak = 0
                if st.streak >= self.persist:
                    if not st.active:
                        st.active = True
                        st.fault = dict(entry, t_first=st.t_first, t_last=t)
                        self.raised.append(st.fault)
                    elif st.fault is not None:
                        st.fault.update(
                            estimate=entry["estimate"], std=entry["std"], t_last=t
                        )
            elif informative:
                st.streak = 0
                if st.active:
                    st.clear_streak += 1
                    if st.clear_streak >= self.persist:
                        st.active = False
                        st.clear_streak = 0
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
        }

    def active(self) -> list[dict]:
        """Faults active now (reports.md ``faults`` entries plus ``std`` and ``t_last``)."""
        return [
            _public(st.fault)
            for st in self._state.values()
            if st.active and st.fault is not None
        ]

    def all_raised(self) -> list[dict]:
        """Every fault raised so far, latched, in the order raised."""
        return [_public(f) for f in self.raised]


def _public(f: dict) -> dict:
    keys = ("triad", "sensor", "cause", "estimate", "certificate", "limit", "t_first",
            "t_last", "std")
    return {k: f[k] for k in keys if k in f}


__all__ = ["PredicateTracker", "candidates"]
