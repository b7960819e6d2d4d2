"""Benchmarks and measured figures of the 18-parameter diagnosis.

    python -m benchmarks.diagnosis cost        # window cost per window / per sample at 1 kHz
    python -m benchmarks.diagnosis throughput  # `imudiag diagnose` on a 10^6-sample log
    python -m benchmarks.diagnosis variants    # isolation table: exact vs literal vs moving base
    python -m benchmarks.diagnosis all

``variants`` runs seeded simulated multi-position sessions (default MEMS
certificate and the navigation-grade one of tests/data/diagnosis) with one
injected fault at 3 to 6 times its limit, or none, through each method of
``imudiag.diagnosis`` and prints the isolation rates and estimate errors
that docs/diagnosis.md quotes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imudiag.certificate import Certificate, load, load_default
from imudiag.diagnosis import DiagnosisConfig, diagnose_samples
from imudiag.diagnosis.params import certificate_vector, limit_vector
from imudiag.diagnosis.window import diagnose_window
from imudiag.logs import open_writer
from imudiag.sim import Fault, multi_position, simulate

ROOT = Path(__file__).resolve().parent.parent
NAV_CERT = ROOT / "tests" / "data" / "diagnosis" / "nav-grade.yaml"
PARAM_INDEX = {"bias": 0, "scale_factor": 3, "misalignment": 6}
AXES = "xyz"
PAIRS = ("{t}x/{t}y", "{t}x/{t}z", "{t}y/{t}z")


@dataclass
class Case:
    """One simulated session: grade, fault (or None), session seed."""

    grade: str  #: mems | nav
    kind: str | None  #: bias | scale_factor | misalignment | None (clean)
    sensor: str | None
    factor: float  #: fault size in limits (signed)
    seed: int

    @property
    def triad(self) -> str | None:
        """Triad of the fault."""
        return None if self.sensor is None else ("gyro" if self.sensor[0] == "g" else "accel")

    @property
    def index(self) -> int | None:
        """Parameter index 0..8 of the fault."""
        if self.kind is None or self.sensor is None:
            return None
        if self.kind == "misalignment":
            return 6 + [p.format(t=self.sensor[0]) for p in PAIRS].index(self.sensor)
        return PARAM_INDEX[self.kind] + AXES.index(self.sensor[1])

    def label(self) -> str:
        """Short name."""
        if self.kind is None:
            return f"{self.grade}-clean-s{self.seed}"
        return f"{self.grade}-{self.kind}-{self.sensor}-{self.factor:+.1f}x-s{self.seed}"


def fault_catalogue(grade: str) -> list[tuple[str, str]]:
    """(kind, sensor) pairs the evidence covers for a grade."""
    out = []
    for t in ("a", "g"):
        for kind in ("bias", "scale_factor", "misalignment"):
            if t == "g" and kind == "misalignment" and grade == "mems":
                continue  # MEMS gyro misalignment: not part of the evidence list
            sensors = (
                [p.format(t=t) for p in PAIRS]
                if kind == "misalignment"
                else [f"{t}{a}" for a in AXES]
            )
            out.extend((kind, s) for s in sensors)
    return out


def make_cases(grade: str, n_faulty: int, n_clean: int, seed: int) -> list[Case]:
    """A seeded random subset of the fault catalogue (sign and size 3..6 limits) plus clean."""
    rng = np.random.default_rng(seed)
    cat = fault_catalogue(grade)
    pick = rng.permutation(len(cat))
    cases = []
    for k in range(n_faulty):
        kind, sensor = cat[pick[k % len(cat)]]
        factor = float(rng.uniform(3.0, 6.0)) * float(rng.choice([-1.0, 1.0]))
        cases.append(Case(grade, kind, sensor, factor, int(rng.integers(0, 10_000))))
    cases.extend(Case(grade, None, None, 0.0, int(rng.integers(0, 10_000))) for _ in range(n_clean))
    return cases


def certificate_for(grade: str) -> Certificate:
    """The certificate of a grade."""
    return load_default() if grade == "mems" else load(NAV_CERT)


def session(case: Case):  # noqa: ANN201 - SimResult
    """Simulate the case's session (MEMS: 16 attitudes 3 s, 200 Hz; nav: 20 attitudes 20 s,
    100 Hz)."""
    cert = certificate_for(case.grade)
    if case.grade == "mems":
        traj = multi_position(n_attitudes=16, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=case.seed)
    else:
        traj = multi_position(n_attitudes=20, dwell_s=20.0, turn_s=2.0, rate_hz=100, seed=case.seed)
    faults = []
    if case.kind is not None and case.index is not None and case.sensor is not None:
        limit = limit_vector(cert.triad(case.triad))[case.index]
        faults = [Fault(case.kind, case.sensor, 0.0, case.factor * limit)]
    return simulate(cert, traj, seed=case.seed + 1, faults=faults)


def judge(case: Case, diag) -> dict:  # noqa: ANN001
    """Per-triad outcome of one diagnosis run against the case's truth.

    For the triad with the fault: isolated (exactly that fault), found + extra,
    misattributed (other faults only) or missed; for a triad without a fault:
    clean or false alarm. ``error_limits``: |estimate - truth| of the faulted
    parameter in the last window, in limits.
    """
    v = diag.verdict()
    cert = diag.certificate
    out: dict = {}
    for triad in ("accel", "gyro"):
        raised = {(f["sensor"], f["cause"]) for f in v["faults"] if f["triad"] == triad}
        if case.triad != triad:
            out[triad] = {"faulty": False, "outcome": "clean" if not raised else "false alarm"}
            continue
        want = (case.sensor, case.kind)
        if raised == {want}:
            outcome = "isolated"
        elif want in raised:
            outcome = "found + extra"
        elif raised:
            outcome = "misattributed"
        else:
            outcome = "missed"
        res = {"faulty": True, "outcome": outcome}
        if diag.windows:
            tri = cert.triad(triad)
            i = case.index
            truth = certificate_vector(tri)[i] + case.factor * limit_vector(tri)[i]
            est = diag.windows[-1].fit(triad).estimate[i]
            res["error_limits"] = float(abs(est - truth) / limit_vector(tri)[i])
        out[triad] = res
    return out


METHODS = ("exact", "linear", "moving-base", "moving-base-self")


def run_method(case: Case, sim, method: str):  # noqa: ANN001, ANN201
    """Diagnose a simulated session with one of METHODS."""
    cert = certificate_for(case.grade)
    rate = sim.truth.rate_hz
    if method == "moving-base":
        mag = {
            "accel": np.linalg.norm(sim.truth.specific_force, axis=1),
            "gyro": np.linalg.norm(sim.truth.omega, axis=1),
        }
        return diagnose_samples(cert, sim.samples, {"method": "moving-base"}, rate, mag)
    if method == "moving-base-self":
        return diagnose_samples(cert, sim.samples, {"method": "moving-base"}, rate)
    return diagnose_samples(cert, sim.samples, {"method": method}, rate)


def variants(n_faulty: int, n_clean: int, seed: int, methods: tuple[str, ...]) -> dict:
    """Per-triad isolation table over seeded sessions for both grades."""
    table: dict = {}
    for grade in ("mems", "nav"):
        cases = make_cases(grade, n_faulty, n_clean, seed)
        for case in cases:
            sim = session(case)
            for m in methods:
                res = judge(case, run_method(case, sim, m))
                for triad, r in res.items():
                    row = table.setdefault(
                        (grade, m, triad), {"faulty": 0, "clean": 0, "outcomes": {}, "errors": []}
                    )
                    row["faulty" if r["faulty"] else "clean"] += 1
                    row["outcomes"][r["outcome"]] = row["outcomes"].get(r["outcome"], 0) + 1
                    if "error_limits" in r:
                        row["errors"].append(r["error_limits"])
    return table


def print_variants(table: dict) -> None:
    """Markdown table of the variants, one row per grade, method and triad."""
    print(
        "| grade | method | triad | faulty sessions: isolated / found+extra / misattributed "
        "/ missed | estimate error, limits (median, 90 %) | sessions without a fault in "
        "the triad: false alarms |"
    )
    print("|---|---|---|---|---|---|")
    for (grade, m, triad), row in sorted(table.items()):
        o = row["outcomes"]
        err = np.array(row["errors"]) if row["errors"] else np.array([np.nan])
        print(
            f"| {grade} | {m} | {triad} | {o.get('isolated', 0)} / {o.get('found + extra', 0)}"
            f" / {o.get('misattributed', 0)} / {o.get('missed', 0)} of {row['faulty']} | "
            f"{np.nanmedian(err):.2f}, {np.nanpercentile(err, 90):.2f} | "
            f"{o.get('false alarm', 0)} of {row['clean']} |"
        )


# ---------------------------------------------------------------------------
# costs


def cost(rate_hz: float = 1000.0, repeats: int = 3) -> dict:
    """Window diagnosis cost at ``rate_hz``: per full window (24 intervals) and per sample."""
    cert = load_default()
    traj = multi_position(n_attitudes=25, dwell_s=3.0, turn_s=1.5, rate_hz=rate_hz, seed=5)
    sim = simulate(cert, traj, seed=6)
    cfg = DiagnosisConfig()
    diag = diagnose_samples(cert, sim.samples, cfg, rate_hz, block_size=65536)
    window = list(diag._window)
    t0 = time.perf_counter()
    for _ in range(repeats):
        diagnose_window(cert, window, cfg)
    per_window = (time.perf_counter() - t0) / repeats
    span = window[-1].t_end - window[0].t_start
    # streaming cost of everything (detector, intervals, windows) per sample
    t0 = time.perf_counter()
    diag = diagnose_samples(cert, sim.samples, cfg, rate_hz, block_size=int(rate_hz))
    total = time.perf_counter() - t0
    return {
        "rate_hz": rate_hz,
        "window_intervals": len(window),
        "window_span_s": span,
        "window_samples": int(span * rate_hz),
        "per_window_ms": per_window * 1e3,
        "per_window_sample_us": per_window / (span * rate_hz) * 1e6,
        "stream_samples": len(sim.samples),
        "stream_windows": diag.windows_run,
        "stream_per_sample_us": total / len(sim.samples) * 1e6,
        "stream_realtime_factor": (len(sim.samples) / rate_hz) / total,
    }


def throughput(n_samples: int = 1_000_000) -> dict:
    """`imudiag diagnose` wall time on a simulated 10^6-sample log (.npz, 200 Hz)."""
    cert = load_default()
    rate = 200.0
    per = multi_position(n_attitudes=16, dwell_s=3.0, turn_s=1.5, rate_hz=rate, seed=9)
    reps = math.ceil(n_samples / len(per))
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "long.npz")
        with open_writer(path, {"sample_rate": rate, "units": "gyro=count accel=count"}) as w:
            written = 0
            for k in range(reps):
                sim = simulate(cert, per, seed=100 + k)
                blk = sim.samples
                blk.t = blk.t + k * (per.t[-1] + 1.0 / rate)
                take = min(len(blk), n_samples - written)
                w.write(blk.slice(0, take))
                written += take
        out = os.path.join(tmp, "report.json")
        t0 = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "imudiag", "diagnose", path, "--json", out],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        wall = time.perf_counter() - t0
        rep = json.loads(Path(out).read_text())
    return {
        "samples": rep["samples"],
        "wall_s": wall,
        "samples_per_s": rep["samples"] / wall,
        "windows": rep["windows_run"],
        "verdict": [rep["verdict"]["accel"], rep["verdict"]["gyro"]],
    }


def main(argv: list[str] | None = None) -> int:
    """Command line of the benchmark."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("what", choices=("cost", "throughput", "variants", "all"))
    p.add_argument("--faulty", type=int, default=40, help="faulty sessions per grade")
    p.add_argument("--clean", type=int, default=10, help="clean sessions per grade")
    p.add_argument("--seed", type=int, default=2026)
    p.add_argument("--methods", default=",".join(METHODS))
    a = p.parse_args(argv)
    if a.what in ("cost", "all"):
        for rate in (200.0, 1000.0):
            print("cost", json.dumps(cost(rate), indent=1))
    if a.what in ("throughput", "all"):
        print("throughput", json.dumps(throughput(), indent=1))
    if a.what in ("variants", "all"):
        print_variants(variants(a.faulty, a.clean, a.seed, tuple(a.methods.split(","))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
