"""``python -m benchmarks.gyro_turns``: the gyros-in-turns figures of docs/moving-base.md.

For each car scenario and seed (standard GNSS, 0.03/0.05 m/s per axis, 1 sigma): a
clean drive and 3-limit gz faults (scale factor +-3 limits, bias +3 limits) from the
start; prints the turn check's verdict, its faults, the turns used, the ratio of the
gyro-integrated |omega| to the GNSS course change, and the gz fit (certificate units).
Fixed seeds; one line per run.
"""

from __future__ import annotations

import argparse
import time

from imudiag.aiding.moving import MovingConfig, moving_base_diagnosis
from imudiag.aiding.tpv import parse_tpv, track_from_reports
from imudiag.certificate import load_default
from imudiag.sim.drive import simulate_drive
from imudiag.sim.faults import Fault


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=600.0, help="drive length, s")
    ap.add_argument("--seeds", default="21,22,23")
    ap.add_argument("--scenarios", default="urban,hilly,highway")
    ap.add_argument("--slip", type=float, default=0.0, help="side slip, rad per m/s^2")
    args = ap.parse_args(argv)
    cert = load_default()
    lim = cert.gyro.limits
    runs = [
        ("clean", ()),
        ("gz scale +3", (Fault("scale_factor", "gz", 0.0, 3 * float(lim.scale_factor_error[2])),)),
        ("gz scale -3", (Fault("scale_factor", "gz", 0.0, -3 * float(lim.scale_factor_error[2])),)),
        ("gz bias +3", (Fault("bias", "gz", 0.0, 3 * float(lim.bias[2])),)),
    ]
    for sc in args.scenarios.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            for name, faults in runs:
                t0 = time.perf_counter()
                res, reports, _ = simulate_drive(
                    sc, args.duration, cert, seed=seed, faults=faults,
                    slip_rad_per_m_s2=args.slip,
                )  # fmt: skip
                track = track_from_reports([parse_tpv(r) for r in reports])
                gt = moving_base_diagnosis(res.samples, cert, track, MovingConfig())["gyro_turns"]
                raised = [f"{f.get('sensor', 'gyro')} {f['cause']}" for f in gt["faults"]]
                line = f"{sc:8s} {seed:3d} {name:12s} {gt['verdict']:7s} raised: {raised}"
                if "turns" in gt:
                    p = gt["fit"]["parameters"]
                    s, b = p["gz scale_factor"], p["gz bias"]
                    det = [f"{d['sensor']} {d['cause']}" for d in gt["determined"]]
                    line += (
                        f"; {gt['turns']['count']} turns ({gt['used']} epochs), ratio "
                        f"{gt['turns']['ratio_total']}, F0 failed {gt['f0']['failed']}; gz scale "
                        f"{s['deviation']:+.3f} +- {s['std']:.3f}, gz bias {b['deviation']:+.1f} "
                        f"+- {b['std']:.1f} count; determined {det}; rejected {gt['rejected']}"
                    )
                else:
                    line += f"; {gt['reason']}"
                print(f"{line}; {time.perf_counter() - t0:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
