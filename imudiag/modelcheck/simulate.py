"""Simulate the recorded session with a model (the certificate's, or the extended one).

The motion is rebuilt from the data where it is quasi-static: every still run
is held at its measured gravity direction with zero rate, at the measured
temperature, sampled at the session's rate over exactly the chunks of the
first pass. :func:`imudiag.sim.simulate`'s streaming :class:`~imudiag.sim.Simulator`
then produces raw outputs with the model's white noise (the certificate's
density, or the one measured from the shortest-tau Allan deviation when the
certificate has none), its bias random walk, and, for the extended model,
the periodic lines and steps that a certificate cannot hold and the noise
terms the noise model names (quantisation, bias instability, random walk,
rate ramp, Gauss-Markov bias, with that model's white noise). Outputs are
quantised to the step seen in the data. The simulated segments go through the
same statistics as the measured ones.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from ..certificate import Certificate, Noise
from ..sim import BiasStep, Effects, PeriodicDisturbance, Simulator, Trajectory
from .spectral import Line
from .streams import Segments, SegmentStats
from .summaries import Session

SENSORS = ("gx", "gy", "gz", "ax", "ay", "az")


@dataclass
class NoiseModel:
    """What the simulation adds to a certificate's deterministic model (output units)."""

    density: np.ndarray  #: (6,) white noise, one-sided, output units / sqrt(Hz)
    walk: np.ndarray  #: (6,) bias random walk, output units / sqrt(s)
    lines: list[Line] = field(default_factory=list)
    steps: list[tuple[str, float, float]] = field(default_factory=list)  #: (sensor, t s, size)
    #: per sensor, the named noise model's terms (noisemodel.NoiseFit.terms, output units):
    #: its density replaces ``density`` there, and quantization Q (u s), bias_instability B
    #: (u), bias_drift K (u/sqrt(s), replaces ``walk``), rate_ramp R (u/s) and a
    #: Gauss-Markov bias (gauss_markov_sigma u, gauss_markov_time s) are simulated
    terms: dict[str, dict[str, float]] = field(default_factory=dict)


def with_noise(certificate: Certificate, density: np.ndarray) -> Certificate:
    """A copy of ``certificate`` whose noise densities are ``density`` (6,)."""
    cert = copy.deepcopy(certificate)
    for k, name in enumerate(("gyro", "accel")):
        tri = cert.triad(name)
        if tri.noise is None:
            tri.noise = Noise()
        tri.noise.density = np.asarray(density[3 * k : 3 * k + 3], dtype=float)
    return cert


def simulate_session(
    certificate: Certificate,
    noise: NoiseModel,
    session: Session,
    segments: Segments,
    chunk_input: np.ndarray,
    stats: SegmentStats,
    seed: int,
    halves: tuple[int, ...] = (0, 1),
) -> None:
    """Simulate the still segments of ``session`` and accumulate them into ``stats``.

    ``chunk_input`` (C, 3): the specific force of every chunk, accel input units.
    """
    c = session.chunks
    if len(c) == 0:
        return
    density = np.asarray(noise.density, dtype=float).copy()
    walk = np.asarray(noise.walk, dtype=float).copy()
    rate = session.rate_hz
    quantization: dict[str, float] = {}
    flicker: dict[str, float] = {}
    ramp: dict[str, float] = {}
    markov: dict[str, tuple[float, float]] = {}
    for s, terms in noise.terms.items():
        j = SENSORS.index(s)
        density[j] = terms.get("density", density[j])
        walk[j] = terms.get("bias_drift", walk[j])
        if terms.get("quantization", 0.0) > 0:  # steps of an integrating output, u
            quantization[s] = terms["quantization"] * rate * float(np.sqrt(12.0))
        if terms.get("bias_instability", 0.0) > 0:
            flicker[s] = terms["bias_instability"]
        if terms.get("rate_ramp", 0.0) > 0:
            ramp[s] = terms["rate_ramp"]
        if terms.get("gauss_markov_sigma", 0.0) > 0:
            markov[s] = (terms["gauss_markov_sigma"], terms["gauss_markov_time"])
    cert = with_noise(certificate, density)
    temp_profile = None
    if session.has_temp:
        tm, tv = c.t_mid, c.temp

        def temp_profile(t: np.ndarray) -> np.ndarray:
            return np.interp(t, tm, tv)

    effects = Effects(
        white_noise=True,
        bias_drift={s: float(k) for s, k in zip(SENSORS, walk, strict=True) if k > 0},
        temperature=temp_profile,
        temperature_reference=25.0,
        bias_step=[BiasStep(s, t, size) for s, t, size in noise.steps],
        periodic_disturbance=[
            PeriodicDisturbance(
                ln.sensor,
                ln.amplitude,
                ln.frequency,
                float(np.random.default_rng(seed + i).uniform(0, 2 * np.pi)),
            )
            for i, ln in enumerate(noise.lines)
        ],
        quantization=quantization,
        flicker=flicker,
        rate_ramp=ramp,
        bias_instability=markov,
    )
    sim = Simulator(cert, effects, seed=seed)
    f_si = chunk_input * cert.accel.unit_to_si
    quantum = session.quantum
    for seg in range(len(segments)):  # one simulator step per segment
        if int(segments.half[seg]) not in halves:
            continue
        ids = np.flatnonzero(segments.of_chunk == seg)
        counts = c.n[ids]
        chunk = np.repeat(ids, counts)
        offsets = np.concatenate([np.arange(k) for k in counts.tolist()])
        t = c.t_start[chunk] + offsets / rate
        n = t.shape[0]
        traj = Trajectory(
            t=t,
            omega=np.zeros((n, 3)),
            specific_force=f_si[chunk],
            attitude=np.broadcast_to(np.eye(3), (n, 3, 3)),
            static=np.ones(n, dtype=bool),
            rate_hz=rate,
        )
        block = sim.step(traj)
        u = np.concatenate([block.gyro, block.accel], axis=1)
        q = np.where(quantum > 0, quantum, 1.0)
        u = np.where(quantum > 0, np.round(u / q) * q, u)
        stats.add(
            block.t, u, block.temp if session.has_temp else None, chunk, int(segments.half[seg])
        )


__all__ = ["NoiseModel", "simulate_session", "with_noise"]
