"""The monitor's settings (:class:`MonitorConfig`, the one definition of each default) and
each triad's running state (:class:`TriadState`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..persistence import Persistence


@dataclass
class MonitorConfig:
    """Settings of the per-sample checks."""

    persistence_k: int = 20  #: failed checks among the last n checked samples to declare a fault
    persistence_n: int = 50  #: checked samples in the persistence window
    stuck_samples: int = 50  #: identical consecutive raw outputs that mean a stuck channel
    #: quantisation steps of the output: the stuck check runs only on channels whose
    #: certificate noise sigma is at least this many steps (a finer noise repeats at rest)
    stuck_min_sigma: float = 1.0
    #: a physical output (not counts; a device may filter it) is checked for stuck only
    #: after this many consecutive output pairs were seen ...
    stuck_history: int = 200
    #: ... with at most this share of them identical (then a clean run of
    #: ``stuck_samples`` has a chance of about 0.5**49 = 2e-15 per sample)
    stuck_max_repeat: float = 0.5
    static_window_s: float = 0.5  #: window of the quasi-static detector, s
    gyro_window_s: float = 1.0  #: averaging window of the MEMS rest-rate check, s
    k_sigma: float = 5.0  #: standard deviations of margin in the gyro rest-rate check
    ring_capacity: int = 4096  #: samples kept in the ring buffer of recent samples
    noise_window_s: float = 1.0  #: window of the white-noise estimate, s
    noise_ratio: float = 2.0  #: estimated / certificate noise sigma that counts as excess noise
    #: the noise check judges only windows where the angular acceleration (rad/s^2, from the
    #: change of the 0.1 s mean rate) stayed below this: a hand turn puts far more into
    #: second differences than the noise; a steady rate (a gross bias, a turntable) does not
    noise_motion_gate: float = 0.5
    noise_check_s: float = 0.1  #: the noise check runs every this many seconds of samples
    #: excess-noise checks among the last n that raise the fault: 3 s of excess within 4 s, so
    #: a burst of a second or two (a hand on the unit, a knock) is not a noise fault
    noise_persistence_k: int = 30
    noise_persistence_n: int = 40
    #: noise beyond ``noise_gross_ratio`` times the certificate's is gross: 3 of 5 checks raise it
    noise_gross_ratio: float = 3.0
    earth_rate_noise_ratio: float = 0.2  #: per-sample Earth-rate F0 needs sigma_f0 < ratio*limit
    #: F0 is judged on the mean of m consecutive checked samples, m the least that makes the
    #: noise of the mean at most limit / f0_noise_ratio (from the certificate's noise at the
    #: sample rate, else the noise the still detector measures in the data): 1 where one
    #: sample's noise is that small already (the bundled certificate at 200 Hz), 13 at
    #: 4 kHz, where single samples fail a healthy unit's F0 about one time in four; 0
    #: judges every sample alone
    f0_noise_ratio: float = 4.0
    #: s of samples gathered before the checks run on them, when a read can change no F0
    #: verdict (every sample passes its F0 limit and none failed in the persistence window):
    #: one call per batch instead of one per read (issue 14). A read with a sample beyond
    #: the limit runs the quasi-static detector and the F0 checks at once; 0: every read
    #: runs everything
    batch_s: float = 0.25


@dataclass
class TriadState:
    """Running counters and last values of one triad's checks."""

    checked: int = 0  #: samples on which the F0 check applied
    failed: int = 0  #: of those, samples in checks beyond the limit
    #: last check's value: F0 (the mean of its samples), or the rest-rate ratio (gyro)
    last_f0: float = float("nan")
    sum_f0_sq: float = 0.0  #: sum of the squared checked values (their RMS is the estimate)
    worst_axis: int | None = None  #: axis of the last gyro rest-rate failure
    #: checked F0 values (dimensionless) and their sample times (s) not yet in a mean
    carry: tuple[np.ndarray, np.ndarray] = field(default_factory=lambda: (np.zeros(0), np.zeros(0)))
    persistence: Persistence | None = None
    saturation: Persistence | None = None
    stuck_active: np.ndarray = field(default_factory=lambda: np.zeros(3, dtype=bool))
    noise: list[Persistence] = field(default_factory=list)  #: per axis, excess noise
    noise_gross: list[Persistence] = field(default_factory=list)  #: per axis, gross noise
    noise_ratio_last: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    #: noise checks judged (the other triad at its own noise) and set aside (it was not:
    #: the unit vibrating or moving, issue 25)
    noise_judged: int = 0
    noise_not_at_rest: int = 0
    #: measured / certificate white-noise sigma (3 axes) of the judged checks with an axis
    #: beyond ``noise_ratio`` (at most 100 000 kept): the noise fault's figure
    noise_excess: list[np.ndarray] = field(default_factory=list)
