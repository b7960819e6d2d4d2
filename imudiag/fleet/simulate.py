"""``imudiag simulate fleet``: a simulated fleet to try ``imudiag fleet`` on, with its
ground truth (``truth.json``).

Each vehicle has a folder of flights in mixed formats (CSV, gzip CSV, NPZ, the raw
capture) and flight types (a pre-flight multi-position check, a static cycle with fewer
attitudes); half the vehicles name themselves in their logs' metadata (``vehicle``: a
serial number), the others are known by their folder. Every unit carries small steady
offsets within its limits; a few units have one parameter drifting linearly over their
flights, from 0.2 to 1.5 times its limit. A few extra files are corrupt or truncated.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import write_text_atomic
from ..certificate import Certificate, load_default
from ..diagnosis.params import cause_unit
from ..errors import BadInput
from ..logs import open_writer
from ..sim.faults import Fault
from ..sim.scenarios import parse_effects, scenario_motion
from ..sim.simulator import Simulator

#: Formats the flights are written in, in turn.
FORMATS = (".csv", ".npz", ".csv.gz", ".bin")
#: Flight types in turn: three pre-flight multi-position checks, then a static cycle.
FLIGHT_TYPES = ("multiposition", "multiposition", "multiposition", "static")
#: Parameters that drift on a drifting unit, in turn: (triad, sensor, cause).
DRIFTS = (("accel", "az", "bias"), ("gyro", "gy", "bias"), ("accel", "ax", "scale_factor"))
#: A drifting parameter's offset on the first and the last flight, in limits.
DRIFT_FROM, DRIFT_TO = 0.2, 1.5
#: Steady offsets of every unit, in limits (uniform in +-).
STEADY = 0.25
#: Corruptions applied to the extra bad files, in turn.
CORRUPTIONS = ("truncated", "garbage-row", "not-a-log")
#: First flight's day (UTC).
EPOCH = dt.datetime(2026, 1, 5, 8, 0, tzinfo=dt.UTC)
FLIGHT_SECONDS = (35.0, 60.0)  #: default flight length range, s
DEFAULT_RATE_HZ = 100.0
TURN_S = 1.0  #: time of each turn between attitudes, s


def _limit(cert: Certificate, triad: str, sensor: str, cause: str) -> float:
    model = cert.triad(triad)
    axis = "xyz".index(sensor[-1])
    lim = {"bias": model.limits.bias, "scale_factor": model.limits.scale_factor_error}[cause]
    return float(lim[axis])


def _motion(kind: str, seconds: float, seed: int) -> Any:
    if kind == "multiposition":
        n = 12
        dwell = max(1.5, (seconds - n * TURN_S) / n)
        return scenario_motion(
            kind, seed, {"n": str(n), "dwell": f"{dwell:g}", "turn": f"{TURN_S:g}"}
        )
    n = 8
    dwell = max(1.5, (seconds - n * 1.5) / n)
    return scenario_motion(kind, seed, {"n": str(n), "dwell": f"{dwell:g}", "turn": "1.5"})


def write_flight(
    path: Path,
    cert: Certificate,
    kind: str,
    seconds: float,
    rate: float,
    faults: list[Fault],
    seed: int,
    meta: dict[str, Any],
) -> int:
    """One simulated flight of ``kind`` (``multiposition``: 12 holds, ``static``: 8) lasting
    ``seconds`` at ``rate`` Hz with ``faults``, written to ``path`` (any log format) with
    ``meta``; the number of samples written."""
    motion = _motion(kind, seconds, seed)
    total = motion.n_samples(rate)
    want = int(round(seconds * rate))
    total = want if total is None else min(total, want)
    sim = Simulator(cert, parse_effects(["board"]), faults, seed, meta=dict(meta))
    chunk = int(30 * rate)
    with open_writer(path, meta=meta) as writer:
        done = 0
        while done < total:
            n = min(chunk, total - done)
            writer.write(sim.step(motion.sample(rate, done, n)))
            done += n
    return total


def _corrupt(path: Path, how: str, rng: np.random.Generator) -> None:
    data = path.read_bytes()
    if how == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif how == "garbage-row":
        lines = data.split(b"\n")
        k = len(lines) // 2
        lines[k] = b"1.0,not-a-number,\xff\xfe,3"
        path.write_bytes(b"\n".join(lines))
    else:
        path.write_bytes(rng.bytes(4096))


def simulate_fleet(
    out: str | Path,
    vehicles: int,
    flights: int,
    *,
    seed: int = 0,
    drifting: int | None = None,
    corrupt: int = 3,
    seconds: tuple[float, float] = FLIGHT_SECONDS,
    rate_hz: float = DEFAULT_RATE_HZ,
    certificate: Certificate | None = None,
    progress: Any = None,
) -> dict[str, Any]:
    """Write a simulated fleet into ``out`` and its ``truth.json``; returns the truth.

    ``drifting``: units with a drifting parameter (default: a third of them, at least 1).
    ``corrupt``: extra corrupt or truncated files. ``seconds``: flight length range, s.
    """
    if vehicles < 1 or flights < 1:
        raise BadInput("--vehicles and --flights: at least 1 each")
    if flights < 3 and (drifting or 0) > 0:
        raise BadInput("--flights: a drift needs at least 3 flights")
    cert = certificate or load_default()
    n_drift = max(1, vehicles // 3) if drifting is None else drifting
    if n_drift > vehicles:
        raise BadInput(f"--drifting {n_drift}: more than the {vehicles} vehicles")
    rng = np.random.default_rng(seed)
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    drift_units = set(rng.choice(vehicles, size=n_drift, replace=False).tolist())
    truth: dict[str, Any] = {
        "seed": seed,
        "rate_hz": rate_hz,
        "certificate": str(cert.source),
        "vehicles": [],
        "corrupt": [],
    }
    logs_total = vehicles * flights
    written = 0
    for v in range(vehicles):
        folder = root / f"unit-{v + 1:02d}"
        folder.mkdir(exist_ok=True)
        serial = f"SN-{4100 + 17 * v}" if v % 2 == 0 else None
        steady = []
        for triad, sensors in (("accel", ("ax", "ay", "az")), ("gyro", ("gx", "gy", "gz"))):
            for s in sensors:
                lim = _limit(cert, triad, s, "bias")
                steady.append(Fault("bias", s, 0.0, float(rng.uniform(-STEADY, STEADY) * lim)))
        drift: dict[str, Any] | None = None
        if v in drift_units:
            triad, sensor, cause = DRIFTS[sorted(drift_units).index(v) % len(DRIFTS)]
            lim = _limit(cert, triad, sensor, cause)
            sign = float(rng.choice([-1.0, 1.0]))
            drift = {
                "triad": triad,
                "sensor": sensor,
                "cause": cause,
                "unit": cause_unit(cert.triad(triad), cause),
                "limit": lim,
                "offsets": [
                    sign * lim * (DRIFT_FROM + (DRIFT_TO - DRIFT_FROM) * k / max(1, flights - 1))
                    for k in range(flights)
                ],
            }
        entry: dict[str, Any] = {
            "vehicle": serial or folder.name,
            "folder": folder.name,
            "named_in_logs": serial is not None,
            "drifting": drift,
            "flights": [],
        }
        when = EPOCH + dt.timedelta(hours=float(rng.uniform(0, 48)))
        for k in range(flights):
            kind = FLIGHT_TYPES[k % len(FLIGHT_TYPES)]
            fmt = FORMATS[(v + k) % len(FORMATS)]
            faults = [
                f
                for f in steady
                if not (drift and f.sensor == drift["sensor"] and drift["cause"] == "bias")
            ]
            if drift:
                faults.append(Fault(drift["cause"], drift["sensor"], 0.0, drift["offsets"][k]))
            meta: dict[str, Any] = {
                "sample_rate": int(rate_hz) if float(rate_hz).is_integer() else rate_hz,
                "start": when.isoformat(),
            }
            if serial:
                meta["vehicle"] = serial
            path = folder / f"flight-{k + 1:03d}{fmt}"
            seconds_k = float(rng.uniform(*seconds))
            n = write_flight(
                path, cert, kind, seconds_k, rate_hz, faults, seed * 100003 + v * 1009 + k, meta
            )
            entry["flights"].append(
                {
                    "path": str(path.relative_to(root)),
                    "type": kind,
                    "format": fmt,
                    "start": when.isoformat(),
                    "samples": n,
                    "seconds": n / rate_hz,
                }
            )
            when += dt.timedelta(days=float(rng.uniform(1.0, 4.0)))
            written += 1
            if progress:
                progress("simulating", written / logs_total, written)
        truth["vehicles"].append(entry)
    for c in range(corrupt):
        how = CORRUPTIONS[c % len(CORRUPTIONS)]
        v = c % vehicles
        folder = root / f"unit-{v + 1:02d}"
        fmt = ".npz" if how == "truncated" else ".csv"
        path = folder / f"bad-{c + 1:02d}{fmt}"
        write_flight(
            path,
            cert,
            "multiposition",
            seconds[0],
            rate_hz,
            [],
            seed + 7919 + c,
            {"sample_rate": rate_hz},
        )
        _corrupt(path, how, rng)
        truth["corrupt"].append({"path": str(path.relative_to(root)), "how": how})
    write_text_atomic(root / "truth.json", json.dumps(truth, indent=1) + "\n")
    return truth


__all__ = ["simulate_fleet", "write_flight"]
