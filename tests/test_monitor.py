"""The per-sample monitor on simulated sessions: F0, rest-rate, stuck, saturation, blocking."""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.bench.devices import calibrate, calibrated_certificate
from imudiag.certificate import load_default
from imudiag.monitor import Monitor, MonitorConfig
from imudiag.samples import FLAG_ACCEL_SATURATED, SampleBlock
from imudiag.sim import Effects, Fault, multi_position, simulate, still

CERT = load_default()


def _feed(monitor: Monitor, block: SampleBlock, sizes: list[int]) -> None:
    start = 0
    for size in sizes:
        monitor.update(block.slice(start, start + size))
        start += size
    monitor.update(block.slice(start, len(block)))


def _session(faults=(), seed: int = 1, duration_s: float = 20.0) -> SampleBlock:
    traj = still(duration_s, rate_hz=CERT.sample_rate, attitude_rpy_deg=(10.0, -20.0, 30.0))
    return simulate(CERT, traj, seed=seed, faults=faults).samples


def test_clean_still_session_raises_nothing():
    m = Monitor(CERT)
    _feed(m, _session(), [1000, 7, 300])
    assert m.f0_checked["accel"] > 3000 and m.f0_failed["accel"] == 0
    assert m.f0_checked["gyro"] > 3000 and m.f0_failed["gyro"] == 0
    assert m.check_mode("gyro") == "rest_rate"  # MEMS gyro: Earth rate is not observable
    assert m.active_faults == []


@pytest.mark.parametrize("sensor", ["ax", "ay", "az"])
def test_gross_accel_bias_fails_f0_after_its_time(sensor):
    m = Monitor(CERT)
    _feed(m, _session([Fault("bias", sensor, 8.0, 2000.0)]), [513] * 10)
    faults = [f for f in m.active_faults if f["cause"] == "f0"]
    assert [f["triad"] for f in faults] == ["accel"]
    assert faults[0]["sensor"] is None  # F0 is a triad check: the key is there, no axis
    # the step itself looks like motion to the 0.5 s detector window, then 20 of 50 fail
    assert 8.0 <= faults[0]["t_first"] < 9.0


def test_gyro_bias_fault_fails_rest_rate_check_and_names_the_axis():
    m = Monitor(CERT)
    # 200 counts = 3 deg/s at 65.5 count/(deg/s)
    _feed(m, _session([Fault("bias", "gy", 5.0, 200.0)]), [400] * 5)
    faults = [f for f in m.active_faults if f["cause"] == "f0"]
    assert [(f["triad"], f["sensor"]) for f in faults] == [("gyro", "gy")]
    assert 5.0 <= faults[0]["t_first"] < 7.0


def test_results_do_not_depend_on_block_sizes():
    block = _session([Fault("bias", "ax", 6.0, 300.0)], seed=4)
    runs = []
    for sizes in ([len(block)], [1] * 300 + [997, 3, 50], [64] * 40):
        m = Monitor(CERT)
        _feed(m, block, sizes)
        runs.append((m.f0_checked, m.f0_failed, m.active_faults))
    assert runs[0] == runs[1] == runs[2]


def test_accel_f0_not_applicable_while_moving():
    traj = multi_position(n_attitudes=6, dwell_s=2.0, turn_s=2.0, rate_hz=CERT.sample_rate, seed=2)
    block = simulate(CERT, traj, seed=2).samples
    m = Monitor(CERT)
    m.update(block)
    moving = int(np.count_nonzero(~traj.static))
    assert m.f0_checked["accel"] <= len(block) - moving  # no check during the turns
    assert m.f0_failed["accel"] == 0 and m.active_faults == []


def test_stuck_channel_is_named():
    block = _session([Fault("stuck", "gz", 3.0, None)])
    m = Monitor(CERT, MonitorConfig(stuck_samples=50))
    _feed(m, block, [256] * 8)
    stuck = [f for f in m.active_faults if f["cause"] == "stuck"]
    assert [{k: f[k] for k in ("triad", "sensor", "cause")} for f in stuck] == [
        {"triad": "gyro", "sensor": "gz", "cause": "stuck"}
    ]
    # in force at the sample completing 50 identical outputs (the frozen one and 49 more)
    t_frozen = block.t[np.searchsorted(block.t, 3.0)]
    assert stuck[0]["t_first"] == pytest.approx(t_frozen + 49 / CERT.sample_rate, abs=1e-9)


# -- the stuck check in any unit: physical outputs, float or quantised ----------------------

SI_CERT = calibrated_certificate(CERT)  #: the same sensor calibrated into rad/s and m/s^2
#: WitMotion WT901 output steps (16 g and 2000 deg/s over 32768), in rad/s and m/s^2
WT901_STEP = {"gyro": 2000.0 / 32768 * np.pi / 180.0, "accel": 16.0 / 32768 * 9.80665}


def _si(block: SampleBlock, step: dict[str, float] | None = None) -> SampleBlock:
    """``block`` (counts) calibrated into SI floats, rounded to ``step`` (SI units) if given."""
    gyro, accel = calibrate(block, CERT)
    if step is not None:
        gyro = np.rint(gyro / step["gyro"]) * step["gyro"]
        accel = np.rint(accel / step["accel"]) * step["accel"]
    return SampleBlock(t=block.t, gyro=gyro, accel=accel)


@pytest.mark.parametrize("step", [None, WT901_STEP], ids=["float", "wt901-quantised"])
def test_stuck_and_dead_channels_are_named_in_si_units(step):
    """SI outputs whose noise spans many steps (a float HIGHRES_IMU, a WT901's LSB at a
    noise of 4 and 16 LSB): a frozen gyro and a dead accelerometer channel are named."""
    faults = [Fault("stuck", "gx", 4.0, None), Fault("dead", "ay", 8.0, 0.0)]
    block = _si(_session(faults, duration_s=10.0), step)
    m = Monitor(SI_CERT)
    _feed(m, block, [97] * 20)
    stuck = {
        (f["triad"], f["sensor"]): f["t_first"] for f in m.active_faults if f["cause"] == "stuck"
    }
    assert set(stuck) == {("gyro", "gx"), ("accel", "ay")}
    assert 4.0 < stuck["gyro", "gx"] <= 4.0 + 50 / SI_CERT.sample_rate
    assert 8.0 < stuck["accel", "ay"] <= 8.0 + 50 / SI_CERT.sample_rate


@pytest.mark.parametrize("step", [None, WT901_STEP], ids=["float", "wt901-quantised"])
def test_clean_si_outputs_are_never_stuck(step):
    block = _si(_session(duration_s=20.0), step)
    m = Monitor(SI_CERT)
    _feed(m, block, [1000, 7, 300])
    assert [f for f in m.active_faults if f["cause"] == "stuck"] == []


def test_a_quantised_output_at_rest_that_repeats_is_not_stuck():
    """A WT901-like output whose step is coarser than the noise (10 sigma): at rest it
    repeats for long runs, as a real one does; the check stays off on such a channel
    (the step learned from the data is never finer than the true one), so no false stuck,
    while the channels with fine steps are still checked."""
    sigma = SI_CERT.accel.noise_sigma(SI_CERT.sample_rate)
    coarse = {"gyro": WT901_STEP["gyro"], "accel": 10.0 * float(np.max(sigma))}
    block = _si(_session([Fault("stuck", "gy", 10.0, None)], duration_s=20.0), coarse)
    for axis in range(3):  # (an axis may never change at all in the session)
        changes = np.flatnonzero(np.diff(block.accel[:, axis]) != 0)
        runs = np.diff(np.concatenate([[-1], changes, [len(block) - 1]]))
        assert runs.max() >= 50  # runs of identical outputs longer than the stuck count
    m = Monitor(SI_CERT)
    _feed(m, block, [333] * 12)
    named = [(f["sensor"], f["cause"]) for f in m.active_faults if f["cause"] == "stuck"]
    assert named == [("gy", "stuck")]
    assert m.stuck_checked == {"gyro": [True] * 3, "accel": [False] * 3}  # said in the status


def test_saturation_flags_persist_into_a_fault():
    block = _session(duration_s=5.0)
    flags = np.zeros(len(block), dtype=np.uint16)
    flags[600:] |= FLAG_ACCEL_SATURATED
    block.flags = flags
    m = Monitor(CERT)
    m.update(block)
    sat = [f for f in m.active_faults if f["cause"] == "saturation"]
    assert len(sat) == 1 and sat[0]["triad"] == "accel"
    assert sat[0]["t_first"] == pytest.approx(block.t[600 + 19])  # 20 of the last 50 samples


def test_a_stuck_output_that_frees_itself_stays_in_the_streams_faults():
    """``stuck_faults``: what the stream ever raised (diagnose's verdict and the daemon's),
    after the fault in force has cleared; the same however the reads cut the stream."""
    block = _session([Fault("stuck", "gz", 3.0, None)])
    free = block.slice(0, len(block))
    frozen = np.flatnonzero(block.t >= 6.0)
    free.gyro[frozen, 2] += np.arange(frozen.size) % 7  # gz moves again from t = 6 s
    runs = []
    for sizes in ([len(free)], [256] * 8, [1] * 300 + [999]):
        m = Monitor(CERT, MonitorConfig(stuck_samples=50))
        _feed(m, free, sizes)
        assert [f for f in m.active_faults if f["cause"] == "stuck"] == []  # cleared
        runs.append(m.stuck_faults())
    assert runs[0] == runs[1] == runs[2]
    (fault,) = runs[0]
    t_frozen = block.t[np.searchsorted(block.t, 3.0)]
    assert fault == {
        "triad": "gyro",
        "sensor": "gz",
        "cause": "stuck",
        "t_first": pytest.approx(t_frozen + 49 / CERT.sample_rate, abs=1e-9),
        "raised": 1,
        "samples": 50,
    }
    m = Monitor(CERT, MonitorConfig(stuck_samples=50))
    m.update(_session())
    assert m.stuck_faults() == [] and m.saturation_faults() == []


def test_saturation_that_ends_stays_in_the_streams_faults():
    block = _session(duration_s=5.0)
    flags = np.zeros(len(block), dtype=np.uint16)
    flags[600:700] |= FLAG_ACCEL_SATURATED
    block.flags = flags
    m = Monitor(CERT)
    m.update(block)
    assert [f for f in m.active_faults if f["cause"] == "saturation"] == []  # ended
    assert m.saturation_faults() == [
        {
            "triad": "accel",
            "sensor": None,
            "cause": "saturation",
            "t_first": pytest.approx(block.t[600 + 19]),
            "raised": 1,
        }
    ]


def test_temperature_block_of_the_certificate_is_applied():
    """With a temperature-dependent bias the monitor is clean only with the extended certificate."""
    from imudiag.certificate import Temperature
    from imudiag.sim import TemperatureProfile

    cert_t = CERT.copy()
    cert_t.accel.temperature = Temperature(
        reference=25.0, bias_coefficient=np.array([0.0, 0.0, 25.0]), scale_coefficient=np.zeros(3)
    )
    traj = still(40.0, rate_hz=CERT.sample_rate)
    eff = Effects(
        temperature=TemperatureProfile(start_c=25.0, warmup_c=20.0, warmup_tau_s=10.0),
        temperature_bias={"az": 25.0},  # counts per degC
    )
    block = simulate(CERT, traj, seed=3, effects=eff).samples
    plain, extended = Monitor(CERT), Monitor(cert_t)
    plain.update(block)
    extended.update(block)
    assert any(f["cause"] == "f0" for f in plain.active_faults)  # 500 counts of bias drift
    assert extended.active_faults == [] and extended.f0_failed["accel"] == 0


def test_noise_increase_is_named_even_when_it_hides_the_rest():
    block = _session([Fault("noise", "ay", 6.0, 5.0)], duration_s=12.0)
    m = Monitor(CERT)
    _feed(m, block, [333] * 7)
    noise = [f for f in m.active_faults if f["cause"] == "noise"]
    assert [(f["triad"], f["sensor"]) for f in noise] == [("accel", "ay")]
    # 5x is gross noise: named once the window's median sees it (0.5 s) and 3 of 5 checks
    assert 6.0 <= noise[0]["t_first"] < 7.0


def test_noise_check_is_quiet_through_turns():
    traj = multi_position(n_attitudes=8, dwell_s=2.0, turn_s=1.5, rate_hz=CERT.sample_rate, seed=5)
    eff = Effects(quantize=True)
    m = Monitor(CERT)
    m.update(simulate(CERT, traj, seed=5, effects=eff).samples)
    assert [f for f in m.active_faults if f["cause"] == "noise"] == []
    assert np.all(m.state["gyro"].noise_ratio_last < 1.5)


def test_gross_gyro_bias_on_a_horizontal_axis_does_not_hide_later_faults():
    """A 6 deg/s gx bias (12 limits) with x horizontal: still seen as still, and named."""
    block = _session([Fault("bias", "gx", 4.0, 400.0), Fault("bias", "az", 10.0, 800.0)])
    m = Monitor(CERT)
    _feed(m, block, [500] * 7)
    found = {(f["triad"], f.get("sensor"), f["cause"]) for f in m.active_faults}
    assert ("gyro", "gx", "f0") in found
    assert ("accel", None, "f0") in found
    assert not any(f["cause"] == "noise" for f in m.active_faults)  # steps are not noise


def test_every_status_fault_carries_the_contract_keys_sensor_null_where_untold():
    from imudiag.service.status import merge_faults

    merged = merge_faults(
        [{"triad": "accel", "cause": "f0", "t_first": 3.0}],
        [{"triad": "accel", "sensor": "az", "cause": "scale_factor"}],
        [{"triad": "accel", "sensor": None, "cause": "f0"}],  # the same fault again
    )
    assert [list(f)[:3] for f in merged] == [["triad", "sensor", "cause"]] * 2
    assert [(f["sensor"], f["cause"]) for f in merged] == [(None, "f0"), ("az", "scale_factor")]


def test_a_filtered_physical_output_that_repeats_at_rest_is_not_stuck():
    """A device that filters its output (as a WT901 does) is smoother than its certificate
    says: at rest its output at the WT901's step repeats more often than not, in runs
    longer than the stuck count, though the stated noise spans several steps. The
    channel's own repeat rate keeps the check off there: no false stuck."""
    block = _si(_session(duration_s=30.0))
    kernel = np.ones(100) / 100  # a 0.5 s moving average, then the WT901's step
    for name in ("gyro", "accel"):
        x = getattr(block, name)
        smooth = np.stack([np.convolve(x[:, i], kernel, mode="same") for i in range(3)], axis=1)
        setattr(block, name, np.rint(smooth / WT901_STEP[name]) * WT901_STEP[name])
    changes = np.flatnonzero(np.diff(block.accel[:, 0]) != 0)
    assert np.diff(np.concatenate([[-1], changes, [len(block) - 1]])).max() >= 50
    sigma = SI_CERT.accel.noise_sigma(SI_CERT.sample_rate)
    assert np.all(sigma >= 4 * WT901_STEP["accel"])  # what the certificate states
    for max_repeat, expected in ((1.0, True), (MonitorConfig().stuck_max_repeat, False)):
        m = Monitor(SI_CERT, MonitorConfig(stuck_max_repeat=max_repeat))
        ever = []
        for start in range(0, len(block), 97):
            m.update(block.slice(start, start + 97))
            ever += [f["sensor"] for f in m.active_faults if f["cause"] == "stuck"]
        # without the repeat-rate rule (1.0: any rate) the filtered axes would be "stuck"
        assert bool(ever) is expected, (max_repeat, ever)
    assert m.stuck_checked["accel"] == [False] * 3
