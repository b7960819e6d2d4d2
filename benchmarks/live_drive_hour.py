"""``python -m benchmarks.live_drive_hour``: 1 h drives through the daemon's own path.

For each car scenario and seed (vibration-free, the bundled certificate's rate,
standard-grade GNSS): the monitor (the daemon's per-sample checks) and the live
aiding (:class:`imudiag.aiding.live.LiveAiding`, its real gpsd client on a loopback
TCP socket that speaks gpsd's JSON) fed the same 0.25 s blocks, each TPV line written
to the socket when the IMU stream reaches the fix's time, the aiding's clock the
sample time (so "outage" means sample seconds, not wall seconds). Prints one line
per run: the faults raised on the clean drive (monitor F0, accelerometer groups, F0
in motion, gyros in turns), the aiding's batches and state; then the time from a
3-limit az bias and a 3-limit gz scale factor at 1800 s to the first fault and its
name. The figures are in docs/moving-base.md ("1 h drives through the daemon").
"""

from __future__ import annotations

import argparse
import json
import select
import socket
import time
from dataclasses import dataclass, field

from imudiag.aiding.live import LiveAiding
from imudiag.aiding.moving import MovingConfig
from imudiag.aiding.tpv import parse_tpv
from imudiag.certificate import Certificate, load_default
from imudiag.monitor import Monitor
from imudiag.sim.drive import EPOCH_UNIX, GnssSimConfig, gnss_reports
from imudiag.sim.faults import Fault
from imudiag.sim.scenarios import scenario_motion
from imudiag.sim.simulator import Simulator

T_FAULT = 1800.0  #: s into the drive


@dataclass
class LiveRun:
    """What the daemon's path raised over one drive (times in drive seconds)."""

    first: dict[str, float] = field(default_factory=dict)  #: fault name -> first raised, s
    batches: int = 0  #: LiveAiding batches run
    status: dict = field(default_factory=dict)  #: the aiding's status at the end
    fixes_sent: int = 0


def fault_name(f: dict) -> str:
    """A status fault in words: ``accel az|az bias|scale_factor (moving_base)``."""
    who = f.get("sensor") or f.get("triad")
    return f"{f['triad']} {who} {f['cause']} ({f.get('source', 'monitor')})"


def run_live_drive(
    scenario: str,
    seed: int,
    duration_s: float,
    cert: Certificate,
    faults: tuple = (),
    block_s: float = 0.25,
    gnss: GnssSimConfig | None = None,
    cfg: MovingConfig | None = None,
    batch_s: float | None = None,
    hold_s: float = 0.0,
) -> LiveRun:
    """Drive ``duration_s`` s of ``scenario`` through the Monitor and LiveAiding as the
    daemon feeds them (blocks of ``block_s`` s, GNSS reports over a loopback gpsd socket
    in sample time, a batch every ``batch_s`` s of fixes, None: LiveAiding's default; with
    ``hold_s`` > 0 the lines are held back and sent in a burst every ``hold_s`` s of sample
    time, as a receiver or a loaded machine delivers them late); faults as
    :class:`imudiag.sim.faults.Fault` (t in drive s)."""
    rate = float(cert.sample_rate)
    motion = scenario_motion(scenario, seed, {"length": str(duration_s)})
    total = motion.n_samples(rate)
    sim = Simulator(cert, None, list(faults), seed)
    mon = Monitor(cert)
    lines = [
        (r["t"], (json.dumps(raw) + "\n").encode())
        for raw in gnss_reports(motion, gnss or GnssSimConfig(), seed)
        if (r := parse_tpv(raw)) is not None
    ]
    run = LiveRun()
    now = [0.0]
    chunk = max(1, int(round(block_s * rate)))
    with socket.create_server(("127.0.0.1", 0)) as srv:
        url = f"gpsd://127.0.0.1:{srv.getsockname()[1]}"
        opts = {} if batch_s is None else {"batch_s": batch_s}
        # the batches inline: each runs in update() on the samples so far, as the daemon's
        # worker process runs the same batches (tests/test_aiding_thread.py), so a run does
        # not depend on how busy the machine is
        aid = LiveAiding(
            url, cert, cfg or MovingConfig(), clock=lambda: now[0], mode="inline", **opts
        )
        aid.update(None)  # connects and sends ?WATCH
        conn, _ = srv.accept()
        with conn:
            k = 0
            for start in range(0, total, chunk):
                block = sim.step(motion.sample(rate, start, min(chunk, total - start)))
                block.t = block.t + EPOCH_UNIX
                t_end = float(block.t[-1])
                now[0] = t_end - EPOCH_UNIX
                sent = []
                due = hold_s <= 0 or int(t_end // hold_s) > int((t_end - block_s) // hold_s)
                while due and k < len(lines) and lines[k][0] <= t_end:
                    sent.append(lines[k][1])
                    k += 1
                if sent:
                    conn.sendall(b"".join(sent))
                    # delivered before the aiding reads: loopback under load can hold
                    # lines back for seconds, and late arrivals move the clock tie
                    select.select([aid.client.sock], [], [], 10.0)
                mon.update(block)
                aid.update(block)
                raised = [dict(f, source="monitor") for f in mon.faults_in_force()]
                for f in raised + aid.faults():
                    run.first.setdefault(fault_name(f), now[0])
            run.fixes_sent = k
        run.batches = aid.worker.submitted
        run.status = aid.status()
        aid.close()
    return run


def _after(run: LiveRun, t0: float) -> str:
    """The faults raised from ``t0`` (drive s) on, first first, with their delays."""
    late = sorted((t, n) for n, t in run.first.items() if t >= t0)
    return "; ".join(f"{n} +{t - t0:.0f} s" for t, n in late) or "not raised"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--duration", type=float, default=3600.0, help="drive length, s")
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--scenarios", default="urban,highway,hilly")
    ap.add_argument("--block", type=float, default=0.25, help="block length fed, s")
    ap.add_argument("--runs", default="clean,az,gz", help="of clean, az, gz")
    ap.add_argument(
        "--hold", type=float, default=0.0, help="send the gpsd lines in bursts every S s (late)"
    )
    args = ap.parse_args(argv)
    cert = load_default()
    az = Fault("bias", "az", T_FAULT, 3.0 * float(cert.accel.limits.bias[2]))
    gz = Fault("scale_factor", "gz", T_FAULT, 3.0 * float(cert.gyro.limits.scale_factor_error[2]))
    for sc in args.scenarios.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            runs = args.runs.split(",")
            t0 = time.perf_counter()
            if "clean" in runs:
                _print_clean(
                    sc,
                    seed,
                    run_live_drive(sc, seed, args.duration, cert, (), args.block, hold_s=args.hold),
                    t0,
                )
            if T_FAULT >= args.duration:
                continue
            for label, fault in (("az bias +3", az), ("gz scale +3", gz)):
                if label[:2] not in runs:
                    continue
                t0 = time.perf_counter()
                run = run_live_drive(
                    sc, seed, args.duration, cert, (fault,), args.block, hold_s=args.hold
                )
                before = {n: round(t) for n, t in run.first.items() if t < T_FAULT}
                print(
                    f"{sc:8s} {seed} {label} at {T_FAULT:.0f} s: {_after(run, T_FAULT)}; "
                    f"before it {before or 'none'}; "
                    f"{time.perf_counter() - t0:.0f} s",
                    flush=True,
                )
    return 0


def _print_clean(sc: str, seed: int, run: LiveRun, t0: float) -> None:
    st = run.status
    gt = st["gyro_turns"]
    print(
        f"{sc:8s} {seed} clean: faults {len(run.first)} "
        f"({'; '.join(f'{n} at {t:.0f} s' for n, t in run.first.items()) or 'none'}); "
        f"batches {run.batches}, windows {st['windows']}, F0 in motion failed "
        f"{st['f0']['failed']} of {st['f0']['checked']}; aiding in_use {st['in_use']} "
        f"{st['reason']!r}, latency {st['latency_s']} s ({st['latency']}), gyro turns "
        f"{gt.get('verdict')}; fixes {st['fixes']}/{run.fixes_sent}; "
        f"{time.perf_counter() - t0:.0f} s",
        flush=True,
    )


if __name__ == "__main__":
    raise SystemExit(main())
