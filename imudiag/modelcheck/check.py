"""The model check of a recorded session against a certificate (spec/reports.md).

1. First pass (:mod:`.summaries`): quasi-static chunks, streamed.
2. Residuals of the chunk means against the certificate's model
   (:mod:`.residuals`), and for every catalogue effect a test with a
   significance and a held-out gain (:mod:`.detectors`).
3. Second pass (:mod:`.streams`): full-rate Allan deviation, spectrum and F0 of
   the quasi-static samples; spectral lines (:mod:`.spectral`).
4. Simulation of the session with the certificate's model and with the
   extended one (:mod:`.simulate`), compared with the measurement.
5. The extended certificate and the held-out metrics (:mod:`.extend`).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..certificate import Certificate, TriadModel
from ..noise_estimate import METHOD as WHITE_NOISE_METHOD
from ..reports import MODEL_CHECK_FORMAT, header
from ..samples import SampleBlock
from ..units import Conversion, conform_meta
from .config import ModelCheckConfig
from .detectors import ChannelResult, analyse_channel, k_on_rows
from .extend import (
    GAIN_DEFINITION,
    HELDOUT_LOGLIK_KEY,
    Effect,
    accel_folds,
    allan_misfit,
    collect_effects,
    extended_certificate,
    f0_checks,
    f0_rate,
    predictor,
    ratio,
    residual_rms,
    rotation_rms,
)
from .noisemodel import (
    MIN_RUN_S,
    NoNoiseSeen,
    SensorNoise,
    longest_run,
    report_entry,
    run_samples,
    select,
)
from .residuals import (
    SENSORS,
    Channel,
    accel_effect_specs,
    build_channels,
    chunk_accel_input,
    distinct_attitudes,
    norm_and_gradient,
    refit_accel,
    run_up,
    temperature_reference,
    white_variance,
    with_effects,
)
from .rotations import (
    MIN_TURNS,
    MotionCollector,
    motion_windows,
    reduce_motion,
    rotation_channel,
    usable_pairs,
)
from .simulate import NoiseModel, simulate_session
from .spectral import Line, find_lines
from .streams import F0Check, Segments, SegmentStats, allan_m_grid, make_segments, stream_measured
from .summaries import (
    DEFAULT_BLOCK_SIZE,
    BlockSource,
    ProgressCallback,
    Session,
    block_source,
    collect,
)

FORMAT = MODEL_CHECK_FORMAT
ALL_SENSORS = SENSORS["gyro"] + SENSORS["accel"]
CATALOGUE = (
    "quantization",
    "bias_drift",
    "bias_instability",
    "gauss_markov_bias",
    "rate_ramp",
    "temperature_bias",
    "temperature_scale",
    "g_sensitivity",
    "scale_nonlinearity",
    "bias_step",
    "periodic_disturbance",
)


@dataclass
class ModelCheckResult:
    """The report and what produced it."""

    report: dict[str, Any]
    effects: list[Effect]
    extended: Certificate
    session: Session
    channels: list[ChannelResult] = field(default_factory=list)
    measured: SegmentStats | None = None
    simulated: dict[str, list[SegmentStats]] = field(default_factory=dict)
    lines: list[Line] = field(default_factory=list)


def _chunk_residual(
    certificate: Certificate,
    accel: TriadModel,
    means: np.ndarray,
    temp: np.ndarray | None,
    a_in: np.ndarray,
) -> np.ndarray:
    """(C, 4) residuals gx gy gz (output units) and accel norm (input units) of chunk means."""
    gyro = certificate.gyro
    pred = gyro.forward(
        np.zeros((means.shape[0], 3)),
        temp_c=temp,
        accel_input=a_in if gyro.g_sensitivity is not None else None,
    )
    g_in = certificate.gravity / accel.unit_to_si
    _x, norm, _g = norm_and_gradient(accel, means[:, 3:6], temp)
    return np.concatenate([means[:, :3] - pred, (norm - g_in)[:, None]], axis=1)


def _stats(
    session: Session,
    config: ModelCheckConfig,
    segments: Segments,
    predictors: dict,
    checks: list[F0Check],
    cert: Certificate,
) -> SegmentStats:
    longest = int(segments.n.max()) if len(segments) else 0
    rate = session.rate_hz
    nper = 0
    if len(segments):
        typical = int(np.median(segments.n))
        nper = 1 << int(math.floor(math.log2(max(min(typical, config.psd_max_segment), 1))))
        if nper < config.psd_min_segment:
            nper = 0
    return SegmentStats(
        m=allan_m_grid(longest, config.allan_points_per_decade),
        rate_hz=rate,
        nperseg=nper,
        n_chunks=len(session.chunks),
        predictors=predictors,
        f0_checks=checks,
        gravity_in=cert.gravity / cert.accel.unit_to_si,
        f0_limit=cert.accel.limits.f0,
    )


def _f0_summary(check: F0Check | None) -> dict[str, Any] | None:
    if check is None or check.checked == 0:
        return None
    n = check.checked
    mean = check.total / n
    return {
        "samples": n,
        "false_alarm_rate": check.failed / n,
        "mean": mean,
        "std": math.sqrt(max(check.total_sq / n - mean * mean, 0.0)),
        "p01": check.quantile(0.01),
        "p99": check.quantile(0.99),
    }


def _round(x: Any, digits: int = 6) -> Any:
    """Round floats in nested structures to ``digits`` significant digits (JSON size)."""
    if isinstance(x, float):
        if not math.isfinite(x):
            return None
        return float(f"{x:.{digits}g}")
    if isinstance(x, dict):
        return {k: _round(v, digits) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_round(v, digits) for v in x]
    if isinstance(x, np.generic):
        return _round(x.item(), digits)
    if isinstance(x, np.ndarray):
        return _round(x.tolist(), digits)
    return x


def _empty_metrics() -> dict[str, Any]:
    return {
        "residual_rms": {"gyro": None, "accel": None},
        "f0_false_alarm_rate": {"gyro": None, "accel": None},
        "allan_misfit": {"gyro": None, "accel": None},
    }


def _converted(source: BlockSource, units: Conversion) -> BlockSource:
    """``source`` whose every pass yields blocks in the certificate's units."""

    def again() -> Iterator[SampleBlock]:
        return (units.apply(block) for block in source())

    return again


def model_check(
    log: str | Path | SampleBlock | BlockSource,
    certificate: Certificate,
    seed: int = 0,
    config: ModelCheckConfig | None = None,
    block_size: int = DEFAULT_BLOCK_SIZE,
    progress: ProgressCallback | None = None,
) -> ModelCheckResult:
    """Run the model check of ``log`` (a path, a block, or a re-startable block source);
    a log is read ``block_size`` samples at a time (three passes); ``progress`` is told
    how far each pass has got (a path or a block). The steps of the module doc, in order."""
    cfg = config or ModelCheckConfig()
    source, meta = block_source(log, block_size, progress)
    where = str(log) if isinstance(log, (str, Path)) else "(samples)"
    conversion = conform_meta(meta, certificate, where)  # exact, or refused (imudiag.units)
    if not conversion.identity:
        source = _converted(source, conversion)
    session = collect(source, certificate, cfg, meta)
    base_report = _base_report(log, certificate, session, conversion)
    if len(session.chunks) < 6:
        return _too_little_data(base_report, certificate, session)
    out_units = {"gyro": certificate.gyro.output_unit, "accel": certificate.accel.output_unit}
    chunk = _chunk_tests(certificate, session, cfg, out_units)
    models = _models(certificate, session, cfg, chunk)
    c = session.chunks

    # -- second pass over the measurement; gyro scale effects from the turns between runs ---
    measured, pairs, rot_ch, rot_res = _second_pass(
        source, certificate, session, cfg, chunk, models
    )
    results, det_effects = chunk.results, chunk.det_effects  # with the gyro scale's found
    density_meas, cert_density, density_model = _densities(certificate, session, measured)

    # -- spectral lines: fitted on the first half, confirmed on the second -----------------------
    lines, line_tests, psd_untestable = _spectral_lines(measured, session, cfg)
    effects = det_effects + collect_effects(
        [], lines, c.t_start, c.t_end, c.run, chunk.half_y, out_units
    )

    # -- the noise model the longest still run supports (Allan, whole run, held-out choice) ----
    noise_section, noise_fits = _noise_model(source, c, session.rate_hz, cfg, out_units)
    effects = _noise_effects(effects, noise_fits, out_units)

    # -- noise models: certificate's, and extended (walk and lines fitted on the first half) ---
    noise_base, noise_ext = _noise_models(
        certificate, session, results, effects, noise_fits, density_model, lines, models
    )

    # -- simulations (common random numbers: the same seeds for both models) ------------------
    sims = _simulations(
        certificate, session, cfg, models, chunk.accel_w, noise_base, noise_ext, effects, seed
    )

    base_m, ext_m, gain, units = _metrics(
        certificate, results, rot_res, models, measured, sims, effects
    )

    extended = _extended(
        certificate, effects, cert_density, density_meas, models, noise_fits, noise_section
    )

    # -- comparison: measurement against the simulation of the certificate's model -------------
    comparison = _comparison(
        certificate,
        chunk.accel_w,
        session,
        measured,
        sims,
        chunk.a_in,
        chunk.temp,
        density_meas,
        cert_density,
    )
    tested = _tested(results, line_tests)
    report = dict(base_report)
    report.update(
        {
            "quasi_static": _quasi_static_section(session, models, pairs, rot_ch),
            "effects": [e.as_dict() for e in sorted(effects, key=lambda e: -e.significance)],
            "baseline": base_m,
            "extended": ext_m,
            "gain": gain,
            "units": units,
            "evaluation": _evaluation(session, cfg, models),
            "comparison": comparison,
            "noise_model": noise_section,
            "tested": sorted(tested, key=lambda d: -float(d.get("significance", 0.0))),
            "untestable": _untestable(results, rot_ch, pairs, cfg, psd_untestable),
        }
    )
    return ModelCheckResult(
        report=_round(report),
        effects=effects,
        extended=extended,
        session=session,
        channels=results,
        measured=measured,
        simulated=sims,
        lines=lines,
    )


def _densities(
    certificate: Certificate, session: Session, measured: SegmentStats
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """White-noise densities (6,), output units / sqrt(Hz): measured on the quasi-static
    samples, the certificate's (NaN where it has none), and the model's (the certificate's,
    else the measured)."""
    sigma_meas = measured.sample_sigma()
    density_meas = sigma_meas / math.sqrt(session.rate_hz / 2.0)
    cert_density = np.concatenate([_density(certificate.triad(n)) for n in ("gyro", "accel")])
    density_model = np.where(np.isfinite(cert_density), cert_density, density_meas)
    return density_meas, cert_density, density_model


def _extended(
    certificate: Certificate,
    effects: list[Effect],
    cert_density: np.ndarray,
    density_meas: np.ndarray,
    models: _Models,
    noise_fits: dict[str, SensorNoise],
    noise_section: dict[str, Any] | None,
) -> Certificate:
    """Step 5: the certificate extended with the effects found (the measured noise density
    where the certificate has none) and the named noise models; ``noise_section`` is told
    what the extended certificate predicts."""
    missing = None if np.all(np.isfinite(cert_density)) else density_meas
    extended = extended_certificate(certificate, effects, missing, models.refs)
    _write_noise_model(extended, noise_fits)
    if noise_section is not None:
        _predicted_by_extended(noise_section, extended)
    return extended


def _base_report(
    log: str | Path | SampleBlock | BlockSource,
    certificate: Certificate,
    session: Session,
    conversion: Conversion,
) -> dict[str, Any]:
    """The report's head: format, log, certificate, samples, duration (s), rate (Hz)."""
    base_report: dict[str, Any] = {
        **header(FORMAT),
        "log": str(log) if isinstance(log, (str, Path)) else None,
        "certificate": certificate.source,
        "samples": session.samples,
        "duration_s": session.duration_s,
        "sample_rate": session.rate_hz,
    }
    if not conversion.identity:
        base_report["unit_conversion"] = conversion.describe()
    return base_report


def _too_little_data(
    base_report: dict[str, Any], certificate: Certificate, session: Session
) -> ModelCheckResult:
    """The result of a session with fewer than 6 quasi-static chunks: every effect
    untestable."""
    c = session.chunks
    report = dict(base_report)
    report.update(
        {
            "quasi_static": {
                "samples": session.static_samples,
                "chunks": len(c),
                "runs": int(len(session.runs)),
                "s": round(session.static_samples / session.rate_hz, 3),
            },
            "effects": [],
            "baseline": _empty_metrics(),
            "extended": _empty_metrics(),
            "gain": _empty_metrics(),
            "untestable": [
                {
                    "name": n,
                    "triad": t,
                    "sensor": s,
                    "reason": "too little quasi-static data (needs a few seconds still)",
                }
                for n in CATALOGUE
                for t in ("gyro", "accel")
                for s in SENSORS[t]
                if not (n == "g_sensitivity" and t == "accel")
            ],
        }
    )
    return ModelCheckResult(
        report=_round(report), effects=[], extended=certificate, session=session
    )


@dataclass
class _ChunkTests:
    """Step 2 of the module doc: the chunk residuals' tests and what they rest on."""

    results: list[ChannelResult]  #: each channel's tests
    accel_w: TriadModel  #: the accelerometer model re-fitted with its effects
    sigma2: np.ndarray  #: white-noise variance of the chunk means
    a_in: np.ndarray  #: each chunk's accelerometer input (input units)
    half_y: dict[str, np.ndarray]  #: residuals of each chunk's two halves, per sensor
    det_effects: list[Effect]  #: the effects the chunk tests found
    temp: np.ndarray | None  #: each chunk's temperature (deg C), None without
    out_units: dict[str, str]  #: each triad's output unit


def _chunk_tests(
    certificate: Certificate, session: Session, cfg: ModelCheckConfig, out_units: dict[str, str]
) -> _ChunkTests:
    """Residuals of the chunk means against the certificate's model and a test per
    catalogue effect."""
    c = session.chunks
    sigma2 = white_variance(session)
    accel_w, _v = refit_accel(certificate, session, sigma2)
    channels = build_channels(certificate, session, cfg, accel_w, sigma2)
    results = [analyse_channel(ch, cfg) for ch in channels]
    temp = c.temp if session.has_temp else None
    results, accel_w = _refine_accel(results, certificate, accel_w, session, cfg, sigma2)
    a_in = chunk_accel_input(accel_w, session)
    half_y: dict[str, np.ndarray] = {}
    halves = []
    for k in range(2):
        means = np.concatenate([c.gyro_half[:, k], c.accel_half[:, k]], axis=1)
        halves.append(_chunk_residual(certificate, accel_w, means, temp, a_in))
    for j, s in enumerate(SENSORS["gyro"]):
        half_y[s] = np.stack([halves[0][:, j], halves[1][:, j]], axis=1)
    half_y["accel"] = np.stack([halves[0][:, 3], halves[1][:, 3]], axis=1)
    det_effects = collect_effects(results, [], c.t_start, c.t_end, c.run, half_y, out_units)
    return _ChunkTests(results, accel_w, sigma2, a_in, half_y, det_effects, temp, out_units)


@dataclass
class _Models:
    """The baseline and extended models the measurement and the simulations are scored on."""

    refs: dict[str, float]  #: each triad's temperature reference (deg C)
    ups: dict[int, np.ndarray]  #: each still run's up direction
    chunk_input: np.ndarray  #: each chunk's accelerometer input (input units)
    steps: list[tuple[str, float, float]]  #: bias steps found: sensor, t (s), value
    ext_det: Certificate  #: the certificate extended with the effects found
    ext_accel_w: TriadModel  #: its accelerometer, from the re-fitted one
    predictors: dict[str, Any]  #: the chunk predictors of each model
    folds: dict[str, Any]  #: the accelerometer's two folds per model
    checks: list[F0Check]  #: the F0 checks scored on the measurement
    t_half: float  #: the session's middle (s): noise fitted before, scored after
    segments: Segments  #: the quasi-static segments of the second pass


def _models(
    certificate: Certificate, session: Session, cfg: ModelCheckConfig, chunk: _ChunkTests
) -> _Models:
    """The baseline (the certificate's) and the extended model (with the effects found)."""
    c = session.chunks
    accel_w = chunk.accel_w
    refs = {n: temperature_reference(certificate.triad(n), cfg) for n in ("gyro", "accel")}
    ups = run_up(accel_w, session)
    g_in = certificate.gravity / certificate.accel.unit_to_si
    chunk_input = np.array([ups[int(r)] for r in c.run]) * g_in
    steps = [
        (e.sensor, float(e.extra["t"]), float(e.value))  # type: ignore[arg-type]
        for e in chunk.det_effects
        if e.name == "bias_step"
    ]
    ext_det = extended_certificate(certificate, chunk.det_effects, None, refs)
    ext_accel_w = extended_certificate(
        _with_accel(certificate, accel_w), chunk.det_effects, None, refs
    ).accel
    predictors = {
        "baseline": predictor(certificate.gyro, accel_w, chunk_input, []),
        "extended": predictor(ext_det.gyro, ext_accel_w, chunk_input, steps),
    }
    accel_res = next((r for r in chunk.results if r.channel.triad == "accel"), None)
    folds = {}
    if accel_res is not None and len(accel_res.channel) >= 4:
        folds = {
            name: accel_folds(certificate, session, chunk.sigma2, accel_res, refs["accel"], ext)
            for name, ext in (("baseline", False), ("extended", True))
        }
    checks = f0_checks(folds)
    checks.append(F0Check(name="certificate", model=certificate.accel, parity=None))
    t_half = float(np.median(c.t_mid))
    max_seg = int(cfg.max_segment_s * session.rate_hz)
    segments = make_segments(c, t_half, max_seg)
    return _Models(
        refs, ups, chunk_input, steps, ext_det, ext_accel_w, predictors, folds, checks, t_half,
        segments,
    )  # fmt: skip


def _second_pass(
    source: BlockSource,
    certificate: Certificate,
    session: Session,
    cfg: ModelCheckConfig,
    chunk: _ChunkTests,
    models: _Models,
) -> tuple[SegmentStats, list[Any], Channel | None, ChannelResult | None]:
    """Step 3: the measurement's full-rate statistics on the quasi-static segments, and
    the turns between still runs with the gyro scale channel they make (None: too few),
    whose tests and effects join ``chunk``'s."""
    c = session.chunks
    measured = _stats(session, cfg, models.segments, models.predictors, models.checks, certificate)
    g_named = models.ext_det.gyro.g_sensitivity  # the certificate's and the named, or None
    motion = MotionCollector(
        motion_windows(c, cfg.max_motion_s),
        reduce=lambda w: reduce_motion(
            w,
            certificate,
            chunk.accel_w,
            c,
            g_named,
            chunk.sigma2,
            models.refs["gyro"],
            3.0 / session.rate_hz,
        ),
    )
    stream_measured(source(), c, models.segments, measured, motion)
    t_span = float(np.nanmax(c.temp) - np.nanmin(c.temp)) if session.has_temp else 0.0
    pairs = motion.pairs
    rot_ch = rotation_channel(
        pairs, certificate, cfg, session.has_temp, t_span, models.refs["gyro"]
    )
    rot_res = analyse_channel(rot_ch, cfg) if rot_ch is not None else None
    if rot_res is not None:
        chunk.results.append(rot_res)
        chunk.det_effects += collect_effects(
            [rot_res], [], c.t_start, c.t_end, c.run, chunk.half_y, chunk.out_units
        )
    return measured, pairs, rot_ch, rot_res


def _spectral_lines(
    measured: SegmentStats, session: Session, cfg: ModelCheckConfig
) -> tuple[list[Line], list[dict[str, Any]], str]:
    """Spectral lines fitted on the first half and confirmed on the second, their tests,
    and why they could not be tested ("" where they could)."""
    lines, line_tests = find_lines(
        measured.psd("baseline", 0),
        measured.psd("baseline", 1),
        measured.nperseg,
        session.rate_hz,
        cfg.z_min,
        cfg.max_lines,
        cfg.z_heldout,
    )
    if measured.nperseg == 0 or not measured.psd("baseline", 1)[2]:
        psd_untestable = "still stretches too short or too few for a spectrum on both halves"
    else:
        psd_untestable = ""
    return lines, line_tests, psd_untestable


def _quasi_static_section(
    session: Session, models: _Models, pairs: list[Any], rot_ch: Channel | None
) -> dict[str, Any]:
    """The report's ``quasi_static``: samples, chunks, runs, attitudes, temperature range
    (deg C), turns."""
    c = session.chunks
    return {
        "samples": session.static_samples,
        "chunks": len(c),
        "runs": int(len(session.runs)),
        "attitudes": distinct_attitudes(np.array(list(models.ups.values()))),
        "temperature": (
            [float(np.nanmin(c.temp)), float(np.nanmax(c.temp))] if session.has_temp else None
        ),
        "turns": {
            "between_runs": len(pairs),
            "used": (len(rot_ch) // 2) if rot_ch is not None else 0,
        },
    }


def _evaluation(session: Session, cfg: ModelCheckConfig, models: _Models) -> dict[str, Any]:
    """The report's ``evaluation``: how the models were fitted and scored."""
    return {
        "chunk_s": session.chunk_s,
        "deterministic": "two folds of alternate quasi-static chunks: fit on one, score "
        "the other; both models re-fit the certificate's own biases "
        "(and accelerometer scale and misalignment) on the fitting fold",
        "noise": f"fitted on quasi-static data before t = {models.t_half:.3f} s, scored after",
        "z_min": cfg.z_min,
        "significance": "one-sided standard-normal equivalent of the p-value",
        "gain": GAIN_DEFINITION,
    }


def _noise_models(
    certificate: Certificate,
    session: Session,
    results: list[ChannelResult],
    effects: list[Effect],
    noise_fits: dict[str, SensorNoise],
    density_model: np.ndarray,
    lines: list[Line],
    models: _Models,
) -> tuple[NoiseModel, NoiseModel]:
    """The certificate's noise model and the extended one (walk and lines fitted on the
    first half)."""
    c = session.chunks
    walk_cert = np.concatenate([_walk(certificate.triad(n)) for n in ("gyro", "accel")])
    walk_first = walk_cert.copy()
    first = c.t_mid < models.t_half
    for res in results:
        for d in res.drift:
            e = next((x for x in effects if x.name == "bias_drift" and x.sensor == d.sensor), None)
            if e is None:
                continue
            j = list(res.channel.sensors).index(d.sensor)
            walk_first[ALL_SENSORS.index(d.sensor)] = max(
                k_on_rows(res, j, first), walk_cert[ALL_SENSORS.index(d.sensor)]
            )
    noise_base = NoiseModel(density=density_model, walk=walk_cert)
    # the named noise models, fitted on the first half of their still stretch (the Allan
    # misfit is scored on the second half of the session)
    noise_terms = {
        s: dict((f.first_half or f.model).terms) for s, f in noise_fits.items() if f.terms_named
    }
    noise_ext = NoiseModel(
        density=density_model, walk=walk_first, lines=lines, steps=models.steps, terms=noise_terms
    )
    return noise_base, noise_ext


def _simulations(
    certificate: Certificate,
    session: Session,
    cfg: ModelCheckConfig,
    models: _Models,
    accel_w: TriadModel,
    noise_base: NoiseModel,
    noise_ext: NoiseModel,
    effects: list[Effect],
    seed: int,
) -> dict[str, list[SegmentStats]]:
    """``cfg.replicas`` simulations of the session with each model (common random
    numbers: the same seeds for both)."""
    segments, chunk_input = models.segments, models.chunk_input
    sims: dict[str, list[SegmentStats]] = {"baseline": [], "extended": []}
    for r in range(max(cfg.replicas, 1)):
        s_base = _stats(
            session,
            cfg,
            segments,
            {"baseline": models.predictors["baseline"]},
            [F0Check(name="certificate", model=certificate.accel, parity=None)],
            certificate,
        )
        simulate_session(
            certificate, noise_base, session, segments, chunk_input, s_base, seed=seed * 1000 + r
        )
        sims["baseline"].append(s_base)
        if not effects:  # the extended model is the certificate's
            continue
        s_ext = _stats(
            session, cfg, segments, {"extended": models.predictors["extended"]}, [], certificate
        )
        simulate_session(
            _with_accel(models.ext_det, models.ext_accel_w),
            noise_ext,
            session,
            segments,
            chunk_input,
            s_ext,
            seed=seed * 1000 + r,
        )
        sims["extended"].append(s_ext)
    return sims


def _metrics(
    certificate: Certificate,
    results: list[ChannelResult],
    rot_res: ChannelResult | None,
    models: _Models,
    measured: SegmentStats,
    sims: dict[str, list[SegmentStats]],
    effects: list[Effect],
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any], dict[str, Any]]:
    """The held-out metrics of each model, their gains and units."""
    folds, checks = models.folds, models.checks
    in_units = {"gyro": certificate.gyro.input_unit, "accel": certificate.accel.input_unit}
    base_m = {
        "residual_rms": residual_rms(results, False, folds.get("baseline")),
        "rotation_rms": {"gyro": rotation_rms(rot_res, extended=False), "accel": None},
        "f0_false_alarm_rate": {"gyro": None, "accel": f0_rate(checks, "baseline")},
        "allan_misfit": allan_misfit(measured, sims["baseline"], "baseline"),
    }
    ext_m = {
        "residual_rms": residual_rms(results, True, folds.get("extended")),
        "rotation_rms": {"gyro": rotation_rms(rot_res, extended=True), "accel": None},
        "f0_false_alarm_rate": {"gyro": None, "accel": f0_rate(checks, "extended")},
        "allan_misfit": allan_misfit(measured, sims["extended"], "extended"),
    }
    if not effects:  # nothing named: the extended model is the baseline, gain 1
        ext_m = copy.deepcopy(base_m)
    gain = {k: {t: ratio(ext_m[k][t], base_m[k][t]) for t in ("gyro", "accel")} for k in base_m}
    units = {
        "residual_rms": {"gyro": in_units["gyro"], "accel": in_units["accel"]},
        "f0_false_alarm_rate": "fraction of held-out quasi-static samples (gyro: "
        "none, F0 needs gyros that resolve Earth rate)",
        "allan_misfit": "RMS z of log Allan deviation (about 1: explained)",
        "rotation_rms": "rad: gravity direction after a turn, predicted from the gyros "
        "against measured, held out",
    }
    return base_m, ext_m, gain, units


def _untestable(
    results: list[ChannelResult],
    rot_ch: Channel | None,
    pairs: list[Any],
    cfg: ModelCheckConfig,
    psd_untestable: str,
) -> list[dict[str, Any]]:
    """The effects that could not be tested, each with its reason."""
    untestable = [u for res in results for u in res.channel.untestable]
    if rot_ch is None:
        n_big = sum(p.angle_deg >= cfg.min_rotation_deg for p in pairs)
        n_ok = sum(
            p.angle_deg >= cfg.min_rotation_deg
            for p in usable_pairs(pairs, cfg.max_turn_misfit_rad)
        )
        reason = (
            f"{n_big} rotation(s) of {cfg.min_rotation_deg:g} deg or more between still "
            f"runs: needs {MIN_TURNS} (at rest a gyro's input is zero)"
        )
        if n_big >= MIN_TURNS:
            reason = (
                f"only {n_ok} of {n_big} turns agree with the gyros within "
                f"{cfg.max_turn_misfit_rad:g} rad after a linear recalibration "
                f"(saturation, gaps, or errors beyond a linear model): needs {MIN_TURNS}"
            )
        for s in ("gx", "gy", "gz"):
            for name in ("temperature_scale", "scale_nonlinearity"):
                untestable.append({"name": name, "triad": "gyro", "sensor": s, "reason": reason})
    if psd_untestable:
        untestable += [
            {"name": "periodic_disturbance", "triad": t, "sensor": s, "reason": psd_untestable}
            for t in ("gyro", "accel")
            for s in SENSORS[t]
        ]
    return untestable


def _tested(results: list[ChannelResult], line_tests: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every test run, with its triad (the held-out likelihood under its own name)."""
    tested = [dict(t, triad=res.channel.triad) for res in results for t in res.tested]
    tested += [
        {
            "name": "bias_drift",
            "triad": res.channel.triad,
            "sensor": d.sensor,
            "significance": d.significance,
            "heldout": d.heldout,
            "value": d.value,
            "certificate": d.certificate,
        }
        for res in results
        for d in res.drift
    ]
    tested += [
        dict(t, triad="gyro" if t["sensor"].startswith("g") else "accel") for t in line_tests
    ]
    for t in tested:  # the likelihood improvement under its own name (not a gain)
        if "heldout" in t:
            t[HELDOUT_LOGLIK_KEY] = t.pop("heldout")
    return tested


def _refine_accel(
    results: list[ChannelResult],
    certificate: Certificate,
    accel: TriadModel,
    session: Session,
    cfg: ModelCheckConfig,
    sigma2: np.ndarray,
    rounds: int = 3,
) -> tuple[list[ChannelResult], TriadModel]:
    """Gauss-Newton on the accelerometer channel: the norm is not linear in large effects
    and nuisance changes (1 % of g changes |f| by 5e-5 g at second order), so the
    accelerometer's own parameters are re-fitted together with the effects found, the
    channel is rebuilt at that point, the effects' linear trace is replaced by the exact
    one, and the channel is analysed again until the selection is stable."""
    k = next((i for i, r in enumerate(results) if r.channel.triad == "accel"), None)
    if k is None:
        return results, accel
    res = results[k]
    c = session.chunks
    temp = c.temp if session.has_temp else None
    g_in = certificate.gravity / accel.unit_to_si
    ref = temperature_reference(certificate.accel, cfg)
    for _ in range(rounds):
        specs = accel_effect_specs(res.selected)
        if not specs:
            break
        accel, values = refit_accel(certificate, session, sigma2, specs, ref)
        ch = next(
            x
            for x in build_channels(certificate, session, cfg, accel, sigma2)
            if x.triad == "accel"
        )
        # exact trace of the effects at their fitted values in place of the linear one
        u = c.accel.copy()
        idx = np.arange(len(c))
        for (name, j, b), v in zip(specs, values, strict=True):
            if name == "bias_step":
                u[idx >= (b or 0), j] -= v
        ext = with_effects(accel, specs, values, ref)
        y_ext = np.linalg.norm(ext.inverse(u, temp_c=temp), axis=1) - g_in
        lin = np.zeros(len(c))
        for (name, j, b), v in zip(specs, values, strict=True):
            col = _column_of(ch, name, SENSORS["accel"][j], b)
            if col is not None:
                lin += col * v
        ch.y = y_ext + lin
        new = analyse_channel(ch, cfg)
        same = accel_effect_specs(new.selected) == specs
        res = new
        if same:
            break
    results = list(results)
    results[k] = res
    return results, accel


def _column_of(ch: Channel, name: str, sensor: str, boundary: int | None) -> np.ndarray | None:
    """The regressor (C,) of a single-column effect on ``sensor`` (a step at ``boundary``)."""
    j = list(ch.sensors).index(sensor)
    if name == "bias_step":
        return ch.H[:, j] * (np.arange(len(ch)) >= (boundary or 0))
    for cand in ch.candidates:
        if cand.name == name and cand.sensor == sensor and cand.columns is not None:
            return cand.columns[:, 0]
    return None


def _with_accel(cert: Certificate, accel: TriadModel) -> Certificate:
    out = copy.deepcopy(cert)
    out.accel = copy.deepcopy(accel)
    return out


def _density(tri: TriadModel) -> np.ndarray:
    if tri.noise is None or tri.noise.density is None:
        return np.full(3, np.nan)
    return np.asarray(tri.noise.density, dtype=float)


def _walk(tri: TriadModel) -> np.ndarray:
    if tri.noise is None or tri.noise.bias_random_walk is None:
        return np.zeros(3)
    return np.asarray(tri.noise.bias_random_walk, dtype=float)


def _comparison(
    certificate: Certificate,
    accel_w: TriadModel,
    session: Session,
    measured: SegmentStats,
    sims: dict[str, list[SegmentStats]],
    a_in: np.ndarray,
    temp: np.ndarray | None,
    density_meas: np.ndarray,
    cert_density: np.ndarray,
) -> dict[str, Any]:
    c = session.chunks
    meas_means = np.concatenate([c.gyro, c.accel], axis=1)
    r_meas = _chunk_residual(certificate, accel_w, meas_means, temp, a_in)
    r_cert = _chunk_residual(certificate, certificate.accel, meas_means, temp, a_in)
    sim0 = sims["baseline"][0] if sims["baseline"] else None
    out: dict[str, Any] = {}
    labels = ["gx", "gy", "gz", "accel_norm"]
    unit = [certificate.gyro.output_unit] * 3 + [certificate.accel.input_unit]
    res: dict[str, Any] = {}
    r_sim = None
    if sim0 is not None:
        sm = sim0.chunk_means()
        ok = np.all(np.isfinite(sm), axis=1)
        r_sim = _chunk_residual(
            certificate, certificate.accel, sm[ok], None if temp is None else temp[ok], a_in[ok]
        )

    def rms(v: np.ndarray, centre: bool) -> float:
        v = v - np.mean(v) if centre else v
        return float(np.sqrt(np.mean(v * v)))

    for j, lab in enumerate(labels):
        gyro = j < 3  # a gyro's rest offset is nuisance: centre it; the norm is not centred
        entry = {
            "unit": unit[j],
            "measured_rms": rms(r_meas[:, j], gyro),
            "measured_rms_certificate_as_is": rms(r_cert[:, j], False),
        }
        if r_sim is not None:
            entry["simulated_rms"] = rms(r_sim[:, j], gyro)
        res[lab] = entry
    out["chunk_residuals"] = res
    noise = {}
    sim_density = (
        sim0.sample_sigma() / math.sqrt(session.rate_hz / 2.0)
        if sim0 is not None
        else np.full(6, np.nan)
    )
    for j, s in enumerate(ALL_SENSORS):
        noise[s] = {
            "certificate": None if not np.isfinite(cert_density[j]) else float(cert_density[j]),
            "measured": float(density_meas[j]),
            "simulated": float(sim_density[j]),
            "method": WHITE_NOISE_METHOD,
        }
    out["noise_density"] = noise
    tau, adev_m, ind = measured.allan("baseline")
    allan: dict[str, Any] = {"tau": tau.tolist(), "independent_terms": ind.tolist()}
    if sims["baseline"]:
        avar = np.mean(np.stack([s.allan("baseline")[1] ** 2 for s in sims["baseline"]]), 0)
        for j, s in enumerate(ALL_SENSORS):
            allan[s] = {
                "measured": adev_m[:, j].tolist(),
                "simulated": np.sqrt(avar[:, j]).tolist(),
            }
    out["allan"] = allan
    f0: dict[str, Any] = {}
    chk_m = next((x for x in measured.f0_checks if x.name == "certificate"), None)
    chk_s = next((x for x in sim0.f0_checks if x.name == "certificate"), None) if sim0 else None
    f0["accel"] = {
        "measured": _f0_summary(chk_m),
        "simulated": _f0_summary(chk_s),
        "limit": certificate.accel.limits.f0,
    }
    out["f0"] = f0
    spec: dict[str, Any] = {}
    for half in (0, 1):
        f, p, k = measured.psd("baseline", half)
        if k == 0:
            continue
        floor = np.median(p[1:], axis=0)
        sim_floor = None
        if sim0 is not None:
            _fs, ps, ks = sim0.psd("baseline", half)
            if ks:
                sim_floor = np.median(ps[1:], axis=0)
        spec[f"half{half}"] = {
            s: {
                "measured_floor": float(floor[j]),
                "simulated_floor": None if sim_floor is None else float(sim_floor[j]),
            }
            for j, s in enumerate(ALL_SENSORS)
        }
        spec[f"half{half}"]["segments"] = k
        spec[f"half{half}"]["resolution_hz"] = float(f[1] - f[0])
    out["psd"] = spec
    return out


NOISE_METHOD = (
    "Allan deviation of the longest still stretch (still runs joined across detector "
    "false alarms: gaps under 2 s without a change of attitude; bins of at most 0.05 s), "
    "cluster times from 0.1 s to a tenth of the stretch. Candidates: white noise alone, "
    "with quantization Q, with bias_instability B, with bias_drift K, with a Gauss-Markov "
    "bias, with rate_ramp R, with B and K. "
    "Each is fitted on one half of the stretch and scored on the other (Gaussian "
    "likelihood of ln adev); a model beyond white noise must gain z_min^2/2 nats per "
    "parameter held out. Among the models that reproduce the whole stretch's curve "
    "within 1.5x, the lowest whole-stretch score plus the same penalty per parameter is "
    "chosen and fitted on the whole stretch."
)


def _noise_model(
    source: BlockSource, c: Any, rate_hz: float, cfg: ModelCheckConfig, out_units: dict[str, str]
) -> tuple[dict[str, Any] | None, dict[str, SensorNoise]]:
    """The noise-model section of the report and the selection per sensor ({} when the
    longest still run is shorter than MIN_RUN_S)."""
    t0, t1 = longest_run(c.t_start, c.t_end, c.run, c.accel)
    if t1 - t0 < MIN_RUN_S:
        return (
            {
                "untestable": f"longest still run {t1 - t0:.1f} s: a noise model needs "
                f"{MIN_RUN_S:g} s or more (cluster times to a tenth of it)"
            },
            {},
        )
    y, rate = run_samples(source(), t0, t1, rate_hz)
    fits: dict[str, SensorNoise] = {}
    entries: dict[str, Any] = {}
    for j, s in enumerate(ALL_SENSORS):
        try:
            fits[s] = select(y[:, j], rate, cfg.z_min)
        except NoNoiseSeen as exc:  # a sensor stuck on one step: reported, not fitted
            entries[s] = {"untestable": str(exc)}
            continue
        entries[s] = report_entry(fits[s], out_units["gyro" if s.startswith("g") else "accel"])
    section: dict[str, Any] = {
        "run": [t0, t1],
        "run_s": t1 - t0,
        "tau_range_s": [0.1, (t1 - t0) / 10.0],
        "method": NOISE_METHOD,
        "sensors": entries,
    }
    return section, fits


def _noise_effects(
    effects: list[Effect], fits: dict[str, SensorNoise], out_units: dict[str, str]
) -> list[Effect]:
    """Effects named by the noise model replace the chunk-level random walk of a sensor."""
    if not fits:
        return effects
    out = [e for e in effects if not (e.name == "bias_drift" and e.sensor in fits)]
    for s, f in fits.items():
        triad = "gyro" if s.startswith("g") else "accel"
        u = out_units[triad]
        z = f.significance()
        terms = f.model.terms
        common = {"model": f.model.name, "density": terms["density"]}
        # each named term: the effect's name, its coefficient and the coefficient's unit
        # (IEEE Std 952 terms in the sensor's output unit u)
        units = {
            "quantization": f"{u} s",
            "bias_instability": u,
            "bias_drift": f"{u}/sqrt(s)",
            "rate_ramp": f"{u}/s",
        }
        for name in f.terms_named:
            if name in units:
                effect, value, extra = name, terms[name], dict(common)
                unit = units[name]
            elif name == "gauss_markov":
                effect, value, unit = "gauss_markov_bias", terms["gauss_markov_sigma"], u
                extra = dict(common, correlation_time=terms["gauss_markov_time"])
            else:
                continue
            out.append(Effect(effect, triad, s, value, unit, z, heldout=f.gain_nats, extra=extra))
    return out


def _write_noise_model(cert: Certificate, fits: dict[str, SensorNoise]) -> None:
    """The chosen noise terms into the extended certificate's noise fields (in place)."""
    from ..certificate import Noise

    for k, triad in enumerate(("gyro", "accel")):
        sensors = ALL_SENSORS[3 * k : 3 * k + 3]
        if not all(s in fits for s in sensors):
            continue
        tri = cert.triad(triad)
        if tri.noise is None:
            tri.noise = Noise()
        terms = [fits[s].model.terms for s in sensors]
        tri.noise.density = np.array([t["density"] for t in terms])
        tri.noise.bias_random_walk = np.array([t.get("bias_drift", 0.0) for t in terms])
        b = np.array([t.get("bias_instability", 0.0) for t in terms])
        tri.noise.bias_instability = b if np.any(b) else None
        r = np.array([t.get("rate_ramp", 0.0) for t in terms])
        tri.noise.rate_ramp = r if np.any(r) else None
        q = np.array([t.get("quantization", 0.0) for t in terms])
        tri.noise.quantization = q if np.any(q) else None
        gs = np.array([t.get("gauss_markov_sigma", 0.0) for t in terms])
        if np.any(gs):
            tri.noise.gauss_markov_sigma = gs
            tri.noise.gauss_markov_time = np.array([t.get("gauss_markov_time", 1.0) for t in terms])
        else:
            tri.noise.gauss_markov_sigma = tri.noise.gauss_markov_time = None


def _predicted_by_extended(section: dict[str, Any], cert: Certificate) -> None:
    """Add, per sensor, the Allan deviation the extended certificate's noise fields predict
    (closed form) and its ratio to the measured one, over the compared cluster times."""
    for j, s in enumerate(ALL_SENSORS):
        entry = section.get("sensors", {}).get(s)
        if entry is None or "allan" not in entry:
            continue
        tri = cert.triad("gyro" if j < 3 else "accel")
        tau = np.asarray(entry["allan"]["tau"], dtype=float)
        pred = tri.allan_deviation(tau)
        if pred is None or tau.shape[0] == 0:
            continue
        p = pred[j % 3]
        r = np.asarray(entry["allan"]["measured"]) / p
        entry["allan"]["extended_certificate"] = p.tolist()
        entry["allan"]["ratio_extended_certificate"] = r.tolist()
        entry["max_ratio_extended_certificate"] = float(np.max(np.maximum(r, 1.0 / r)))


__all__ = ["CATALOGUE", "FORMAT", "ModelCheckResult", "model_check"]
