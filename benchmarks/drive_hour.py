"""``python -m benchmarks.drive_hour``: 1 h simulated drives with and without GNSS aiding.

For each car scenario (vibration-free, the certificate's rate, seed fixed): the
monitor (the daemon's per-sample checks, fed at speed 0 in 10 s blocks) on a clean
drive with the quasi-static detector as shipped and with its drift tests off
(faults raised, F0 failures, samples taken as quasi-static per true motion class);
the moving-base diagnosis with standard-grade GNSS on the clean drive (faults);
and an az bias of 3 limits injected at 1800 s: the time to the first fault without
aiding (the monitor's F0) and with it (the moving-base isolation). Prints one line
per run; the figures are in docs/moving-base.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from imudiag.aiding.moving import MovingConfig, moving_base_diagnosis
from imudiag.aiding.tpv import parse_tpv, track_from_reports
from imudiag.certificate import load_default
from imudiag.monitor import Monitor
from imudiag.quasistatic import QuasiStaticDetector
from imudiag.samples import SampleBlock
from imudiag.sim.drive import EPOCH_UNIX, GnssSimConfig, gnss_reports
from imudiag.sim.faults import Fault
from imudiag.sim.scenarios import scenario_motion
from imudiag.sim.simulator import Simulator

T_FAULT = 1800.0
CLASSES = ("stopped", "cruise", "accelerating", "turning or pitching")


def _run_monitor(scenario, seed, duration, faults, drift):
    cert = load_default()
    rate = float(cert.sample_rate)
    motion = scenario_motion(scenario, seed, {"length": str(duration)})
    total = motion.n_samples(rate)
    sim = Simulator(cert, None, list(faults), seed)
    mon = Monitor(cert)
    opts = {} if drift else {"drift_f0_fraction": None}
    mon.detector = QuasiStaticDetector(cert, rate, **opts)  # type: ignore[arg-type]
    det = QuasiStaticDetector(cert, rate, **opts)  # type: ignore[arg-type]
    counts = {k: [0, 0] for k in CLASSES}
    blocks = []
    chunk = int(10 * rate)
    for start in range(0, total, chunk):
        traj = motion.sample(rate, start, min(chunk, total - start))
        block = sim.step(traj)
        block.t = block.t + EPOCH_UNIX
        mon.update(block)
        static = det.update(block)
        _, w_nb, acc, stopped = motion.kinematics(traj.t)
        turning = np.linalg.norm(w_nb, axis=1) > 0.005
        accel = np.linalg.norm(acc, axis=1) > 0.02
        cls = np.where(stopped, 0, np.where(turning, 3, np.where(accel, 2, 1)))  # the CLASSES order
        for i, k in enumerate(CLASSES):
            m = cls == i
            counts[k][0] += int(m.sum())
            counts[k][1] += int(static[m].sum())
        blocks.append(block)
    return cert, motion, mon, counts, blocks


def _turns(out: dict) -> str:
    """The gyro-in-turns check of a moving-base report in a few words."""
    turns = out.get("gyro_turns") or {}
    faults = turns.get("faults") or []
    names = (
        ", ".join(f"{f.get('sensor') or f.get('triad')} {f.get('cause')}" for f in faults) or "none"
    )
    return f"{turns.get('verdict')} (faults: {names})"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=3600.0, help="drive length, s")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--scenarios", default="urban,highway,hilly")
    args = ap.parse_args(argv)
    for sc in args.scenarios.split(","):
        for drift in (False, True):
            t0 = time.perf_counter()
            cert, motion, mon, counts, blocks = _run_monitor(
                sc, args.seed, args.duration, (), drift
            )
            faults = mon.f0_faults()
            label = "shipped detector" if drift else "drift tests off"
            static = ", ".join(f"{k} {s}/{n}" for k, (n, s) in counts.items())
            print(
                f"{sc:8s} clean, no aiding, {label}: faults raised "
                f"{sum(f['raised'] for f in faults)} "
                f"({', '.join(f['triad'] for f in faults) or 'none'}); accel F0 failed "
                f"{mon.f0_failed['accel']} of {mon.f0_checked['accel']}; quasi-static samples "
                f"per class: {static}; {time.perf_counter() - t0:.0f} s",
                flush=True,
            )
        whole = SampleBlock.concat(blocks)
        track = track_from_reports(
            [parse_tpv(r) for r in gnss_reports(motion, GnssSimConfig(), args.seed)]  # type: ignore[arg-type]
        )
        t0 = time.perf_counter()
        out = moving_base_diagnosis(whole, cert, track, MovingConfig())
        print(
            f"{sc:8s} clean, aided (standard GNSS): faults {len(out['faults'])}; F0 in motion "
            f"failed {out['f0']['failed']} of {out['f0']['checked']} epochs; gyros in turns "
            f"{_turns(out)}; {time.perf_counter() - t0:.0f} s",
            flush=True,
        )
        lim = float(cert.accel.limits.bias[2])
        fault = (Fault("bias", "az", T_FAULT, 3.0 * lim),)
        cert, motion, mon, _, blocks = _run_monitor(sc, args.seed, args.duration, fault, True)
        ff = mon.f0_faults()
        first = f"+{ff[0]['t_first'] - EPOCH_UNIX - T_FAULT:.0f} s" if ff else "not raised"
        out = moving_base_diagnosis(SampleBlock.concat(blocks), cert, track, MovingConfig())
        aided = "not raised"
        if out["faults"]:
            f = out["faults"][0]
            name = (
                f"{f['sensor']} {f['cause']}"
                if f["named"]
                else " or ".join(f"{o['sensor']} {o['cause']}" for o in f["one_of"])
            )
            aided = f"{name} +{f['t_first'] - EPOCH_UNIX - T_FAULT:.0f} s"
        print(
            f"{sc:8s} az bias 3 limits at {T_FAULT:.0f} s: without aiding (monitor F0) "
            f"{first}; with aiding {aided}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
