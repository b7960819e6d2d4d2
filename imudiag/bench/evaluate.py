"""Judge the daemon's status lines against what the bench injected.

Per injection:

- sensor faults: the first status line whose ``faults`` hold an expected
  entry (triad, sensor, cause); detected at the entry's ``t_first`` (the sample
  time the daemon put the fault in force: every check says it) when that is after
  the line before, else (a fault in force before under another sensor, as the
  rest-rate check's worst axis, or an entry without one) at the line's ``t``:
  so a daemon that reads a late burst of frames at once does not look slow; latency = that
  minus the injection time, both sample time (s); a matching entry before the
  injection is *premature*; unexplained entries on the same triad within the
  bound are *wrong* attributions (first seen at their own sample time, the same
  way);
- counter faults (garbage, crc, lost, duplicate): the counters' increment
  between the last status before the injection and the last status before
  the next one must equal what was injected, key by key; latency = sample
  time until a status shows the full increment;
- unplug and stall: state ``no_data`` within a wall-clock bound of the
  outage's start (sample time stands still without samples, so this one is
  wall time), link ``reconnecting`` meanwhile for an unplug and ``connected``
  throughout a stall, and samples flowing again within a wall-clock bound of
  the replug (resume), with the counters continuing, not reset. The wall-clock
  figures are judged against ``within``/``recover_within`` unless the run is
  made with ``wall_bounds=False`` (the test suite's real-time tier: there the
  events decide and the wall figures are reported only, ``wall_over_bound``).

Over the whole run: fault entries no injected fault explains are false
alarms; the error counters never decrease and end exactly at the sum of the
injections; ``bytes`` and ``frames`` end at what the board sent (not
checkable after an unplug without drain: frames in flight are lost then);
``max_status_delay_wall_s`` is the longest wall time from a board write until
a status line showed its samples (a blocked sampling path shows there).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from .daemon_process import StatusRecord
from .feeder import InjectionRecord
from .scenario import ERROR_COUNTERS, BenchScenario, Expectation, Injection

BASELINE_GAP_S = 0.2  #: a counter baseline is a status at least this long before, s (sample)
PASS = "pass"


def _key(entry: dict[str, Any]) -> tuple[str, str, str]:
    return (entry.get("triad", ""), entry.get("sensor") or "", entry.get("cause", ""))


def _entry(key: tuple[str, str, str]) -> dict[str, Any]:
    d: dict[str, Any] = {"triad": key[0]}
    if key[1]:
        d["sensor"] = key[1]
    d["cause"] = key[2]
    return d


def fault_time(entry: dict[str, Any], line_t: float, prev_t: float | None) -> float:
    """Sample time (s) a status ``faults`` entry first seen on a line at ``line_t`` stands
    for: its own ``t_first`` (when the check put it in force) where the daemon gives one
    after ``prev_t``, the ``t`` of the line before (which did not show it); else the line's
    ``t`` (no ``t_first``, or one from before that line: the condition was in force under
    another identity, e.g. the rest-rate check's worst axis changed)."""
    t_first = entry.get("t_first")
    if isinstance(t_first, int | float) and (prev_t is None or t_first >= prev_t - 1e-9):
        return float(t_first)
    return line_t


def _r(x: float | None, nd: int = 3) -> float | None:
    return None if x is None else round(float(x), nd)


class Evaluation:
    """Evaluates one bench run; :meth:`report` gives the JSON-ready result."""

    def __init__(
        self,
        scenario: BenchScenario,
        records: Sequence[StatusRecord],
        injected: Sequence[InjectionRecord],
        diagnosis: bool,
        rate_hz: float,
        sent: dict[str, int],
        pace: Sequence[tuple[float, int]] = (),
        wall_bounds: bool = True,
    ) -> None:
        self.scenario = scenario
        self.records = list(records)
        self.timed = [r for r in self.records if r.status.get("t") is not None]
        self.injected = {rec.injection.number: rec for rec in injected}
        self.diagnosis = diagnosis
        self.dt = 1.0 / rate_hz
        self.sent = sent
        self.pace = list(pace)
        self.wall_bounds = wall_bounds

    # -- expectations -------------------------------------------------------

    def _active(self, inj: Injection) -> tuple[list[Expectation], list[Expectation]]:
        """(expectations checked in this run, expectations pending the diagnosis)."""
        active: list[Expectation] = []
        pending: list[Expectation] = []
        for e in inj.expect:
            (pending if e.requires == "diagnosis" and not self.diagnosis else active).append(e)
        return active, pending

    def _explained(self, key: tuple[str, str, str], t: float) -> bool:
        entry = _entry(key)
        for inj in self.scenario.sensor_injections:
            if inj.t_s <= t + 1e-9 and any(e.matches(entry) for e in (*inj.expect, *inj.also)):
                return True
        return False

    def false_alarms(self) -> list[dict[str, Any]]:
        """Fault entries no injected fault explains: first/last t and status lines."""
        seen: dict[tuple[str, str, str], dict[str, Any]] = {}
        prev_t: float | None = None
        for rec in self.timed:
            line_t = float(rec.status["t"])
            for entry in rec.status.get("faults", []):
                t = fault_time(entry, line_t, prev_t)
                key = _key(entry)
                if self._explained(key, t):
                    continue
                fa = seen.setdefault(key, {**_entry(key), "t_first": t, "t_last": t, "lines": 0})
                fa["t_last"] = line_t
                fa["lines"] += 1
            prev_t = line_t
        return [
            {**v, "t_first": _r(v["t_first"]), "t_last": _r(v["t_last"])} for v in seen.values()
        ]

    # -- per injection ------------------------------------------------------

    def sensor_result(self, inj: Injection, false_alarms: list[dict[str, Any]]) -> dict[str, Any]:
        active, pending = self._active(inj)
        out: dict[str, Any] = {
            **inj.as_dict(),
            "category": "sensor",
            "expected": [e.as_dict() for e in active],
            "pending": [e.as_dict() for e in pending],
        }
        if not active:
            out.update(result="pending", detected=None, latency_s=None)
            return out
        premature: float | None = None
        found: tuple[float, dict[str, Any], Expectation] | None = None
        prev_t: float | None = None
        for rec in self.timed:
            line_t = float(rec.status["t"])
            for entry in rec.status.get("faults", []):
                e = next((e for e in active if e.matches(entry)), None)
                if e is None:
                    continue
                t = fault_time(entry, line_t, prev_t)
                if t < inj.t_s - 1e-9:
                    premature = t if premature is None else premature
                elif found is None:
                    found = (t, entry, e)
            if found is not None:
                break
            prev_t = line_t
        bound = max(e.within_s for e in active)
        wrong = [
            fa
            for fa in false_alarms
            if fa["triad"] == inj.fault().triad and inj.t_s <= fa["t_first"] <= inj.t_s + bound
        ]
        out["premature_t"] = _r(premature)
        out["wrong"] = wrong
        if found is None:
            out.update(
                detected=False,
                latency_s=None,
                bound_s=bound,
                result="premature" if premature is not None else "missed",
            )
            return out
        t, entry, e = found
        latency = t - inj.t_s
        out.update(
            detected=True,
            t_detected=_r(t),
            latency_s=_r(latency),
            matched={k: entry[k] for k in ("triad", "sensor", "cause") if k in entry},
            bound_s=e.within_s,
        )
        if premature is not None:
            out["result"] = "premature"
        elif latency > e.within_s + 1e-9:
            out["result"] = "late"
        else:
            out["result"] = PASS
        return out

    def _counters_at(self, pred) -> dict[str, int] | None:
        chosen = None
        for rec in self.timed:
            if pred(float(rec.status["t"])):
                chosen = rec.status["counters"]
        return chosen

    def counter_result(self, inj: Injection, next_t: float | None) -> dict[str, Any]:
        rec = self.injected.get(inj.number)
        out: dict[str, Any] = {**inj.as_dict(), "category": "counters"}
        if rec is None:
            out.update(result="not_injected", detected=False, latency_s=None)
            return out
        expected = {k: rec.expected.get(k, 0) for k in ERROR_COUNTERS}
        checked = [k for k in ERROR_COUNTERS if expected[k] is not None]
        t0 = rec.t_s
        before = self._counters_at(lambda t: t <= t0 - BASELINE_GAP_S)
        limit = next_t - BASELINE_GAP_S if next_t is not None else float("inf")
        after = self._counters_at(lambda t: t <= limit)
        out["expected"] = {
            k: ("any" if v is None else v) for k, v in expected.items() if v is None or v
        }
        out["frames_affected"] = rec.frames_affected
        if before is None or after is None:
            out.update(result="no_baseline", detected=False, latency_s=None)
            return out
        observed = {k: after[k] - before[k] for k in ERROR_COUNTERS}
        out["observed"] = {k: v for k, v in observed.items() if v}
        target = {k: before[k] + n for k in checked if (n := expected[k])}
        t_det = None
        for r in self.timed:
            t = float(r.status["t"])
            if t > t0 - BASELINE_GAP_S and all(
                r.status["counters"][k] >= v for k, v in target.items()
            ):
                t_det = t
                break
        exact = all(observed[k] == expected[k] for k in checked)
        latency = None if t_det is None else max(0.0, t_det - t0)
        out.update(
            detected=t_det is not None,
            t_detected=_r(t_det),
            latency_s=_r(latency),
            bound_s=inj.within_s,
            exact=exact,
        )
        if not exact:
            out["result"] = "inexact" if t_det is not None else "missed"
        elif latency is None or latency > inj.within_s + 1e-9:
            out["result"] = "late"
        else:
            out["result"] = PASS
        return out

    def outage_result(self, inj: Injection) -> dict[str, Any]:
        rec = self.injected.get(inj.number)
        out: dict[str, Any] = {
            **inj.as_dict(),
            "category": "outage",
            "expected": {
                "state": "no_data",
                "within_wall_s": inj.within_s,
                "recover_within_wall_s": inj.recover_within_s,
            },
        }
        if rec is None or rec.wall_s is None:
            out.update(result="not_injected", detected=False, latency_s=None)
            return out
        pulled = rec.wall_s
        replug = rec.wall_replug_s
        before: dict[str, Any] | None = None
        no_data: StatusRecord | None = None
        reconnecting = False
        recovered: StatusRecord | None = None
        for r in self.records:
            s = r.status
            if r.wall_s < pulled:
                before = s
                continue
            if (
                replug is not None
                and r.wall_s >= replug
                and s.get("state") != "no_data"
                and s.get("t") is not None
                and rec.t_last_s is not None
                and s["t"] > rec.t_last_s + 1e-9
            ):
                recovered = r
                break
            if s.get("link") == "reconnecting":
                reconnecting = True
            if no_data is None and s.get("state") == "no_data":
                no_data = r
        if inj.kind == "unplug":
            out["drained"] = rec.drained
        out["link_reconnecting_seen"] = reconnecting
        out["latency_s"] = None  # sample time stands still without samples
        out["detected"] = no_data is not None
        if no_data is not None:
            out["wall_latency_s"] = _r(no_data.wall_s - pulled)
            out["t_detected"] = no_data.status.get("t")
        problems: list[str] = []
        over_bound: list[str] = []  # wall-clock bounds exceeded
        if no_data is None:
            problems.append(f"no no_data status during the {inj.kind}")
        elif no_data.wall_s - pulled > inj.within_s:
            over_bound.append("no_data late")
        if inj.kind == "unplug" and not reconnecting:
            problems.append("link never reported reconnecting")
        if inj.kind == "stall" and reconnecting:
            problems.append("link reported reconnecting while the port stayed open")
        if replug is not None:
            if recovered is None:
                problems.append("samples did not flow again after the replug")
            else:
                s = recovered.status
                out["recover_wall_s"] = _r(recovered.wall_s - replug)
                out["t_resumed"] = s.get("t")
                out["state_after"] = s.get("state")
                if recovered.wall_s - replug > inj.recover_within_s:
                    over_bound.append("recovery late")
                if before is not None:
                    cont = all(
                        s["counters"][k] >= before["counters"][k] for k in before["counters"]
                    )
                    grew = s["counters"]["frames"] > before["counters"]["frames"]
                    out["counters_continued"] = cont and grew
                    if not (cont and grew):
                        problems.append("counters reset or stopped across the replug")
        if self.wall_bounds:
            problems += over_bound
        else:
            out["wall_over_bound"] = over_bound
        out["problems"] = problems
        if not problems:
            out["result"] = PASS
        elif no_data is None:
            out["result"] = "missed"
        elif any("flow" in p or "recovery" in p for p in problems):
            out["result"] = "no_recovery"
        elif any("late" in p for p in problems):
            out["result"] = "late"
        else:
            out["result"] = "wrong"
        return out

    # -- GNSS aiding ----------------------------------------------------------

    def aiding_result(self) -> dict[str, Any] | None:
        """With ``aiding:``: the receiver simulated, when the status's ``aiding`` object
        first said ``in_use`` (sample time), on how many lines, its last state, and the
        problems (never in use, or later than ``in_use_within``); None without aiding."""
        spec = self.scenario.aiding
        if spec is None:
            return None
        lines = [r.status for r in self.timed if isinstance(r.status.get("aiding"), dict)]
        used = [s for s in lines if s["aiding"].get("in_use")]
        t_first = float(used[0]["t"]) if used else None
        problems: list[str] = []
        if not lines:
            problems.append("no status line has an aiding object")
        elif t_first is None:
            problems.append(f"aiding never in use: {lines[-1]['aiding'].get('reason')!r}")
        elif t_first > spec.in_use_within + 1e-9:
            problems.append(
                f"aiding in use only at t = {t_first:.1f} s (bound {spec.in_use_within:g} s)"
            )
        last = lines[-1]["aiding"] if lines else {}
        return {
            **spec.as_dict(),
            "source": last.get("source"),
            "t_first_in_use": _r(t_first),
            "lines_in_use": len(used),
            "lines": len(lines),
            "final": {
                k: last.get(k)
                for k in ("link", "in_use", "reason", "fixes", "mode", "f0", "windows", "latency_s")
            },
            "problems": problems,
        }

    # -- whole run ----------------------------------------------------------

    def counters_summary(self) -> dict[str, Any]:
        expected: dict[str, int | None] = dict.fromkeys(ERROR_COUNTERS, 0)
        for rec in self.injected.values():
            for k, v in rec.expected.items():
                old = expected[k]
                expected[k] = None if v is None or old is None else old + v
        expected["bytes"] = self.sent["bytes"]
        expected["frames"] = self.sent["frames"]
        final = self.records[-1].status["counters"] if self.records else {}
        monotonic = True
        prev: dict[str, int] | None = None
        for r in self.records:
            c = r.status["counters"]
            if prev is not None and any(c[k] < prev[k] for k in prev):
                monotonic = False
            prev = c
        observed = {k: final.get(k) for k in expected}
        checkable = all(r.drained for r in self.injected.values() if r.injection.kind == "unplug")
        exact = all(observed[k] == v for k, v in expected.items() if v is not None)
        return {
            "expected": {k: ("any" if v is None else v) for k, v in expected.items()},
            "observed": observed,
            "exact": exact if checkable else None,
            "monotonic": monotonic,
        }

    def max_delay_wall_s(self, pace: Sequence[tuple[float, int]]) -> float | None:
        """Longest wall time (s) from a board write until a status line shows its samples
        (``t`` within one status period of the write's last sample). A daemon whose
        sampling blocked shows here, not in the sample-time latencies."""
        if not pace or not self.timed:
            return None
        import numpy as np

        period = 1.0 / float(self.scenario.daemon.get("status", {}).get("rate_hz", 1.0))
        walls = np.array([p[0] for p in pace])
        sent_t = (np.array([p[1] for p in pace], dtype=float) - 1) * self.dt
        rec_wall = np.array([r.wall_s for r in self.timed])
        rec_t = np.array([float(r.status["t"]) for r in self.timed])
        # first record at or after each write whose t reaches the write's samples
        reached = np.maximum.accumulate(rec_t)
        j = np.searchsorted(reached, sent_t - period - 1e-9, side="left")
        ok = j < len(rec_t)
        if not ok.any():
            return None
        delay = np.maximum(rec_wall[j[ok]] - walls[ok], 0.0)
        return float(delay.max())

    def report(self) -> dict[str, Any]:
        """Per-injection results, false alarms, counter totals and the overall verdict."""
        false_alarms = self.false_alarms()
        transport_times = [i.t_s for i in self.scenario.transport_injections]
        results = []
        for inj in sorted(self.scenario.injections, key=lambda i: (i.t_s, i.number)):
            if inj.category == "sensor":
                results.append(self.sensor_result(inj, false_alarms))
            elif inj.category == "counters":
                later = [t for t in transport_times if t > inj.t_s]
                results.append(self.counter_result(inj, min(later) if later else None))
            else:
                results.append(self.outage_result(inj))
        counters = self.counters_summary()
        aiding = self.aiding_result()
        tally: dict[str, int] = {}
        for r in results:
            tally[r["result"]] = tally.get(r["result"], 0) + 1
        checked = [r for r in results if r["result"] != "pending"]
        passed = (
            all(r["result"] == PASS for r in checked)
            and not false_alarms
            and counters["exact"] is not False
            and counters["monotonic"]
            and not (aiding and aiding["problems"])
        )
        return {
            "faults": results,
            "false_alarms": false_alarms,
            "counters": counters,
            "max_status_delay_wall_s": _r(self.max_delay_wall_s(self.pace)),
            "summary": tally,
            **({} if aiding is None else {"aiding": aiding}),
            "passed": passed,
        }


__all__ = ["Evaluation"]
