"""GNSS aiding physics (imudiag.aiding): normal gravity, Earth and transport
rates, specific force from GNSS velocity, the IMU's epoch means, gating, latency.

Every expected value is derived in the test from stated physics, not read
back from the code under test.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from imudiag.aiding import (
    GateConfig,
    GnssTrack,
    estimate_latency,
    gnss_epochs,
    imu_epochs,
    normal_gravity,
    read_gpspipe_log,
    transport_rate_ned,
)
from imudiag.aiding.specific_force import measured_velocity_sigma
from imudiag.earth import OMEGA_E, coriolis_term, radii
from imudiag.errors import BadInput


def make_track(t, vel, lat=45.0, alt=0.0, mode=3, eps=0.02, epc=0.04) -> GnssTrack:
    k = len(t)
    return GnssTrack(
        t=np.asarray(t, float),
        mode=np.full(k, mode),
        status=np.zeros(k, int),
        lat_deg=np.full(k, lat),
        lon_deg=np.zeros(k),
        alt_m=np.full(k, alt),
        vel_ned=np.asarray(vel, float),
        eps=np.full(k, eps),
        epc=np.full(k, epc),
    )


# --------------------------------------------------------------------------- Earth model


def test_normal_gravity_somigliana_values():
    # WGS-84 normal gravity at the equator and the poles (defining values), and
    # Somigliana at 45 deg with the tabulated k = 0.00193185265241 and
    # e^2 = 0.00669437999013 (NIMA TR8350.2, table 3.4)
    assert normal_gravity(0.0) == pytest.approx(9.7803253359, abs=1e-9)
    assert normal_gravity(90.0) == pytest.approx(9.8321849378, abs=1e-9)
    s2 = 0.5
    g45 = 9.7803253359 * (1 + 0.00193185265241 * s2) / math.sqrt(1 - 0.00669437999013 * s2)
    assert normal_gravity(45.0) == pytest.approx(g45, abs=1e-10)


def test_normal_gravity_free_air_gradient():
    # free-air gradient about -3.086e-6 (m/s^2)/m near the surface
    g0, g1 = normal_gravity(40.0, 0.0), normal_gravity(40.0, 1000.0)
    assert (g1 - g0) / 1000.0 == pytest.approx(-3.086e-6, rel=5e-3)


def test_transport_rate_east_at_equator():
    # moving east at v on the equator turns the level frame about north at v / (a + h)
    w = transport_rate_ned(0.0, 0.0, np.array([0.0, 100.0, 0.0]))
    rm, rn = radii(0.0)
    assert w == pytest.approx([100.0 / rn, 0.0, 0.0], abs=1e-15)
    assert rn == pytest.approx(6378137.0)


def test_eotvos_effect():
    # eastward at V the vertical specific force drops by 2 Omega V cos(lat) + V^2 / R:
    # the Eotvos effect of gravimetry (7.5 mGal per knot east at 45 deg... here in SI)
    v = 30.0
    c = coriolis_term(45.0, 0.0, np.array([0.0, v, 0.0]))
    _, rn = radii(45.0)
    assert c[2] == pytest.approx(
        2 * OMEGA_E * v * math.cos(math.radians(45)) + v * v / rn, rel=1e-9
    )


# --------------------------------------------------------------------------- GNSS side


def test_gnss_specific_force_at_rest_is_gravity():
    t = np.arange(0, 10, 0.25)
    ep = gnss_epochs(make_track(t, np.zeros((len(t), 3)), lat=40.0, alt=1600.0))
    assert np.all(ep.valid)
    assert ep.mag == pytest.approx(normal_gravity(40.0, 1600.0), abs=1e-12)


def test_gnss_specific_force_constant_acceleration_north():
    # v_N = a t: f_n = (a, 0, -g) + 2 Omega x v (Coriolis pushes east/west, not down)
    a, lat = 2.0, 45.0
    t = np.arange(0, 5, 0.2)
    vel = np.stack([a * t, 0 * t, 0 * t], 1)
    ep = gnss_epochs(make_track(t, vel, lat=lat))
    g = normal_gravity(lat)
    vm = a * 0.5 * (t[1:] + t[:-1])
    _, rn = radii(lat)
    rm, _ = radii(lat)
    # (2 Omega_ie + omega_en) x (v,0,0): east component -2 Omega sin(lat) v... the
    # transport term adds (0, 0, v^2/(RM))
    fe = 2 * OMEGA_E * math.sin(math.radians(lat)) * vm
    fd = -g + vm**2 / rm
    expect = np.sqrt(a * a + fe**2 + fd**2)
    assert ep.mag == pytest.approx(expect, rel=1e-12)


def test_gnss_noise_propagation():
    # per-axis velocity std s (eps = 2 s): a level |f| ~ g is mostly vertical,
    # so sigma_|f| ~ sqrt(2) s_v / dt with s_v = epc / 2
    t = np.arange(0, 3, 0.25)
    tr = make_track(t, np.zeros((len(t), 3)), eps=0.02, epc=0.06)
    ep = gnss_epochs(tr, GateConfig(velocity_noise="stated"))
    assert ep.sigma_mag == pytest.approx(math.sqrt(2) * 0.03 / 0.25, rel=1e-9)


def test_gate_mode_outage_outlier():
    t = np.arange(0, 20, 0.25)
    t = np.concatenate([t[:40], t[44:]])  # 1 s outage after t = 9.75
    vel = np.stack([10 + 0.5 * t, 0 * t, 0 * t], 1)
    mode = np.full(len(t), 3)
    mode[10] = 2
    tr = make_track(t, vel)
    tr.mode = mode
    tr.vel_ned[60, 1] += 1.5  # multipath: one velocity off by 1.5 m/s
    ep = gnss_epochs(tr, GateConfig())
    assert list(ep.reason[9:11]) == ["mode", "mode"]
    assert ep.reason[39] == "outage"
    assert list(ep.reason[59:61]) == ["outlier", "outlier"]
    assert ep.counts == {"mode": 2, "outage": 1, "outlier": 2}
    # everything else passes: a smooth acceleration is not an outlier
    assert np.sum(ep.valid) == len(ep) - 5


def test_read_gpspipe_log(tmp_path):
    p = tmp_path / "drive.json"
    lines = [
        {"class": "VERSION", "release": "3.22"},
        {
            "class": "TPV",
            "device": "/dev/ttyACM0",
            "mode": 3,
            "time": "2025-07-08T19:34:00.500Z",
            "lat": 40.1,
            "lon": -105.1,
            "altHAE": 1601.5,
            "velN": 1.0,
            "velE": 2.0,
            "velD": 0.5,
            "eps": 0.1,
            "epc": 0.2,
        },
        {"class": "SKY", "satellites": []},
        # no velN/velE/velD: from speed, track and climb
        {
            "class": "TPV",
            "device": "/dev/ttyACM0",
            "mode": 3,
            "time": "2025-07-08T19:34:00.750Z",
            "lat": 40.1,
            "lon": -105.1,
            "alt": 1601.0,
            "speed": 2.0,
            "track": 90.0,
            "climb": 1.0,
        },
    ]
    p.write_text("\n".join(json.dumps(x) for x in lines) + '\n{"class": "TP')
    tr = read_gpspipe_log(p)
    assert len(tr) == 2
    assert tr.t[1] - tr.t[0] == pytest.approx(0.25)
    assert tr.vel_ned[0] == pytest.approx([1.0, 2.0, 0.5])
    assert tr.vel_ned[1] == pytest.approx([0.0, 2.0, -1.0], abs=1e-12)
    assert tr.alt_m[1] == 1601.0
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(lines[1]) + "\nnot json\n" + json.dumps(lines[1]) + "\n")
    with pytest.raises(BadInput, match=r"bad\.json:2: not a gpsd JSON object"):
        read_gpspipe_log(bad)


# --------------------------------------------------------------------------- IMU side


def steady_turn(rate=0.35, speed=20.0, lever=(0.0, 0.0, 0.0), fs=200.0, dur=20.0, g=9.8):
    """Level steady turn: body x along the velocity, yaw rate ``rate`` rad/s.

    IMU at the turn centre distance R = speed / rate; the antenna at body offset
    ``lever``. Returns IMU (t, f_b, w_b) and the antenna's NED velocity at 4 Hz."""
    t = np.arange(0, dur, 1 / fs)
    f_b = np.tile([0.0, speed * rate, -g], (len(t), 1))
    w_b = np.tile([0.0, 0.0, rate], (len(t), 1))
    tg = np.arange(0, dur, 0.25)
    psi = rate * tg
    lev = np.asarray(lever)
    v_body = np.array([speed, 0.0, 0.0]) + np.cross([0.0, 0.0, rate], lev)
    vn = np.stack(
        [
            np.cos(psi) * v_body[0] - np.sin(psi) * v_body[1],
            np.sin(psi) * v_body[0] + np.cos(psi) * v_body[1],
            0 * psi,
        ],
        1,
    )
    return t, f_b, w_b, tg, vn


def _no_earth(monkeypatch, g):
    # the analytic turn lives on a flat, non-rotating Earth with constant gravity
    import imudiag.aiding.specific_force as sf

    monkeypatch.setattr(sf, "coriolis_term", lambda lat, h, v: np.zeros_like(v))
    monkeypatch.setattr(sf, "normal_gravity", lambda lat, h: np.full(np.shape(lat), g))


def test_rotation_compensation_in_a_turn(monkeypatch):
    # body f constant, its NED direction turns: the mean over a 1 s epoch of f_n is
    # shorter by about (w dt)^2/24 of the horizontal part; the gyro-rotated IMU mean matches
    g = 9.8
    _no_earth(monkeypatch, g)
    t, f_b, w_b, tg, vn = steady_turn(rate=0.35)
    tg, vn = tg[::4], vn[::4]  # 1 Hz GNSS: 1 s epochs
    ep = gnss_epochs(make_track(tg, vn), GateConfig(jerk_allowance_m_s3=100.0))
    comp = imu_epochs(t, f_b, ep.t0, ep.t1, gyro_si=w_b)
    plain = imu_epochs(t, f_b, ep.t0, ep.t1)
    ok = comp.covered
    shrink = 7.0 * (0.35 * 1.0) ** 2 / 24 * 7.0 / math.hypot(7.0, g)
    assert np.max(np.abs(plain.mag[ok] - ep.mag[ok])) == pytest.approx(shrink, rel=0.05)
    assert np.max(np.abs(comp.mag[ok] - ep.mag[ok])) < 2e-4


def test_lever_arm_moves_the_specific_force(monkeypatch):
    # antenna at l = (0.5, 1.5, -1.0) m from the IMU in a 0.35 rad/s turn: its specific
    # force is f_imu + w x (w x l) (w constant); configured, the magnitudes match again
    g = 9.8
    _no_earth(monkeypatch, g)
    lever = np.array([0.5, 1.5, -1.0])
    t, f_b, w_b, tg, vn = steady_turn(rate=0.35, lever=lever)
    ep = gnss_epochs(make_track(tg, vn), GateConfig(jerk_allowance_m_s3=100.0))
    without = imu_epochs(t, f_b, ep.t0, ep.t1, gyro_si=w_b)
    with_arm = imu_epochs(t, f_b, ep.t0, ep.t1, gyro_si=w_b, lever_arm_m=lever)
    ok = without.covered
    w = np.array([0.0, 0.0, 0.35])
    f_ant = f_b[0] + np.cross(w, np.cross(w, lever))
    # the GNSS mean over a 0.25 s epoch is shorter by ~(w dt)^2/24 of the horizontal part
    assert ep.mag[ok] == pytest.approx(np.linalg.norm(f_ant), abs=2e-3)
    assert np.median(np.abs(without.mag[ok] - ep.mag[ok])) > 0.05
    assert np.max(np.abs(with_arm.mag[ok] - ep.mag[ok])) < 2e-4


def test_latency_recovered(monkeypatch):
    # accelerations and brakings (1-3 m/s^2, periods 2.5-11 s); GNSS time tags late
    # by 0.18 s; IMU noise 0.02 m/s^2 a sample at 100 Hz, GNSS velocity 0.01 m/s at 4 Hz.
    # Stated tolerance: 0.01 s (one IMU sample)
    g = 9.8
    _no_earth(monkeypatch, g)
    rng = np.random.default_rng(5)
    fs, lat_true = 100.0, 0.18
    t = np.arange(0, 120, 1 / fs)
    acc = sum(
        a * np.sin(2 * np.pi * t / p + ph)
        for a, p, ph in zip(
            [1.2, 1.0, 0.8, 0.8], [2.5, 3.7, 5.3, 11.0], rng.uniform(0, 6, 4), strict=True
        )
    )
    f_b = np.stack([acc, 0 * t, -g + 0 * t], 1) + rng.normal(0, 0.02, (len(t), 3))
    tg = np.arange(0.0, 120.0, 0.25)
    v = np.interp(tg, t, np.cumsum(acc) / fs)
    vn = np.stack([v, 0 * v, 0 * v], 1) + rng.normal(0, 0.01, (len(tg), 3))
    ep = gnss_epochs(make_track(tg + lat_true, vn, eps=0.02, epc=0.02))
    est = estimate_latency(t, f_b, ep, max_latency_s=0.5)
    assert est.determined, est.reason
    assert est.latency_s == pytest.approx(lat_true, abs=0.01)
    assert est.correlation > 0.8


def test_latency_undetermined_at_constant_speed(monkeypatch):
    _no_earth(monkeypatch, 9.8)
    t = np.arange(0, 60, 0.01)
    f_b = np.tile([0.0, 0.0, -9.8], (len(t), 1))
    tg = np.arange(0, 60, 0.25)
    ep = gnss_epochs(
        make_track(tg, np.tile([15.0, 0, 0], (len(tg), 1))), GateConfig(velocity_noise="stated")
    )
    est = estimate_latency(t, f_b, ep)
    assert not est.determined
    assert "nothing to align" in est.reason


# --------------------------------------------------------------------------- real drive

REAL = Path(__file__).parent / "data" / "real" / "gnss-imu-drive"


def test_real_drive_magnitudes_agree():
    # rtklibexplorer drive_0708 (SOURCE.md): TDK ICM45686 at 100 Hz, RTK velocity at 4 Hz.
    # Over 1 s epochs the IMU's |f| follows |dv/dt - g + Coriolis| (correlation ~0.83),
    # and reads ~1.3 % high: the accelerometers are uncalibrated (SOURCE.md: ~1.4 % at rest)
    from imudiag.logs import read_log

    block = read_log(REAL / "imu.csv.gz")
    track = read_gpspipe_log(REAL / "gnss.tpv.json.gz")
    f = block.accel * 9.80665  # the log's accel unit is g
    w = np.radians(block.gyro)
    ep = gnss_epochs(track, span=4)
    assert ep.period_s == pytest.approx(1.0)
    im = imu_epochs(block.t, f, ep.t0, ep.t1, gyro_si=w)
    ok = ep.valid & im.covered
    assert np.sum(ok) > 500
    assert np.corrcoef(im.mag[ok], ep.mag[ok])[0, 1] > 0.8
    assert 1.010 < np.median(im.mag[ok] / ep.mag[ok]) < 1.017
    # the receiver's stated speed error (eps ~0.12 m/s at 2 sigma) is pessimistic: the
    # velocity's white noise measured from its second differences is about 0.02 m/s
    measured = measured_velocity_sigma(track)
    assert np.all(measured < 0.03)
    assert np.median(track.eps) / 2 > 2 * np.max(measured)
    est = estimate_latency(block.t, f, ep, gyro_si=w, max_latency_s=0.5)
    # the latency (0.13 s) is found, but its std (41 ms) is above the 30 ms tolerance
    assert abs(est.latency_s - 0.13) < 0.01 and 0.0 < est.std_s < 0.06
    assert est.determined == (est.std_s <= 0.03)


def test_missing_velocity_rejects_only_its_epochs():
    # gpsd's first TPV after a (re)start may lack velD/climb: only the epochs that use it go
    t = np.arange(0, 10, 0.2)
    vel = np.stack([5 + 0.1 * t, 0 * t, 0 * t], 1)
    vel[0, 2] = np.nan
    for span in (1, 5):
        ep = gnss_epochs(make_track(t, vel), span=span)
        assert list(ep.reason).count("no_velocity") == 1
        assert np.all(ep.valid[1:])


@pytest.mark.parametrize(("scenario", "latency_s"), [("urban", 0.12), ("hilly", 0.4)])
def test_latency_search_coarse_to_fine_equals_the_full_grid(scenario, latency_s, monkeypatch):
    """The latency search correlates a coarse grid of lags, then the grid around its peak:
    the same estimate as every lag of the grid (COARSE_LAG_S 0), at a tenth of the passes
    over the record (the daemon's aiding batch spent 3 s of CPU on 401 lags)."""
    from imudiag.aiding import align
    from imudiag.aiding.tpv import parse_tpv, track_from_reports
    from imudiag.certificate import load_default
    from imudiag.sim.drive import GnssSimConfig, simulate_drive

    cert = load_default()
    res, reports, _ = simulate_drive(
        scenario, 200.0, cert, seed=1, rate_hz=200.0, gnss=GnssSimConfig(latency_s=latency_s)
    )
    s = res.samples
    f_si, w_si = cert.accel.inverse_si(s.accel), cert.gyro.inverse_si(s.gyro)
    track = track_from_reports([x for x in (parse_tpv(r) for r in reports) if x])
    epochs = gnss_epochs(track, span=max(1, int(round(1.0 / track.period_s()))))
    passes = []
    real = align.ImuSeries.epochs  # each lag is one cut of the record (ImuSeries.epochs)

    def counted(self, *args, **kwargs):
        passes.append(kwargs["latency_s"])
        return real(self, *args, **kwargs)

    monkeypatch.setattr(align.ImuSeries, "epochs", counted)
    fast = align.estimate_latency(s.t, f_si, epochs, gyro_si=w_si)
    n_fast = len(passes)
    monkeypatch.setattr(align, "COARSE_LAG_S", 0.0)
    full = align.estimate_latency(s.t, f_si, epochs, gyro_si=w_si)
    n_full = len(passes) - n_fast
    assert fast.determined == full.determined and np.isfinite(fast.latency_s)
    assert fast.latency_s == full.latency_s and fast.correlation == full.correlation
    assert n_full == 401 and n_fast <= 41 + 23  # 5 ms steps over +-1 s; coarse 50 ms + refine
