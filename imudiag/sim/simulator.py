"""The simulated IMU: true motion in, raw sensor outputs out (the certificate's model + effects).

Per triad, with x the true input in the certificate's input unit (rad/s or
deg/s, m/s^2 or g) and T the board temperature (degC)::

    U = B + b_T(T) + diag(S (1 + s_T(T))) N(t) x + q (N x)^2 + G a   (gyros: G a, g-sensitivity)
        + bias faults + random walk + Gauss-Markov + bias steps + periodic + white noise

then saturation (clip, flag bits 0/1), quantisation, stuck/dead faults, ADC errors
(flag bit 2), dropped frames and time-stamp jitter. Time stamps are the device clock,
whole microseconds; the temperature is reported in 0.01 degC steps (as on the wire).

Everything is vectorised over a block of samples; a :class:`Simulator` carries its
state (random walks, Gauss-Markov states, stuck outputs, one random stream per
process) from block to block, so simulating in chunks gives exactly the samples of
one call.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from imudiag.certificate import (
    FLICKER_FACTOR,
    MISALIGNMENT_N_ENTRY,
    SENSOR_NAMES,
    Certificate,
    Noise,
    Temperature,
)
from imudiag.samples import (
    FLAG_ACCEL_SATURATED,
    FLAG_ADC_ERROR,
    FLAG_GYRO_SATURATED,
    SampleBlock,
)

from .effects import Effects, sensor_index
from .faults import Fault, apply_faults
from .processes import flicker_components, gauss_markov, random_walk
from .trajectories import Trajectory

#: (a new stream goes at the end: the earlier ones keep their numbers)
_STREAMS = ("white", "walk", "markov", "adc", "drop", "jitter", "flicker")
_DEFAULT_ADC_RANGE = (0.0, 65535.0)


@dataclass
class SimResult:
    """What :func:`simulate` returns.

    samples: raw outputs in the certificate's output units, with temp, flags and seq
    (seq = row of ``truth``; gaps where frames were dropped). truth: the true motion.
    certificate: the true model at the end of the session (faults active by then
    applied, representable effects written into the extended blocks).
    """

    samples: SampleBlock
    truth: Trajectory
    certificate: Certificate
    faults: tuple[Fault, ...] = ()
    effects: Effects = field(default_factory=Effects)
    nominal: Certificate | None = None  #: the certificate the simulation started from

    def certificate_at(self, t_s: float) -> Certificate:
        """The true model at time ``t_s`` (faults with fault.t_s <= t_s applied)."""
        base = self.nominal if self.nominal is not None else self.certificate
        return true_certificate(base, self.effects, self.faults, t_s, self.truth.rate_hz)


class Simulator:
    """Streaming simulator: feed consecutive trajectory chunks to :meth:`step`."""

    def __init__(
        self,
        certificate: Certificate,
        effects: Effects | None = None,
        faults: Iterable[Fault] = (),
        seed: int = 0,
        meta: dict | None = None,
    ) -> None:
        self.certificate = certificate
        self.effects = effects if effects is not None else Effects()
        self.faults = tuple(faults)
        for f in self.faults:
            f.columns  # noqa: B018 - validate sensor names early
        self.seed = int(seed)
        streams = np.random.SeedSequence(self.seed).spawn(len(_STREAMS))
        self._rng = {
            name: np.random.default_rng(s) for name, s in zip(_STREAMS, streams, strict=True)
        }
        self.n_done = 0
        self._walk = np.zeros(6)
        e = self.effects
        self._walk_k = Effects.per_sensor(e.bias_drift)
        self._gm_sigma = np.zeros(6)
        self._gm_tau = np.full(6, np.inf)
        for s, (sigma, tau) in e.bias_instability.items():
            if sigma < 0 or tau <= 0:
                raise ValueError(f"bias_instability[{s}]: need sigma >= 0 and tau > 0 s")
            self._gm_sigma[sensor_index(s)] = sigma
            self._gm_tau[sensor_index(s)] = tau
        # stationary start of the Gauss-Markov states
        self._gm_state = self._gm_sigma * self._rng["markov"].standard_normal(6)
        # flicker floors: per sensor a sum of Gauss-Markov processes (sigma_k, T_k)
        self._flicker: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]] = []
        if e.flicker:
            tc, w = flicker_components(e.flicker_band)
            for sname, b in sorted(e.flicker.items(), key=lambda kv: sensor_index(kv[0])):
                if b < 0:
                    raise ValueError(f"flicker[{sname}]: need B >= 0, got {b}")
                sig = FLICKER_FACTOR * b * np.sqrt(w)
                state = sig * self._rng["flicker"].standard_normal(tc.shape[0])
                self._flicker.append((sensor_index(sname), sig, tc, state))
        self._ramp = Effects.per_sensor(e.rate_ramp)
        self._quant_step = Effects.per_sensor(e.quantization)
        self._quant_carry = np.zeros(6)  #: accumulated output not yet emitted, u samples
        self._stuck_hold: dict[int, float] = {}
        self.meta = dict(meta or {})
        self._meta_rate: float | None = None

    # -- model pieces --------------------------------------------------------

    def _sigma(self, rate_hz: float) -> np.ndarray:
        out = np.zeros(6)
        for k, name in enumerate(("gyro", "accel")):
            s = self.certificate.triad(name).noise_sigma(rate_hz)
            if s is not None:
                out[3 * k : 3 * k + 3] = s
        return out

    def _deterministic(self, traj: Trajectory, temp: np.ndarray) -> np.ndarray:
        """Noise-free outputs (N, 6) of the certificate model, effects and parameter faults."""
        cert, e, t = self.certificate, self.effects, traj.t
        n = len(traj)
        out = np.empty((n, 6))
        x_in = {
            "gyro": traj.omega / cert.gyro.unit_to_si,
            "accel": traj.specific_force / cert.accel.unit_to_si,
        }
        t_bias = Effects.per_sensor(e.temperature_bias)
        t_scale = Effects.per_sensor(e.temperature_scale)
        q_eff = Effects.per_sensor(e.scale_nonlinearity)
        d_eff = temp - e.temperature_reference
        for k, name in enumerate(("gyro", "accel")):
            tri = cert.triad(name)
            cols = slice(3 * k, 3 * k + 3)
            x = x_in[name]
            nx = x @ tri.n_matrix().T
            for f in self.faults:
                if f.triad != name or f.kind not in ("scale_factor", "misalignment"):
                    continue
                dn = np.zeros((3, 3))
                if f.kind == "scale_factor":
                    j = f.columns[0] % 3
                    dn[j, j] = f.amount / tri.scale_factor[j]
                else:
                    r, c, sign = MISALIGNMENT_N_ENTRY[f.pair_key[1]]
                    dn[r, c] = sign * f.amount
                active = t >= f.t_s
                if np.any(active):
                    nx[active] += x[active] @ dn.T
            bias = tri.bias + t_bias[cols] * d_eff[:, None]
            rel_scale = 1.0 + t_scale[cols] * d_eff[:, None]
            if tri.temperature is not None:
                d_cert = (temp - tri.temperature.reference)[:, None]
                bias = bias + tri.temperature.bias_coefficient * d_cert
                rel_scale = rel_scale + tri.temperature.scale_coefficient * d_cert
            u = bias + tri.scale_factor * rel_scale * nx
            q = q_eff[cols] + (tri.nonlinearity if tri.nonlinearity is not None else 0.0)
            if np.any(q):
                u = u + q * nx**2
            if name == "gyro":
                g = np.zeros((3, 3))
                if tri.g_sensitivity is not None:
                    g = g + tri.g_sensitivity
                if e.g_sensitivity is not None:
                    g = g + e.g_sensitivity
                if np.any(g):
                    u = u + x_in["accel"] @ g.T
            out[:, cols] = u
        for f in self.faults:
            if f.kind == "bias":
                out[t >= f.t_s, f.columns[0]] += f.value
        for s in e.bias_step:
            out[t >= s.t_s, sensor_index(s.sensor)] += s.size
        if np.any(self._ramp):
            out += t[:, None] * self._ramp
        for p in e.periodic_disturbance:
            out[:, sensor_index(p.sensor)] += p.amplitude * np.sin(
                2.0 * math.pi * p.frequency_hz * t + p.phase_rad
            )
        return out

    def _drift(self, n: int, dt: float) -> np.ndarray | None:
        """Random walk plus Gauss-Markov bias (N, 6), or None when both are off."""
        total = None
        if np.any(self._walk_k):
            inc = self._rng["walk"].standard_normal((n, 6)) * (self._walk_k * math.sqrt(dt))
            walk, self._walk = random_walk(inc, self._walk)
            total = walk
        if np.any(self._gm_sigma):
            xi = self._rng["markov"].standard_normal((n, 6))
            gm = np.zeros((n, 6))
            for j in np.flatnonzero(self._gm_sigma).tolist():
                a = math.exp(-dt / self._gm_tau[j])
                drive = xi[:, j] * (self._gm_sigma[j] * math.sqrt(1.0 - a * a))
                gm[:, j] = gauss_markov(drive, a, self._gm_state[j])
                if n:
                    self._gm_state[j] = gm[-1, j]
            total = gm if total is None else total + gm
        if self._flicker:
            fl = np.zeros((n, 6))
            for j, sig, tc, state in self._flicker:
                xi = self._rng["flicker"].standard_normal((n, tc.shape[0]))
                for k in range(tc.shape[0]):  # a dozen components per sensor
                    a = math.exp(-dt / tc[k])
                    x = gauss_markov(xi[:, k] * (sig[k] * math.sqrt(1.0 - a * a)), a, state[k])
                    if n:
                        state[k] = x[-1]
                    fl[:, j] += x
            total = fl if total is None else total + fl
        return total

    # -- one block -------------------------------------------------------------

    def step(self, traj: Trajectory) -> SampleBlock:
        """Raw outputs for the next ``len(traj)`` samples (rows continue the previous call)."""
        n = len(traj)
        e = self.effects
        rate = float(traj.rate_hz)
        dt = 1.0 / rate
        t = traj.t
        seq = self.n_done + np.arange(n, dtype=np.int64)
        self.n_done += n

        temp_true = (
            np.asarray(e.temperature(t), dtype=float)
            if e.temperature is not None
            else np.full(n, e.temperature_reference)
        )
        temp = np.round(temp_true * 100.0) * 0.01  # the board reports 0.01 degC
        u = self._deterministic(traj, temp_true)
        drift = self._drift(n, dt)
        if drift is not None:
            u += drift

        sigma = self._sigma(rate) * e.noise_scale
        noise_faults = [f for f in self.faults if f.kind == "noise"]
        if (e.white_noise and np.any(sigma)) or noise_faults:
            xi = self._rng["white"].standard_normal((n, 6))
            scale = np.tile(sigma if e.white_noise else np.zeros(6), (n, 1))
            for f in noise_faults:
                j = f.columns[0]
                scale[t >= f.t_s, j] = sigma[j] * f.value
            u += xi * scale

        if np.any(self._quant_step) and n:
            u = self._quantize_integrated(u)
        flags = np.zeros(n, dtype=np.uint16)
        if e.quantize:
            u = np.round(u)
        for k, (name, bit) in enumerate(
            (("gyro", FLAG_GYRO_SATURATED), ("accel", FLAG_ACCEL_SATURATED))
        ):
            rng_ = e.saturation_range(name)
            if rng_ is None:
                continue
            cols = slice(3 * k, 3 * k + 3)
            over = np.any((u[:, cols] < rng_[0]) | (u[:, cols] > rng_[1]), axis=1)
            flags[over] |= bit
            u[:, cols] = np.clip(u[:, cols], rng_[0], rng_[1])

        for idx, f in enumerate(self.faults):
            if f.kind not in ("stuck", "dead"):
                continue
            j = f.columns[0]
            active = t >= f.t_s
            if not np.any(active):
                continue
            if f.kind == "dead":
                value = 0.0 if f.value is None else f.value
            else:
                if idx not in self._stuck_hold:
                    self._stuck_hold[idx] = (
                        float(u[np.argmax(active), j]) if f.value is None else float(f.value)
                    )
                value = self._stuck_hold[idx]
            u[active, j] = np.round(value) if e.quantize else value

        if e.adc_error_rate > 0:
            r = self._rng["adc"].random((n, 3))
            bad = np.flatnonzero(r[:, 0] < e.adc_error_rate)
            if bad.size:
                ch = np.minimum((r[bad, 1] * 6).astype(int), 5)
                lo_hi = np.array([self._adc_range("gyro"), self._adc_range("accel")])
                lo = lo_hi[(ch >= 3).astype(int), 0]
                hi = lo_hi[(ch >= 3).astype(int), 1]
                val = lo + r[bad, 2] * (hi - lo)
                u[bad, ch] = np.round(val) if e.quantize else val
                flags[bad] |= FLAG_ADC_ERROR

        t_out = t.copy()
        if e.jitter_s > 0:
            jit = self._rng["jitter"].standard_normal(n) * e.jitter_s
            t_out = t_out + np.clip(jit, -0.45 * dt, 0.45 * dt)
        # device clock: whole microseconds from 0 (as the wire decoder rebuilds it)
        t_out = np.maximum(np.round(t_out * 1e6), 0.0) * 1e-6

        keep: slice | np.ndarray = slice(None)
        if e.drop_rate > 0:
            keep = self._rng["drop"].random(n) >= e.drop_rate
        meta = self.meta
        if self._meta_rate != rate:
            meta.setdefault("sample_rate", rate)
            self._meta_rate = rate
        return SampleBlock(
            t=t_out[keep],
            gyro=u[keep, :3],
            accel=u[keep, 3:],
            temp=temp[keep],
            flags=flags[keep],
            seq=seq[keep],
            meta=meta,
        )

    def _quantize_integrated(self, u: np.ndarray) -> np.ndarray:
        """Outputs as increments of the accumulated output rounded to the sensor's step q
        (output units), the remainder carried to the next sample: the error is the first
        difference of a uniform rounding error, IEEE 952 quantisation Q = q / (rate sqrt(12))."""
        out = u.copy()
        for j in np.flatnonzero(self._quant_step).tolist():
            q = float(self._quant_step[j])
            base = q * math.floor(u[0, j] / q)  # a multiple of q: keeps the sums small
            acc = self._quant_carry[j] + np.cumsum(u[:, j] - base)
            levels = q * np.round(acc / q)
            out[:, j] = base + np.diff(levels, prepend=0.0)
            self._quant_carry[j] = acc[-1] - levels[-1]
        return out

    def _adc_range(self, triad: str) -> tuple[float, float]:
        r = self.effects.saturation_range(triad)
        return r if r is not None else _DEFAULT_ADC_RANGE


def true_certificate(
    certificate: Certificate,
    effects: Effects,
    faults: Sequence[Fault],
    t_s: float,
    rate_hz: float | None = None,
) -> Certificate:
    """The model the simulation follows at ``t_s``: faults applied, representable effects
    (temperature, nonlinearity, g-sensitivity, bias drift, noise terms) written in; the
    quantisation Q (u s) of a step needs the sample rate ``rate_hz`` (Hz)."""
    cert = apply_faults(certificate, faults, t_s)
    e = effects
    for k, name in enumerate(("gyro", "accel")):
        tri = cert.triad(name)
        cols = slice(3 * k, 3 * k + 3)
        tb = Effects.per_sensor(e.temperature_bias)[cols]
        ts = Effects.per_sensor(e.temperature_scale)[cols]
        if np.any(tb) or np.any(ts):
            if tri.temperature is None:
                tri.temperature = Temperature(reference=e.temperature_reference)
            shift = tri.temperature.reference - e.temperature_reference
            tri.bias = tri.bias + tb * shift
            k_scale = 1.0 + ts * shift
            tri.scale_factor = tri.scale_factor * k_scale
            tri.scale_factor_error = tri.scale_factor_error * k_scale
            tri.temperature.bias_coefficient = tri.temperature.bias_coefficient + tb
            tri.temperature.scale_coefficient = (tri.temperature.scale_coefficient + ts) / k_scale
        q = Effects.per_sensor(e.scale_nonlinearity)[cols]
        if np.any(q):
            tri.nonlinearity = q + (tri.nonlinearity if tri.nonlinearity is not None else 0.0)
        if name == "gyro" and e.g_sensitivity is not None:
            base = tri.g_sensitivity if tri.g_sensitivity is not None else np.zeros((3, 3))
            tri.g_sensitivity = base + e.g_sensitivity
        walk = Effects.per_sensor(e.bias_drift)[cols]
        if tri.noise is None:
            tri.noise = Noise()
        if tri.noise.density is not None:
            tri.noise.density = tri.noise.density * (e.noise_scale if e.white_noise else 0.0)
        tri.noise.bias_random_walk = walk
        gm = [e.bias_instability.get(s) for s in SENSOR_NAMES[name]]
        if any(g is not None for g in gm):
            tri.noise.gauss_markov_sigma = np.array([0.0 if g is None else g[0] for g in gm])
            tri.noise.gauss_markov_time = np.array([1.0 if g is None else g[1] for g in gm])
        flick = Effects.per_sensor(e.flicker)[cols]
        if np.any(flick):
            tri.noise.bias_instability = flick
        ramp = Effects.per_sensor(e.rate_ramp)[cols]
        if np.any(ramp):
            tri.noise.rate_ramp = np.abs(ramp)
        step = Effects.per_sensor(e.quantization)[cols]
        if np.any(step) and rate_hz is not None:
            tri.noise.quantization = step / (rate_hz * math.sqrt(12.0))
    return cert


def simulate(
    certificate: Certificate,
    trajectory: Trajectory,
    seed: int = 0,
    effects: Effects | None = None,
    faults: Iterable[Fault] = (),
) -> SimResult:
    """Simulate the raw outputs of a board with ``certificate``'s model along ``trajectory``.

    ``effects`` defaults to white noise only (``Effects()``); ``faults`` are injected at
    their times. Reproducible: the same seed gives the same samples.
    """
    effects = effects if effects is not None else Effects()
    faults = tuple(faults)
    meta = {
        "sample_rate": float(trajectory.rate_hz),
        "device": str(certificate.device.get("model", "simulated IMU")),
        "source": f"imudiag simulate seed={int(seed)}",
    }
    sim = Simulator(certificate, effects, faults, seed, meta=meta)
    block = sim.step(trajectory)
    t_end = float(trajectory.t[-1]) if len(trajectory) else 0.0
    return SimResult(
        samples=block,
        truth=trajectory,
        certificate=true_certificate(certificate, effects, faults, t_end, trajectory.rate_hz),
        faults=faults,
        effects=effects,
        nominal=certificate,
    )
