"""Evidence: a fault that begins mid-session (an onset) is named, alone, on simulated sessions.

Run: ``.venv/bin/python -m benchmarks.fault_onset [--seeds 1 2] [--cases 24 30]``. Per case,
one fault is drawn at random from the catalogue (bias and scale factor of every
accelerometer and MEMS gyro axis, the three accelerometer misalignments), its size 4 to 9
limits (``--limits``) with a random sign, its onset 30 to 90 s into a 40-attitude
multi-position session of the bundled board (3-s holds, 1.5-s turns, 200 Hz, about
180 s), written as a ``.npz`` log and diagnosed as ``imudiag diagnose`` does
(:func:`imudiag.api.diagnose`; the daemon gives the same verdict,
tests/test_one_answer.py). The parameters it names are scored (the
monitor's F0, noise and stuck checks are counted apart):

- ``exact``: the one fault named, nothing else, first in a window after the onset;
- ``wrong``: a parameter named that was not injected, or a fault before the onset;
- ``missed``: no parameter named (the session ended before the windows could tell).

``--windows-only`` scores :func:`imudiag.diagnosis.diagnose_samples` instead: the windows
alone on the samples, with the certificate's noise (the library's streaming default).

``--wander N``: N healthy sessions whose every bias wanders instead (first-order
Gauss-Markov, sigma 0.2 to 0.6 limits, time constant 10 to 60 s, drawn at random): per
session the verdict, the windows that split a step, and the largest true excursion of each
bias (limits; the simulation rerun without white noise, minus one without the wander), so
a named bias fault can be checked against the truth.

Prints one line a case and the totals. Figures of 2026-11-29 (seeds 1 and 2, 24 and 30
cases; seeds 3 and 4, 30 each; ``--limits 2 4`` seed 5, 30): docs/diagnosis.md, "Fault
onsets mid-session".
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from imudiag.api import diagnose
from imudiag.certificate import (
    SENSOR_NAMES,
    Certificate,
    default_certificate_path,
    load_default,
)
from imudiag.diagnosis import diagnose_samples
from imudiag.diagnosis.params import CAUSES, PARAM_KEYS, limit_vector, sensor_of
from imudiag.logs import open_writer
from imudiag.sim import Effects, Fault, multi_position, simulate
from imudiag.sim.simulator import SimResult
from imudiag.sim.trajectories import Trajectory


def catalogue(triads: tuple[str, ...] = ("accel", "gyro")) -> list[tuple[str, str, int]]:
    """(kind, sensor, parameter index) of every fault drawn from: per triad the bias and
    scale factor of each axis, then the accelerometer misalignments (tests/
    test_diagnosis_isolation.py's MEMS catalogue), named as the diagnosis names them."""
    out = []
    for triad in triads:
        for axis in range(3):
            out += [(CAUSES[i], sensor_of(triad, i), i) for i in (axis, 3 + axis)]
    if "accel" in triads:
        out += [(CAUSES[i], sensor_of("accel", i), i) for i in range(6, 9)]
    return out


def run(
    seed: int,
    cases: int,
    windows_only: bool = False,
    limits: tuple[float, float] = (4.0, 9.0),
    workdir: Path | None = None,
) -> dict[str, int]:
    """Score ``cases`` onsets drawn under ``seed``, their size in ``limits`` (low, high);
    prints a line each, returns the totals. The session log is written in ``workdir``
    (a temporary folder removed at the end when None)."""
    if workdir is None:
        with tempfile.TemporaryDirectory(prefix="imudiag-onset-") as tmp:
            return run(seed, cases, windows_only, limits, Path(tmp))
    cert = load_default()
    log = workdir / "session.npz"
    cat = catalogue()
    rng = np.random.default_rng(seed)
    totals = {"exact": 0, "wrong": 0, "missed": 0}
    for _ in range(cases):
        kind, sensor, index = cat[int(rng.integers(len(cat)))]
        factor = float(rng.uniform(*limits)) * float(rng.choice([-1.0, 1.0]))
        at_s = float(rng.uniform(30.0, 90.0))
        sim_seed = int(rng.integers(10_000))
        triad = "gyro" if sensor[0] == "g" else "accel"
        limit = float(limit_vector(cert.triad(triad))[index])
        traj = multi_position(n_attitudes=40, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=sim_seed)
        sim = simulate(
            cert, traj, seed=sim_seed + 1, faults=[Fault(kind, sensor, at_s, factor * limit)]
        )
        if windows_only:
            verdict = diagnose_samples(cert, sim.samples, rate_hz=traj.rate_hz).verdict()
        else:
            with open_writer(log, {"sample_rate": traj.rate_hz}) as out:
                out.write(sim.samples)
            verdict = diagnose(str(log), str(default_certificate_path()))["verdict"]
        faults = [f for f in verdict["faults"] if f["cause"] in PARAM_KEYS]
        checks = sorted(
            {f"{f['sensor'] or f['triad']} {f['cause']}" for f in verdict["faults"]}
            - {f"{f['sensor']} {f['cause']}" for f in faults}
        )
        named = sorted({(f["triad"], f["sensor"], f["cause"]) for f in faults})
        early = [f for f in faults if f["t_first"] < at_s]
        if named == [(triad, sensor, kind)] and not early:
            score = "exact"
        elif named:
            score = "wrong"
        else:
            score = "missed"
        totals[score] += 1
        said = [(f["sensor"], f["cause"], round(f["t_first"], 1)) for f in faults]
        gone = [(f["sensor"], f["cause"]) for f in verdict.get("withdrawn", [])]
        print(
            f"{kind:12s} {sensor:6s} {factor:+5.1f} limits from t = {at_s:5.1f} s: {score:6s} "
            f"named {said}"
            + (f", withdrawn {gone}" if gone else "")
            + (f"; checks {checks}" if checks else ""),
            flush=True,
        )
    return totals


def wander_session(
    cert: Certificate, seed: int
) -> tuple[float, float, Trajectory, SimResult, dict[str, float]]:
    """One healthy session whose every bias wanders (module docstring), drawn under ``seed``:
    (sigma in limits, time constant s, trajectory, simulation, largest true excursion of
    each bias in limits)."""
    triads = ("accel", "gyro")
    lim = {tri: cert.triad(tri).limits.bias for tri in triads}
    rng = np.random.default_rng(seed)
    frac, tau_s = float(rng.uniform(0.2, 0.6)), float(rng.uniform(10.0, 60.0))
    gm = {
        s: (frac * float(lim[tri][i]), tau_s)
        for tri in triads
        for i, s in enumerate(SENSOR_NAMES[tri])
    }
    traj = multi_position(n_attitudes=40, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=seed)
    sim = simulate(cert, traj, seed=seed + 100, effects=Effects(bias_instability=gm))
    quiet = simulate(
        cert, traj, seed=seed + 100, effects=Effects(bias_instability=gm, white_noise=False)
    ).samples
    still = simulate(cert, traj, seed=seed + 100, effects=Effects(white_noise=False)).samples
    excursion = {
        s: float(np.max(np.abs(quiet.triad(tri)[:, i] - still.triad(tri)[:, i])) / lim[tri][i])
        for tri in triads
        for i, s in enumerate(SENSOR_NAMES[tri])
    }
    return frac, tau_s, traj, sim, excursion


def wander(sessions: int, seed: int = 700, workdir: Path | None = None) -> None:
    """Healthy sessions with wandering biases (module docstring); prints a line each. The
    session log is written in ``workdir`` (a temporary folder removed at the end when None)."""
    if workdir is None:
        with tempfile.TemporaryDirectory(prefix="imudiag-wander-") as tmp:
            return wander(sessions, seed, Path(tmp))
    cert = load_default()
    log = workdir / "session.npz"
    for k in range(sessions):
        frac, tau_s, traj, sim, excursion = wander_session(cert, seed + k)
        with open_writer(log, {"sample_rate": traj.rate_hz}) as out:
            out.write(sim.samples)
        report = diagnose(str(log), str(default_certificate_path()))
        verdict = report["verdict"]
        split = sum(
            1
            for w in report["windows"]
            if w["gyro"].get("rest_step")
            or w["accel"].get("step_change")
            or w["gyro"].get("step_change")
        )
        named = [
            (f["sensor"], f["cause"], round((f["estimate"] - f["certificate"]) / f["limit"], 2))
            for f in verdict["faults"]
            if f["cause"] in PARAM_KEYS
        ]
        worst = max(excursion, key=lambda s: excursion[s])
        print(
            f"sigma {frac:.2f} limits, tau {tau_s:4.1f} s: {verdict['accel']}/{verdict['gyro']} "
            f"named {named} (estimate, limits), windows split {split}; largest true "
            f"excursion {worst} {excursion[worst]:.2f} limits; "
            + " ".join(f"{s} {v:.2f}" for s, v in excursion.items()),
            flush=True,
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--cases", type=int, nargs="+", default=[24, 30], help="cases per seed")
    ap.add_argument("--windows-only", action="store_true", help="diagnose_samples instead")
    ap.add_argument(
        "--limits", type=float, nargs=2, default=[4.0, 9.0], help="fault size range, limits"
    )
    ap.add_argument("--wander", type=int, metavar="N", help="N healthy wandering sessions")
    args = ap.parse_args(argv)
    if args.wander:
        wander(args.wander)
        return 0
    grand = {"exact": 0, "wrong": 0, "missed": 0}
    for seed, n in zip(args.seeds, args.cases, strict=True):
        totals = run(seed, n, args.windows_only, (args.limits[0], args.limits[1]))
        print(f"seed {seed}: {totals}", flush=True)
        for k, v in totals.items():
            grand[k] += v
    print(f"all: {grand}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
