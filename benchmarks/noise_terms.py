"""Evidence: the noise model of long still sessions with one noise term hidden at random.

Run: ``.venv/bin/python -m benchmarks.noise_terms [--seeds 0-11] [--rate 100]
[--duration S]``. Per seed, one term of :data:`TERMS` (white noise of another density
than the certificate's, quantisation Q, bias instability B, rate random walk K, rate ramp
R, or none; seed mod 6) is hidden on a random gyro, magnitude and session length (1-3 h), a still
session of the bundled board is simulated (whole counts, as a real count log), and the
noise-model selection of the model check (:func:`imudiag.modelcheck.noisemodel.select`,
on bins of at most 0.05 s as ``imudiag model-check`` reads them) runs blind on all six
sensors. Prints per seed the term and its value, what was named and its value, and the
largest measured/predicted Allan-deviation ratio over 0.1 s to a tenth of the record
(figures of docs/model-check.md). ``tests/test_modelcheck_noise.py`` runs one 1 h case.
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass

import numpy as np

from imudiag.certificate import load_default
from imudiag.modelcheck.noisemodel import MAX_RATIO, SensorNoise, agrees, bin_means, select
from imudiag.sim import Effects, simulate, still

#: the hidden-term catalogue; "white": the white noise differs from the certificate's
#: figure (nothing beyond white noise to name); "none": the certificate's white noise
TERMS = ("white", "quantization", "bias_instability", "bias_drift", "rate_ramp", "none")
#: the noise model's key holding each term's value (u: counts here)
VALUE_KEY = {
    "white": "density",  # count/sqrt(Hz)
    "quantization": "quantization",  # count s
    "bias_instability": "bias_instability",  # count
    "bias_drift": "bias_drift",  # count/sqrt(s)
    "rate_ramp": "rate_ramp",  # count/s
}
SENSORS = ("gx", "gy", "gz", "ax", "ay", "az")
DURATIONS_S = (3600.0, 5400.0, 7200.0, 10800.0)  #: 1, 1.5, 2, 3 h
BIN_S = 0.05  #: s, the model check's read bins (noisemodel.run_samples)


@dataclass
class Case:
    """One hidden term: the value is in the unit of :data:`VALUE_KEY`'s term, counts."""

    seed: int
    term: str
    sensor: str
    value: float
    duration_s: float
    rate_hz: float
    effects: Effects


def draw(seed: int, rate_hz: float, duration_s: float | None = None) -> Case:
    """The term, gyro, magnitude and length (s) hidden under ``seed`` at ``rate_hz`` (Hz)."""
    rng = np.random.default_rng(seed)
    term = TERMS[seed % len(TERMS)]  # every term once in six consecutive seeds
    sensor = str(rng.choice(["gx", "gy", "gz"]))
    dur = float(rng.choice(DURATIONS_S)) if duration_s is None else float(duration_s)
    density = float(load_default().gyro.noise.density[0])  # count/sqrt(Hz), 6.55
    value, eff = 0.0, Effects(quantize=True)
    if term == "white":  # the data-sheet figure 1.5-3x too low (as on the MPU-6050)
        scale = float(rng.uniform(1.5, 3.0))
        value, eff = density * scale, Effects(quantize=True, noise_scale=scale)
    elif term == "quantization":
        # a coarse integrating output: at 0.1 s its Allan deviation sqrt(3) Q / tau is
        # 0.8-2 times the white noise's (density / sqrt(2 tau)); step q = Q rate sqrt(12)
        rel = float(rng.uniform(0.8, 2.0))
        value = rel * density / math.sqrt(0.2) * 0.1 / math.sqrt(3.0)
        step = value * rate_hz * math.sqrt(12.0)
        eff = Effects(quantize=True, quantization={sensor: step})
    elif term == "bias_instability":
        value = float(rng.uniform(12.0, 40.0))  # counts: floor 8-27
        eff = Effects(quantize=True, flicker={sensor: value})
    elif term == "bias_drift":
        value = float(rng.uniform(0.3, 1.0))  # count/sqrt(s)
        eff = Effects(quantize=True, bias_drift={sensor: value})
    elif term == "rate_ramp":
        value = float(rng.uniform(0.01, 0.03))  # count/s
        eff = Effects(quantize=True, rate_ramp={sensor: value})
    return Case(seed, term, sensor, value, dur, float(rate_hz), eff)


def noise_models(case: Case, sensors: tuple[str, ...] = SENSORS) -> dict[str, SensorNoise]:
    """Simulate the still session and select each sensor's noise model blind."""
    r = simulate(
        load_default(),
        still(case.duration_s, rate_hz=case.rate_hz),
        seed=1000 + case.seed,
        effects=case.effects,
    )
    y = np.hstack([r.samples.gyro, r.samples.accel])
    factor = max(1, int(math.floor(case.rate_hz * BIN_S)))
    binned = bin_means(y, factor)
    rate = case.rate_hz / factor
    return {s: select(binned[:, SENSORS.index(s)], rate) for s in sensors}


def named(sn: SensorNoise) -> list[str]:
    """Effect names of the terms beyond white noise a selection names."""
    return ["gauss_markov_bias" if t == "gauss_markov" else t for t in sn.terms_named]


def expected(case: Case, sensor: str) -> list[str]:
    """What a right selection names on ``sensor``."""
    hidden = case.term not in ("white", "none") and sensor == case.sensor
    return [case.term] if hidden else []


def max_ratio(sn: SensorNoise, max_relative_error: float = math.inf) -> tuple[float, float]:
    """Largest measured/predicted Allan deviation (either way) from 0.1 s to a tenth of
    the record, over the cluster times whose measured deviation has a relative standard
    error below ``max_relative_error``, and the cluster time (s) where it occurs."""
    c = sn.curves()
    r = np.asarray(c["ratio"])
    keep = np.asarray(c["relative_error"]) < max_relative_error
    both = np.where(keep, np.maximum(r, 1.0 / r), 0.0)
    k = int(np.argmax(both))
    return float(both[k]), float(c["tau"][k])


def explained(sn: SensorNoise) -> bool:
    """Within 1.5x at every cluster time, or within 2.5 standard errors of the measured
    deviation (:func:`imudiag.modelcheck.noisemodel.agrees`)."""
    c = sn.curves()
    return bool(np.all(agrees(np.asarray(c["ratio"]), np.asarray(c["relative_error"]))))


def fitted_value(case: Case, fits: dict[str, SensorNoise]) -> float:
    """The hidden term's value as fitted on its sensor (counts, its term's unit)."""
    return float(fits[case.sensor].model.terms.get(VALUE_KEY.get(case.term, "density"), 0.0))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default="0-11", help="first-last (default %(default)s)")
    p.add_argument("--rate", type=float, default=100.0, help="sample rate, Hz")
    p.add_argument("--duration", type=float, default=None, help="s (default: drawn, 1-3 h)")
    a = p.parse_args()
    lo, _, hi = a.seeds.partition("-")
    ok = strict = 0
    seeds = range(int(lo), int(hi or lo) + 1)
    for seed in seeds:
        case = draw(seed, a.rate, a.duration)
        t0 = time.perf_counter()
        fits = noise_models(case)
        wall = time.perf_counter() - t0
        got = {s: named(f) for s, f in fits.items() if named(f)}
        right = all(named(f) == expected(case, s) for s, f in fits.items())
        fv = fitted_value(case, fits)
        rel = fv / case.value - 1.0 if case.value else 0.0
        worst, tau_w = max(max_ratio(f) for f in fits.values())
        firm, _ = max(max_ratio(f, 0.1) for f in fits.values())
        stat = all(explained(f) for f in fits.values())
        good = right and abs(rel) < 0.3 and stat and firm <= MAX_RATIO
        strict += worst <= MAX_RATIO
        ok += good
        unit = {
            "white": "count/sqrt(Hz)",
            "quantization": "count s",
            "bias_instability": "count",
            "bias_drift": "count/sqrt(s)",
            "rate_ramp": "count/s",
        }.get(case.term, "")
        print(
            f"seed {seed:3d} {case.duration_s / 3600:.1f} h {a.rate:g} Hz  hidden "
            f"{case.term} {case.sensor if case.term not in ('white', 'none') else ''} "
            f"{case.value:.4g} {unit}  named {got or 'nothing'}  fitted {fv:.4g} "
            f"({rel:+.0%})  max ratio {worst:.3f} at {tau_w:.3g} s, {firm:.3f} where known "
            f"to 10 %{'' if stat else ', beyond 2.5 standard errors'}  "
            f"{'ok' if good else 'MISS'}  ({wall:.1f} s)"
        )
    print(
        f"{ok} of {len(seeds)} cases right (the term on its sensor only, its value within "
        f"30 %, the curve within 1.5x where known to 10 % and within 1.5x or 2.5 standard "
        f"errors everywhere); {strict} within 1.5x at every cluster time"
    )


if __name__ == "__main__":
    main()
