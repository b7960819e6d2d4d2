"""``python -m benchmarks.moving_base``: the moving-base figures of docs/moving-base.md.

For every drive scenario and two GNSS grades (standard u-blox class 0.03/0.05 m/s,
RTK class 0.01/0.015 m/s per axis, 1 sigma): a clean drive (faults raised: must be
none) and 3-limit accelerometer faults injected at 300 s, each reported as named,
as a group (which), or not raised, with the time from onset to the first report, and
the windows whose onset test found the fault's onset inside them (docs/moving-base.md).
Fixed seeds; prints one line per run.

``--clean N --wander L``: instead, N clean drives per scenario (standard GNSS, seeds 1..N)
whose three accelerometer biases wander (first-order Gauss-Markov, sigma L x the bias
limit x U(0.5, 1.5), tau U(20, 80) s, drawn under seed 1000 + the drive's seed): faults
raised (false alarms: must be none), each window's GNSS epochs (the isolation's degrees of
freedom are these less the parameters selected, less 1) and the largest |deviation| / std
of a finding (significant at 4 but within its limit is not a fault).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from imudiag.aiding.moving import MovingConfig, moving_base_diagnosis
from imudiag.aiding.tpv import parse_tpv, track_from_reports
from imudiag.certificate import SENSOR_NAMES, load_default
from imudiag.sim.drive import DRIVE_SCENARIOS, EPOCH_UNIX, GnssSimConfig, simulate_drive
from imudiag.sim.effects import Effects
from imudiag.sim.faults import Fault

GRADES = {
    "standard": GnssSimConfig(),
    "rtk": GnssSimConfig(sigma_h_m_s=0.01, sigma_v_m_s=0.015),
}
FAULTS = (
    ("bias", "az", 2, "bias"),
    ("scale_factor", "az", 2, "scale_factor_error"),
    ("bias", "ax", 0, "bias"),
    ("bias", "ay", 1, "bias"),
    ("misalignment", "ax/ay", 0, "misalignment"),
)
T_FAULT = 300.0


def describe(out: dict) -> str:
    if not out["faults"]:
        return "none"
    parts = []
    for f in out["faults"]:
        dt = f["t_first"] - EPOCH_UNIX - T_FAULT
        if f["named"]:
            parts.append(f"{f['sensor']} {f['cause']} (+{dt:.0f} s)")
        else:
            alts = " | ".join(f"{o['sensor']} {o['cause']}" for o in f["one_of"])
            parts.append(f"one of [{alts}] (+{dt:.0f} s)")
    return "; ".join(parts)


def clean_drives(cert, scenarios: list[str], n: int, wander: float, duration_s: float) -> int:
    """``--clean``: n healthy drives per scenario, biases wandering ``wander`` limits."""
    lim = cert.accel.limits.bias
    drives = alarms = 0
    for sc in scenarios:
        for seed in range(1, n + 1):
            rng = np.random.default_rng(1000 + seed)
            effects = None
            if wander:
                effects = Effects(
                    bias_instability={
                        s: (wander * float(lim[i]) * rng.uniform(0.5, 1.5), rng.uniform(20, 80))
                        for i, s in enumerate(SENSOR_NAMES["accel"])
                    }
                )
            res, reports, _ = simulate_drive(sc, duration_s, cert, seed=seed, effects=effects)
            track = track_from_reports([parse_tpv(r) for r in reports])
            out = moving_base_diagnosis(res.samples, cert, track, MovingConfig())
            drives += 1
            alarms += bool(out["faults"])
            epochs = [w["epochs"] for w in out["windows"]]
            most = max(
                (
                    abs(d) / s
                    for w in out["windows"]
                    for f in w["findings"]
                    for d, s in zip(f["deviation"], f["std"], strict=True)
                    if s > 0
                ),
                default=0.0,
            )
            print(
                f"{sc:8s} seed {seed}: raised {describe(out)}; {len(epochs)} windows of "
                f"{min(epochs, default=0)}-{max(epochs, default=0)} epochs; largest finding "
                f"{most:.2f} std; F0 failed {out['f0']['failed']}/{out['f0']['checked']}",
                flush=True,
            )
    print(f"{alarms} of {drives} clean drives raised a fault (bias wander {wander:g} limits)")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=700.0, help="drive length, s")
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--scenarios", default=",".join(DRIVE_SCENARIOS))
    ap.add_argument("--clean", type=int, default=0, help="clean drives per scenario (doc)")
    ap.add_argument("--wander", type=float, default=0.0, help="bias wander, bias limits")
    args = ap.parse_args(argv)
    cert = load_default()
    if args.clean:
        return clean_drives(cert, args.scenarios.split(","), args.clean, args.wander, args.duration)
    lim = cert.accel.limits
    for sc in args.scenarios.split(","):
        for grade, gcfg in GRADES.items():
            runs = [("clean", ())] + [
                (
                    f"{kind} {sensor} 3 limits",
                    (Fault(kind, sensor, T_FAULT, 3.0 * float(getattr(lim, key)[i])),),
                )
                for kind, sensor, i, key in FAULTS
            ]
            for name, faults in runs:
                t0 = time.perf_counter()
                res, reports, _ = simulate_drive(
                    sc, args.duration, cert, seed=args.seed, gnss=gcfg, faults=faults
                )
                track = track_from_reports([parse_tpv(r) for r in reports])
                out = moving_base_diagnosis(res.samples, cert, track, MovingConfig())
                lat = out["gnss"]["latency"]
                onsets = [w["onset"] for w in out["windows"] if w["onset"]["found"]]
                withheld = sum(1 for o in onsets if "withheld" in o)
                print(
                    f"{sc:8s} {grade:8s} {name:28s} raised: {describe(out)}; "
                    f"latency {lat['latency_s']} s (true 0.12, std {lat.get('std_s')} s, "
                    f"determined {lat['determined']}, used {lat['used_s']} s); "
                    f"F0 failed {out['f0']['failed']}/{out['f0']['checked']}; "
                    f"onset in {len(onsets)} of {len(out['windows'])} windows "
                    f"({withheld} withheld); "
                    f"{time.perf_counter() - t0:.1f} s",
                    flush=True,
                )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
