"""Settings of the model check (times in s, thresholds as significance z)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class ModelCheckConfig:
    """Tunable settings; the defaults suit 100-200 Hz MEMS sessions of minutes to hours."""

    chunk_s: float = 1.0  #: s, quasi-static data is summarised in chunks of this length
    #: at most this many chunks: longer sessions get longer chunks (bounded memory and time)
    max_chunks: int = 4000
    min_chunk_s: float = 0.5  #: s, shorter leftovers at the end of a still run are dropped
    trim_s: float = 0.25  #: s dropped at the end of every still run (detector lag)
    detector_window_s: float = 0.5  #: s, window of the quasi-static detector
    detector_k_sigma: float = 4.0  #: noise standard deviations the detector allows
    max_segment_s: float = 1200.0  #: s, longest stretch analysed at full rate (Allan, PSD)
    max_motion_s: float = 20.0  #: s, longest motion between still runs kept for the gyro
    z_min: float = 5.0  #: significance an effect needs to be named
    z_heldout: float = 0.0  #: held-out log-likelihood improvement (nats) an effect needs
    drift_margin: float = 5.0  #: nats a random walk must beat the best deterministic effect by
    max_step_candidates: int = 200  #: change-point positions scanned per sensor (then refined)
    max_lines: int = 3  #: periodic lines reported per sensor
    psd_max_segment: int = 1024  #: samples per Welch segment at most
    psd_min_segment: int = 64  #: samples per Welch segment at least
    allan_points_per_decade: int = 8
    replicas: int = 2  #: simulations of each model averaged for the expected curves
    temperature_reference: float = 25.0  #: degC, used when the certificate has no temperature block
    min_temperature_span: float = 0.5  #: degC, less than this: temperature effects untestable
    min_rotation_deg: float = 20.0  #: smallest rotation between still runs used for gyro scale
    #: rad: turns whose gravity direction a linear gyro recalibration misses by more are
    #: left out of the gyro scale tests (saturation, gaps, errors far from the model)
    max_turn_misfit_rad: float = 0.05
