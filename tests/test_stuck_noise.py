"""A frozen output is not a measure of noise (the still detector's data-driven noise).

A gyro axis frozen at t = 40 s of a 135-s multi-position session (``Fault("stuck")``)
drove the window diagnosis's measured noise of that axis to zero (its windows' variance
is zero, below every live window's 5 % quantile). From then on no window where the axis
was alive passed the variance test, and ``imudiag diagnose``, which feeds its detector the
whole session in one block, judged the samples before the freeze with that zero too: its
still samples before 40 s fell from 61 % to 30 %, it kept 6 intervals where the daemon
(0.5-s reads) kept 12, and it said the accelerometers were ``undetermined`` where the
daemon said ``ok`` (tests/test_one_answer.py ``session-stuck-gy``). Windows whose variance
on a channel is zero to the rounding of its sums are now left out of that channel's
quantile (:func:`imudiag.quasistatic.detector.flat_windows`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imudiag.certificate import load_default
from imudiag.quasistatic.detector import (
    QuasiStaticDetector,
    flat_ceiling,
    flat_windows,
    rounding_bound,
)
from imudiag.samples import SampleBlock
from imudiag.sim import Fault, multi_position, simulate

CERT = load_default()
TRAJ = multi_position(n_attitudes=30, dwell_s=3.0, turn_s=1.5, rate_hz=200, seed=41)


def _session(sensor: str | None, seed: int = 44) -> SampleBlock:
    faults = [Fault("stuck", sensor, 40.0, None)] if sensor else []
    return simulate(CERT, TRAJ, seed=seed, faults=faults).samples


def _detect(samples: SampleBlock, step: int) -> tuple[QuasiStaticDetector, np.ndarray]:
    det = QuasiStaticDetector(CERT, 200.0, certificate_noise=False)
    masks = [det.update(samples.slice(i, i + step)) for i in range(0, len(samples), step)]
    return det, np.concatenate(masks)


@pytest.mark.parametrize("sensor", ["gy", "az"])
@pytest.mark.parametrize("step", [65536, 100], ids=["one block", "0.5-s reads"])
def test_a_frozen_axis_keeps_its_measured_noise_and_the_stillness_before_it(sensor, step):
    """The frozen axis's noise stays its live figure (the certificate's, 65.5 and 8.2 counts,
    within 20 %), not zero, and the samples before the freeze are still exactly where the
    healthy unit's are (in one block too, which holds the frozen part)."""
    healthy = _session(None)
    frozen = _session(sensor)
    det, mask = _detect(frozen, step)
    _, healthy_mask = _detect(healthy, step)
    triad = "gyro" if sensor[0] == "g" else "accel"
    axis = "xyz".index(sensor[1])
    sigma = det.noise_sigma(triad)
    assert sigma is not None
    live = {"gyro": 65.5, "accel": 8.2}[triad]
    assert 0.8 * live < sigma[axis] < 1.2 * live, sigma
    before = frozen.t < 40.0
    assert np.mean(healthy_mask[before]) > 0.5
    assert np.mean(mask[before]) == pytest.approx(np.mean(healthy_mask[before]), abs=0.01)


def test_flat_windows_are_exactly_those_wholly_inside_a_frozen_run():
    """Counts-like outputs (offset 24 000, noise 60) and SI-like ones (9.8 m/s^2 +- 20,
    noise 1e-3), a run of 700 equal samples on one channel of each triad: exactly the
    windows wholly inside the run are flat, on that channel alone; blocks of every size."""
    rng = np.random.default_rng(7)
    n = 6000
    gyro = 24000.0 + 3000.0 * np.sin(np.arange(n)[:, None] / 400.0) + rng.normal(0, 60, (n, 3))
    accel = 9.8 + 20.0 * np.cos(np.arange(n)[:, None] / 300.0) + rng.normal(0, 1e-3, (n, 3))
    gyro[2000:2700, 1] = gyro[2000, 1]
    accel[4100:4800, 2] = accel[4100, 2]
    block = SampleBlock(t=np.arange(n) / 200.0, gyro=gyro, accel=accel)
    det = QuasiStaticDetector(CERT, 200.0, certificate_noise=False)
    w = det.window
    stage = det._stage  # the detector's own window statistics
    flat_rows = []
    for a, b in ((0, 1), (1, 1000), (1000, 1001), (1001, 4097), (4097, n)):
        st = stage.run(block.slice(a, b))
        if st.skip >= b - a:
            continue
        flags = np.hstack([flat_windows(st, w, slice(0, 3)), flat_windows(st, w, slice(3, 6))])
        for row, f in zip(st.idx, flags, strict=True):
            flat_rows.append((int(row), tuple(np.flatnonzero(f))))
    flat = {(r, c) for r, cols in flat_rows for c in cols}
    want = {(r, 1) for r in range(2000 + w - 1, 2700)} | {(r, 5) for r in range(4100 + w - 1, 4800)}
    assert flat == want


@pytest.mark.parametrize("seed", range(3))
def test_the_ceiling_bounds_every_window_also_across_the_shift_of_the_sums(seed):
    """:func:`flat_ceiling` is at least :func:`flat_windows`' bound of every window of the
    block, over a stream longer than 2^20 rows (the prefix sums shifted back to zero)."""
    rng = np.random.default_rng(seed)
    det = QuasiStaticDetector(CERT, 200.0, certificate_noise=False)
    w = det.window
    stage = det._stage
    done, total = 0, (1 << 20) + 150_000
    while done < total:
        k = int(rng.integers(1000, 200_000))
        t = (done + np.arange(k)) / 200.0
        level = rng.uniform(-5e4, 5e4, 6)
        swing = rng.uniform(0, 5e3, 6)
        x = level + swing * np.sin(t[:, None] / rng.uniform(1, 60, 6)) + rng.normal(0, 50, (k, 6))
        st = stage.run(SampleBlock(t=t, gyro=x[:, :3], accel=x[:, 3:]))
        done += k
        if st.skip >= k:
            continue
        ceiling = flat_ceiling(st, w, done)
        b1, b2 = np.abs(st.back_w[:, :6]), np.abs(st.back_w[:, 6:12])
        s1, s2 = np.abs(st.sums[:, :6]), np.abs(st.sums[:, 6:12])
        bound = rounding_bound(b1, b2, s1, s2, w)
        assert np.all(bound <= ceiling), (done, bound.max(axis=0), ceiling)
    assert done > 1 << 20


def test_an_output_frozen_from_the_start_gives_no_noise_figure_but_the_floor():
    """Nothing alive to measure: the axis's figure is the floor (as before), the others are
    measured, and the detector still judges the stream."""
    s = _session(None)
    gyro = s.gyro.copy()
    gyro[:, 0] = gyro[0, 0]
    det, mask = _detect(SampleBlock(t=s.t, gyro=gyro, accel=s.accel), 65536)
    sigma = det.noise_sigma("gyro")
    assert sigma is not None and sigma[0] < 1e-9 and 50.0 < sigma[1] < 80.0
    assert mask.any()


@pytest.mark.parametrize("triad", ["gyro", "accel"])
def test_a_stuck_output_drawn_at_random_gets_one_answer_from_both_faces(triad, tmp_path):
    """A sensor of each triad drawn under a seed freezes at 40 s: ``imudiag diagnose`` and
    the daemon (``replay://...?speed=0``) give the same verdicts and name the same faults,
    the drawn sensor's ``stuck`` among them. Before 2026-11-30 a frozen gx, gy or gz made
    diagnose say the accelerometers were ``undetermined`` where the daemon said ``ok``."""
    from imudiag.logs import open_writer
    from tests.helpers import named_faults, run_both_faces

    sensor = str(np.random.default_rng(35).choice([f"{triad[0]}{a}" for a in "xyz"]))
    log = tmp_path / f"stuck-{sensor}.npz"
    with open_writer(log, {"sample_rate": 200.0, "units": "gyro=count accel=count"}) as w:
        w.write(_session(sensor))
    both = run_both_faces(log, Path(__file__).parent.parent / "config" / "default-certificate.yaml")
    report, last = both["report"], both["lines"][-1]
    named = named_faults(report["verdict"]["faults"])
    assert (triad, sensor, "stuck") in named, (sensor, named)
    for t in ("accel", "gyro"):
        assert last["verdict"][t] == report["verdict"][t], (sensor, t)
    assert named_faults(last["verdict"]["faults"]) == named


def test_an_axis_without_a_noise_figure_leaves_its_triads_other_axes_measured(tmp_path):
    """``diagnose``'s noise section with a gyro axis frozen from the start (drawn under a
    seed): that axis's density is null and named ``unmeasured``, the triad's other two are
    measured (within 20 % of the certificate's), no ratio is judged on the triad, and the
    accelerometers' section is whole; the daemon's noise object says the same per axis.
    Before 2026-11-30 the one frozen axis blanked the whole triad's figures in ``diagnose``
    (``measured: null``) while the daemon kept the other two."""
    from imudiag.commands.noise import noise_lines
    from imudiag.logs import open_writer
    from tests.helpers import run_both_faces

    axis = int(np.random.default_rng(38).integers(3))
    sensor = "g" + "xyz"[axis]
    s = _session(None)
    gyro = s.gyro.copy()
    gyro[:, axis] = gyro[0, axis]
    log = tmp_path / f"frozen-{sensor}.npz"
    with open_writer(log, {"sample_rate": 200.0, "units": "gyro=count accel=count"}) as w:
        w.write(SampleBlock(t=s.t, gyro=gyro, accel=s.accel))
    both = run_both_faces(log, Path(__file__).parent.parent / "config" / "default-certificate.yaml")
    noise = both["report"]["noise"]
    g = noise["gyro"]
    density = g["measured"]["density"]
    assert g["unmeasured"] == [sensor], (sensor, g)
    assert not np.isfinite(density[axis])
    others = [d for i, d in enumerate(density) if i != axis]
    assert all(0.8 < d / 6.55 < 1.2 for d in others), density
    assert g["ratio"] is None and g["disagrees"] is None and g["certificate"] == [6.55] * 3
    assert noise["accel"]["disagrees"] is False and "unmeasured" not in noise["accel"]
    lines = noise_lines(noise)
    assert any(line.strip().startswith(f"{sensor}: no noise figure") for line in lines), lines
    live = both["lines"][-1]["noise"]["gyro"]["density"]
    assert [v is None for v in live] == [i == axis for i in range(3)], live
