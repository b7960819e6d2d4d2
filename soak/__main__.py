"""``python -m soak``: replay hours of 1 kHz data through the daemon and check it survives."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m soak",
        description="Accelerated replay of simulated 1 kHz IMU data through the monitor daemon "
        "with transport errors and sensor faults injected; exit 0 when it passed.",
    )
    p.add_argument("--hours", type=float, default=24.0, help="data replayed, hours (default 24)")
    p.add_argument("--rate", type=float, default=1000.0, help="sample rate, Hz (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--errors",
        type=float,
        default=1.0,
        help="multiplier of the injected event rates (default 1)",
    )
    p.add_argument(
        "--episodes",
        type=float,
        default=600.0,
        help="seconds of data between sensor-fault episodes (default 600)",
    )
    p.add_argument("--no-diagnosis", action="store_true", help="per-sample checks only")
    p.add_argument(
        "--rss-limit",
        type=float,
        default=5.0,
        help="resident growth allowed after the warm-up, MB (default 5)",
    )
    p.add_argument("--json", metavar="OUT", help="write the result as JSON ('-': stdout)")
    a = p.parse_args(argv)

    from .run import run_soak

    r = run_soak(
        hours=a.hours,
        rate_hz=a.rate,
        seed=a.seed,
        error_rate=a.errors,
        episode_every_s=a.episodes,
        diagnosis=not a.no_diagnosis,
        rss_limit_mb=a.rss_limit,
    )
    print(
        f"soak: {r.hours:g} h at {r.rate_hz:g} Hz = {r.samples} samples in {r.wall_s:.1f} s "
        f"({r.samples_per_s:.3g} samples/s)"
    )
    print(f"  status lines {r.status_lines}, malformed {len(r.status_errors)}")
    print(f"  counters {r.counters}")
    print(
        f"  injected {r.expected_counters}, adc_errors {r.adc_errors}/{r.expected_adc_errors}, "
        f"reconnects {r.reconnects}/{r.expected_reconnects}"
    )
    print(f"  events {r.events}")
    print(
        f"  fault episodes reported {r.episodes_detected}/{r.episodes}, monitor false alarms "
        f"{r.monitor_false_alarms}"
    )
    print(
        f"  resident memory {r.rss_mb_start:.1f} -> {r.rss_mb_end:.1f} MB, growth after warm-up "
        f"{r.rss_growth_mb:.2f} MB, slope {r.rss_slope_mb_per_h:+.3f} MB/h"
    )
    for f in r.failures:
        print(f"  FAIL: {f}")
    print("PASS" if r.passed else "FAIL")
    if a.json:
        text = json.dumps(r.as_dict(), indent=1)
        if a.json == "-":
            print(text)
        else:
            with open(a.json, "w", encoding="utf-8") as fh:
                fh.write(text + "\n")
    return 0 if r.passed else 1


if __name__ == "__main__":
    sys.exit(main())
