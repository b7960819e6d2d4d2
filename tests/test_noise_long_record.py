"""Issue 29 item 3 on a long record: the ADIS16405 situation, simulated under a seed.

The issue's held-out 10,000 s ADIS16405 record showed the extended model 2-3x too low at
1000 s on gy and gz: a long-term component (a rate random walk or a ramp) beside the bias
instability was missed. Here a seeded 10,000 s still record hides, on every gyro, a bias
instability floor (flicker, IEEE B) and, on the axes the seed picks, a long-term term of
the catalogue (``benchmarks.noise_terms.TERMS``: ``bias_drift`` K or ``rate_ramp`` R)
meeting that floor at 150-500 s. The model check's joint selection
(:func:`imudiag.modelcheck.noisemodel.select`) must keep the predicted Allan deviation
within 1.5x of the measured one at every cluster time whose measured 95 % interval is
within +-30 % (:func:`~imudiag.modelcheck.noisemodel.supported_taus`), and must name a
long-term term wherever the bias instability alone misses there (the issue's miss).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.noise_terms import TERMS
from imudiag.certificate import FLICKER_FACTOR, load_default
from imudiag.modelcheck import noisemodel as nm
from imudiag.sim import Effects, simulate, still

RATE = 10.0  #: Hz (the model check reads bins of at most 0.05 s; 10 Hz keeps it short)
DURATION = 10_000.0  #: s, the issue's record length
GYROS = ("gx", "gy", "gz")
LONG_TERMS = tuple(t for t in TERMS if t in ("bias_drift", "rate_ramp"))
#: the seeds of the records: under 1, gx and gy hide a rate ramp beside their bias
#: instability and gz none (the issue's pattern: two axes missed, one right); under 12
#: every gyro hides a ramp (the test prints each draw). Seeds 1-20 all pass
#: (docs/model-check.md).
SEEDS = (1, 12)


def _record(seed: int) -> tuple[dict[str, tuple[float, str, float]], np.ndarray]:
    """Per gyro (B count, hidden long-term term or "none", its value in count/sqrt(s) or
    count/s) and the (n, 3) gyro record (counts) of ``seed``."""
    rng = np.random.default_rng(seed)
    cert = load_default()
    white = cert.gyro.noise.density / math.sqrt(2.0)  # N, count/sqrt(s) (one-sided / sqrt 2)
    flicker: dict[str, float] = {}
    drift: dict[str, float] = {}
    ramp: dict[str, float] = {}
    truth: dict[str, tuple[float, str, float]] = {}
    for c, s in enumerate(GYROS):
        floor_at = float(rng.uniform(20.0, 100.0))  # s, where B's floor meets white noise
        b = float(white[c]) / math.sqrt(floor_at) / FLICKER_FACTOR
        flicker[s] = b
        kind = str(rng.choice(("none",) + LONG_TERMS))
        meet = float(rng.uniform(150.0, 500.0))  # s, where the term meets the floor
        value = 0.0
        if kind == "bias_drift":  # K^2 tau / 3 = (0.664 B)^2 at tau = meet
            value = drift[s] = FLICKER_FACTOR * b * math.sqrt(3.0 / meet)
        elif kind == "rate_ramp":  # R^2 tau^2 / 2 = (0.664 B)^2 at tau = meet
            value = ramp[s] = FLICKER_FACTOR * b * math.sqrt(2.0) / meet
        truth[s] = (b, kind, value)
    eff = Effects(flicker=flicker, bias_drift=drift, rate_ramp=ramp)
    r = simulate(cert, still(DURATION, rate_hz=RATE), seed=seed, effects=eff)
    return truth, r.samples.gyro


@pytest.mark.parametrize("seed", SEEDS)
def test_long_term_component_beside_bias_instability_is_found(seed):
    truth, gyro = _record(seed)
    hidden = [s for s in GYROS if truth[s][1] != "none"]
    assert len(hidden) >= 2, truth  # the situation: a long-term term on some axes
    for c, s in enumerate(GYROS):
        b, kind, value = truth[s]
        sn = nm.select(gyro[:, c], RATE)
        cur = sn.curves()
        tau = np.asarray(cur["tau"])
        ratio = np.asarray(cur["ratio"])  # measured / predicted
        sup = nm.supported_taus(sn.allan, sn.window)
        # what the bias instability alone predicts (the model that missed on the ADIS16405)
        alone = nm.fit("bias_instability", sn.allan, sn.window)
        ratio_alone = np.asarray(cur["measured"]) / alone.adev(tau)
        entry = nm.report_entry(sn, "count")
        print(
            f"seed {seed} {s}: B {b:.3f} count, hidden {kind} {value:.4g}; chosen "
            f"{sn.model.name} { ({k: round(v, 4) for k, v in sn.model.terms.items()}) }; "
            f"supported {tau[sup].min():.1f}-{tau[sup].max():.0f} s, measured/predicted "
            f"{ratio[sup].min():.2f}-{ratio[sup].max():.2f} (B alone up to "
            f"{ratio_alone[sup].max():.2f}); at {tau[-1]:.0f} s {ratio[-1]:.2f} (B alone "
            f"{ratio_alone[-1]:.2f}); 95 % intervals {entry['terms_ci95']}"
        )
        assert sup.sum() >= 10 and tau[sup].max() >= 300.0
        assert np.all(np.abs(np.log(ratio[sup])) <= math.log(nm.MAX_RATIO)), (s, ratio[sup])
        if kind != "none" and np.any(np.abs(np.log(ratio_alone[sup])) > math.log(nm.MAX_RATIO)):
            # the bias instability alone misses where the record is measured: the model
            # must carry a long-term term, with its 95 % interval
            long = [t for t in sn.terms_named if t in LONG_TERMS]
            assert long, (s, sn.model.name)
            assert all(t in entry["terms_ci95"] for t in long)
