"""mavlink:// and mavlink+udp:// (issue 26 item 1): the fake autopilot is encoded by
pymavlink's own encoder (imudiag.bench.devices.MavlinkEncoder), never by the source's
decoder, and reaches the source over a real pty pair or real UDP sockets."""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from imudiag.bench.devices import (
    DeviceWriter,
    MavlinkEncoder,
    calibrated_certificate,
    make_encoder,
)
from imudiag.bench.pty import PtyPair
from imudiag.certificate import datasheet_path, load, load_default
from imudiag.drivers import open_source
from imudiag.drivers.base import SourceError
from imudiag.drivers.mavlink import MavlinkDecoder, x25_crc
from imudiag.drivers.reconnect import ReconnectingSource
from imudiag.samples import SampleBlock
from imudiag.service.daemon import Daemon, DaemonSettings
from imudiag.sim import Fault, multi_position, simulate
from tests.device_sessions import first_named, first_ok
from tests.helpers import CollectSink, read_samples

#: the real-time tier (tests/conftest.py):
#: ptys and a daemon against a fake autopilot, paced in real time
pytestmark = pytest.mark.realtime

dialect = pytest.importorskip("pymavlink.dialects.v20.ardupilotmega")

RATE_HZ = 100.0  #: sample rate of the simulated sessions, Hz
CHUNK = 5  #: samples per block the fake device writes


def _blocks(block: SampleBlock, n: int = CHUNK) -> list[SampleBlock]:
    return [block.slice(i, i + n) for i in range(0, len(block), n)]


def _static(seconds: float, seed: int = 1) -> SampleBlock:
    """A still unit, raw outputs in whole counts of the bundled certificate."""
    cert = load_default()
    s = simulate(cert, multi_position(n_attitudes=1, dwell_s=seconds, rate_hz=RATE_HZ), seed=seed)
    b = s.samples
    return SampleBlock(t=b.t, gyro=np.rint(b.gyro), accel=np.rint(b.accel))


# -- the decoder on pymavlink's frames -----------------------------------------------------


def test_x25_is_pymavlinks_checksum():
    from pymavlink.generator.mavcrc import x25crc_slow

    rng = np.random.default_rng(0)
    for n in (0, 1, 2, 9, 40, 279):
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert x25_crc(data) == x25crc_slow(data).crc


def test_samples_equal_what_pymavlink_encoded_in_any_chunking():
    cert = load_default()
    enc = MavlinkEncoder(cert)
    block = _static(2.0)
    data = enc.encode(block)
    gyro, accel = (np.asarray(x, np.float32) for x in _calibrated(block, cert))
    rng = np.random.default_rng(3)
    for trial in range(3):
        dec = MavlinkDecoder()
        cuts = np.sort(rng.integers(0, len(data), 40 if trial else 0))
        parts = [dec.feed(p) for p in np.split(np.frombuffer(data, np.uint8), cuts)]
        got = SampleBlock.concat(parts)
        assert len(got) == len(block)
        np.testing.assert_array_equal(got.t, np.round(block.t * 1e6) * 1e-6)
        np.testing.assert_array_equal(got.gyro, gyro)  # float32 on the wire, exactly
        np.testing.assert_array_equal(got.accel, accel)
        assert got.meta["units"] == {"gyro": "rad/s", "accel": "m/s^2"}
        c = dec.counters
        assert (c.frames, c.crc_errors, c.skipped_bytes, c.lost, c.duplicates) == (200, 0, 0, 0, 0)
        assert c.bytes == dec.frame_bytes + c.skipped_bytes + dec.pending_bytes == len(data)


def _calibrated(block: SampleBlock, cert) -> tuple[np.ndarray, np.ndarray]:
    from imudiag.bench.devices import calibrate

    return calibrate(block, cert)


def _highres(mav, t_us: int, updated: int = 0x103F, imu: int = 0) -> bytes:
    frame = mav.highres_imu_encode(
        t_us, 0.1, 0.2, -9.8, 0.01, 0.02, 0.03, 0, 0, 0, 0, 0, 0, 25.0, updated, imu
    ).pack(mav)
    mav.seq = (mav.seq + 1) % 256
    return bytes(frame)


def test_garbage_bad_crc_lost_duplicates_and_not_updated_are_counted_and_skipped():
    mav = dialect.MAVLink(None, 1, 1)
    rng = np.random.default_rng(7)
    alphabet = np.frombuffer(MavlinkEncoder.garbage_alphabet, np.uint8)
    garbage = rng.choice(alphabet, 333).tobytes()
    good = [_highres(mav, 1000 * (i + 1)) for i in range(10)]
    bad = bytearray(_highres(mav, 11000))
    bad[20] ^= 0x5A  # a payload byte: the CRC fails (0xFD/0xFE appear in neither)
    assert 0xFD not in bad[1:] and 0xFE not in bad[1:]
    partial = _highres(mav, 12000, updated=0x0007)  # accel only: not a sample
    other = _highres(mav, 13000, imu=1)  # another IMU instance
    after = [_highres(mav, 1000 * (i + 14)) for i in range(3)]
    mav.seq = (mav.seq + 2) % 256  # two frames never sent
    last = _highres(mav, 20000)
    stream = (
        garbage + b"".join(good[:5]) + good[4] + b"".join(good[5:]) + bytes(bad) + partial + other
    )
    stream += b"".join(after) + last
    dec = MavlinkDecoder()
    got = SampleBlock.concat([dec.feed(stream[i : i + 64]) for i in range(0, len(stream), 64)])
    c = dec.counters
    assert len(got) == 14 and c.frames == 14
    assert c.skipped_bytes == 333 + len(bad)
    assert c.crc_errors == 1
    assert c.duplicates == 1  # good[4] twice, byte for byte
    assert c.lost == 1 + 2  # the bad frame's seq, and the two never sent
    assert dec.not_updated == 1 and dec.device_info["not_updated"] == 1 and dec.other_imu == 1
    assert c.bytes == dec.frame_bytes + c.skipped_bytes + dec.pending_bytes
    assert np.all(np.diff(got.t) > 0)


def test_mavlink1_frames_and_signed_frames_decode():
    mav = dialect.MAVLink(None, 1, 1)
    v1 = bytes(mav.scaled_imu_encode(5, 10, 20, 1000, 1, 2, 3, 0, 0, 0, 2500).pack(mav, True))
    dec = MavlinkDecoder(message="scaled")
    b = dec.feed(v1)
    assert len(b) == 1 and b.meta["units"] == {"gyro": "mrad/s", "accel": "mg"}
    np.testing.assert_array_equal(b.accel, [[10, 20, 1000]])
    assert b.temp is not None and b.temp[0] == pytest.approx(25.0)
    signer = dialect.MAVLink(None, 1, 1)
    signer.signing.secret_key = bytes(range(32))
    signer.signing.link_id = 1
    signer.signing.timestamp = 1
    signer.signing.sign_outgoing = True
    msg = signer.highres_imu_encode(7, 1, 2, 3, 4, 5, 6, 0, 0, 0, 0, 0, 0, 0, 63)
    signed = bytes(msg.pack(signer))
    dec = MavlinkDecoder()
    b = dec.feed(signed)
    assert len(b) == 1 and dec.counters.skipped_bytes == 0
    np.testing.assert_array_equal(b.gyro, [[4, 5, 6]])


def test_auto_prefers_highres_else_waits_and_takes_scaled_keeping_its_samples():
    mav = dialect.MAVLink(None, 1, 1)
    hb = bytes(mav.heartbeat_encode(2, 3, 0, 0, 4).pack(mav))  # ArduPilot
    scaled = b"".join(
        bytes(mav.scaled_imu_encode(10 * i, 0, 0, 1000, 0, 0, 0, 0, 0, 0, 0).pack(mav))
        for i in range(1, 151)
    )
    dec = MavlinkDecoder()
    b = dec.feed(hb + scaled)
    # 1 s of device time without HIGHRES_IMU: SCALED_IMU chosen, its held samples kept
    assert dec.kind == "scaled" and len(b) == 150
    assert dec.device_info["message"] == "SCALED_IMU"
    assert dec.device_info["units"] == {"gyro": "mrad/s", "accel": "mg"}
    assert dec.device_info["autopilot"] == "ArduPilot"
    assert dec.device_info["datasheet"] == "mavlink-fc-imu"
    out = dialect.MAVLink(None, 255, 0).parse_buffer(dec.take_outgoing())
    assert [m.get_type() for m in out][0] == "HEARTBEAT"
    asked = [(m.command, int(m.param1)) for m in out if m.get_type() == "COMMAND_LONG"]
    assert (511, 105) in asked and (512, 148) in asked  # HIGHRES_IMU rate, AUTOPILOT_VERSION


# -- over a real pty ------------------------------------------------------------------------


def _wait(cond, timeout_s: float = 10.0) -> None:
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.01)


def _frames(sink: CollectSink) -> int:
    """Samples the daemon had read at its latest status line."""
    return sink.lines[-1]["counters"]["frames"] if sink.lines else 0


def _run_until(daemon: Daemon, done, writer: DeviceWriter | None = None, timeout_s=20.0) -> None:
    """Run ``daemon`` in a thread (``writer`` started once the port is open) until
    ``done()``; then stop both."""
    thread = threading.Thread(target=daemon.run)
    thread.start()
    try:
        if writer is not None:
            _wait(lambda: daemon.source.state == "connected")  # opening flushes the port
            writer.start()
        _wait(done, timeout_s)
    finally:
        daemon.request_stop()
        thread.join(10.0)
        if writer is not None:
            writer.stop()


def test_pty_identity_rate_vibration_in_device_info():
    cert = load_default()
    enc = MavlinkEncoder(cert)
    with PtyPair() as pair:
        writer = DeviceWriter(pair, enc, _blocks(_static(4.0)), speed=4.0)
        src = open_source(f"mavlink://{pair.slave_path}?rate=200")
        src.open()
        writer.start()
        got = read_samples(src, 400, timeout_s=10.0)
        writer.join(5.0)
        src.close()
    assert len(got) == 400
    info = src.device_info
    assert list(info)[:5] == ["vendor", "product", "serial", "firmware", "datasheet"]
    assert info["vendor"] == "0x3162 Holybro" and info["serial"] == "0033002131305111"
    assert info["firmware"].startswith("PX4 1.14.3")
    assert info["datasheet"] == "mavlink-fc-imu" and info["message"] == "HIGHRES_IMU"
    assert info["rate_request"] == {
        "message": "HIGHRES_IMU",
        "requested_hz": 200.0,
        "result": "accepted",
    }
    assert info["rate_hz"] == pytest.approx(RATE_HZ, rel=0.01)  # measured on the stamps
    vib = info["vibration"]
    assert vib["unit"] == "m/s^2" and vib["clipping"] == [0, 0, 0]
    assert all(0 < v < 0.5 for v in vib["accel_rms"])
    intervals = [m for m in enc.commands if m.command == 511 and int(m.param1) == 105]
    assert intervals and intervals[0].param2 == pytest.approx(5000.0)  # us
    assert enc.heartbeats_received >= 1


def test_pty_garbage_and_bad_crc_counted_and_skipped():
    cert = load_default()
    enc = MavlinkEncoder(cert)
    rng = np.random.default_rng(11)
    alphabet = np.frombuffer(enc.garbage_alphabet, np.uint8)
    injected = {"garbage": 0, "bad": 0, "bad_bytes": 0}

    def fault(block: SampleBlock) -> bytes:
        k = int(round(block.t[0] * RATE_HZ)) // CHUNK
        if k % 20 == 7:  # garbage before every 20th block
            injected["garbage"] += 97
            return rng.choice(alphabet, 97).tobytes()
        if k % 20 == 13:  # a corrupted copy of a frame before the block
            frame = bytearray(enc.heartbeat())
            frame[-3] ^= 0x33
            if 0xFD in frame[1:] or 0xFE in frame[1:]:
                return b""
            injected["bad"] += 1
            injected["bad_bytes"] += len(frame)
            return bytes(frame)
        return b""

    block = _static(6.0)
    with PtyPair() as pair:
        writer = DeviceWriter(pair, enc, _blocks(block), speed=6.0, before=fault)
        src = open_source(f"mavlink://{pair.slave_path}")
        src.open()
        writer.start()
        got = read_samples(src, len(block), timeout_s=10.0)
        src.close()
        writer.stop()
    c = src.counters
    assert len(got) == len(block) and np.all(np.diff(got.t) > 0)
    assert injected["garbage"] and injected["bad"]
    assert c.crc_errors == injected["bad"]
    assert c.skipped_bytes == injected["garbage"] + injected["bad_bytes"]
    assert c.lost == injected["bad"]  # the corrupted frame used a sequence number
    assert c.bytes == src.decoder.frame_bytes + c.skipped_bytes + src.decoder.pending_bytes


def test_unplug_and_replug_recover(tmp_path: Path):
    cert = load_default()
    enc = MavlinkEncoder(cert)
    link = tmp_path / "fc0"
    blocks = iter(_blocks(_static(6.0)))
    pair = PtyPair(link=link)
    src = ReconnectingSource(f"mavlink://{link}", min_backoff_s=0.05, max_backoff_s=0.2)
    try:
        src.open()
        writer = DeviceWriter(pair, enc, blocks, speed=3.0)
        writer.start()
        before = read_samples(src, 200, timeout_s=10.0)
        assert len(before) >= 200 and src.state == "connected"
        pair.close_master()  # unplug: the writer stops, the reader gets a hangup
        link.unlink()
        _wait(lambda: len(src.read(0.05)) == 0 and src.state == "reconnecting")
        pair = PtyPair(link=link)  # replug under the same name
        writer = DeviceWriter(pair, enc, writer.remaining, speed=3.0)
        writer.start()
        after = read_samples(src, 200, timeout_s=10.0)
        assert len(after) >= 200
        assert src.state == "connected" and src.reconnects == 1
        assert after.t[0] > before.t[-1]  # the timeline goes on
        assert src.device_info["datasheet"] == "mavlink-fc-imu"
        # the requests went out again on the new connection
        _wait(lambda: enc.heartbeats_received >= 2, 5.0)
    finally:
        src.close()
        pair.close()


# -- over UDP ---------------------------------------------------------------------------------


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_udp_listen_and_connect():
    cert = load_default()
    block = _static(1.0)
    # listen: the router sends to us
    enc = MavlinkEncoder(cert)
    port = _free_port()
    src = open_source(f"mavlink+udp://127.0.0.1:{port}")
    src.open()
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as router:
            for b in _blocks(block, 10):
                router.sendto(enc.encode(b), ("127.0.0.1", port))
            got = read_samples(src, len(block), timeout_s=5.0)
            assert len(got) == len(block)
            # our answers (heartbeat, requests) went back to where the datagrams came from
            router.settimeout(2.0)
            reply, _ = router.recvfrom(65535)
            types = [m.get_type() for m in enc._host.parse_buffer(reply) or []]
            assert "HEARTBEAT" in types
    finally:
        src.close()
    # connect: we send first, the router answers our address
    enc = MavlinkEncoder(cert)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as router:
        router.bind(("127.0.0.1", 0))
        router.settimeout(5.0)
        port = router.getsockname()[1]
        src = open_source(f"mavlink+udp://127.0.0.1:{port}?mode=connect")
        src.open()
        try:
            hello, peer = router.recvfrom(65535)
            assert [m.get_type() for m in enc._host.parse_buffer(hello)] == ["HEARTBEAT"]
            for b in _blocks(block, 10):
                router.sendto(enc.encode(b), peer)
            assert len(read_samples(src, len(block), timeout_s=5.0)) == len(block)
        finally:
            src.close()


def test_unknown_url_keys_and_bad_values_are_refused():
    with pytest.raises(SourceError, match="unknown query key 'sped'"):
        open_source("mavlink:///dev/null?sped=1")
    with pytest.raises(SourceError, match="imu instance"):
        open_source("mavlink:///dev/null?imu=5")
    with pytest.raises(SourceError, match="'mode'"):
        open_source("mavlink+udp://127.0.0.1:14550?mode=both")


# -- the daemon: certificate auto, and the same decisions as the native protocol -------------


class _Run:
    """The daemon in a thread reading a fake device on a pty, until the last sample."""

    def __init__(self, device: str, cert_path: str | Path, session: SampleBlock, **kw) -> None:
        self.sink = CollectSink()
        self.pair = PtyPair()
        cert = load_default()
        self.encoder = make_encoder(device, cert)
        url = {"native": "serial://{p}", "mavlink": "mavlink://{p}"}[device]
        self.daemon = Daemon(
            DaemonSettings(
                source_url=url.format(p=self.pair.slave_path),
                certificate_path=str(cert_path),
                read_interval_s=0.0,
                status_period_s=STATUS_PERIOD_S,
                diagnosis_batch_s=STATUS_PERIOD_S,
                diagnosis_options={"window_intervals": 12},
                **kw,
            ),
            [self.sink],
        )
        self.writer = DeviceWriter(self.pair, self.encoder, _blocks(session), speed=60.0)
        self.t_end = float(session.t[-1])

    def lines(self) -> list[dict]:
        try:
            _run_until(
                self.daemon,
                lambda: any(s["t"] is not None and s["t"] >= self.t_end for s in self.sink.lines),
                self.writer,
                120.0,
            )
        finally:
            self.pair.close()
        return [s for s in self.sink.lines if s["t"] is not None]


def _session(n: int, dwell_s: float, seed: int, faults=()) -> SampleBlock:
    cert = load_default()
    motion = multi_position(n_attitudes=n, dwell_s=dwell_s, rate_hz=RATE_HZ, seed=seed)
    b = simulate(cert, motion, seed=seed + 1, faults=list(faults)).samples
    return SampleBlock(t=b.t, gyro=np.rint(b.gyro), accel=np.rint(b.accel))


#: status period and diagnosis batch of both runs, s of sample time
STATUS_PERIOD_S = 0.1
#: sample time, s, by which the MAVLink path may trail the native one. Both are judged on
#: the sample time the verdict and the fault came in force (the status's
#: ``diagnosis.since`` and the fault's ``t_first``), which does not depend on how fast the
#: daemon keeps up; what is left is the float32 SI outputs against whole counts moving a
#: still interval's end by a few samples
SLACK_S = 3 * STATUS_PERIOD_S


def test_multiposition_ok_and_a_five_limit_bias_named_within_the_native_time(tmp_path: Path):
    """The same simulated samples through the native protocol (counts) and through a fake
    PX4 autopilot (HIGHRES_IMU, the nominal calibration applied: the calibrated
    certificate): both triads ``ok``, then an az bias of 5 limits named, no later."""
    cert = load_default()
    cert.sample_rate = RATE_HZ
    native_cert = tmp_path / "counts.yaml"
    cert.save(native_cert)
    si_cert = tmp_path / "si.yaml"
    calibrated_certificate(cert).save(si_cert)
    clean = _session(24, 3.0, 5).slice(0, int(58 * RATE_HZ))
    fault = Fault("bias", "az", 60.0, 5 * float(cert.accel.limits.bias[2]))
    # the whole 124-s session: the windows of 12 intervals wholly after the onset name the
    # bias from 89 s (the windows straddling it, of 3 degrees of freedom, named it before
    # 92 s, the session's end until the fault test became Student-t there)
    faulty = _session(36, 2.0, 5, [fault]).slice(0, int(124 * RATE_HZ))
    times = {}
    for device, path in (("native", native_cert), ("mavlink", si_cert)):
        ok_lines = _Run(device, path, clean).lines()
        bias_lines = _Run(device, path, faulty).lines()
        times[device] = (first_ok(ok_lines), first_named(bias_lines, "accel", "az", "bias"))
        if device == "mavlink":
            assert ok_lines[-1]["device"]["message"] == "HIGHRES_IMU"
            assert ok_lines[-1]["counters"]["frames"] == len(clean)
    print("sample time, s, at which ok and the az bias came in force:", times)
    (ok_n, named_n), (ok_m, named_m) = times["native"], times["mavlink"]
    assert ok_n is not None and named_n is not None and named_n >= fault.t_s, times
    assert ok_m is not None and ok_m <= ok_n + SLACK_S, times
    assert named_m is not None and fault.t_s <= named_m <= named_n + SLACK_S, times


def test_certificate_auto_loads_the_data_sheet_and_says_so(tmp_path: Path):
    # a unit as the data sheet describes it: simulated with the data-sheet certificate itself
    sheet = load(datasheet_path("mavlink-fc-imu"))
    motion = multi_position(n_attitudes=1, dwell_s=3.0, rate_hz=RATE_HZ)
    block = simulate(sheet, motion, seed=2).samples
    sink = CollectSink()
    with PtyPair() as pair:
        writer = DeviceWriter(pair, MavlinkEncoder(sheet), _blocks(block), 5.0, wait_host_s=20)
        writer.start()
        daemon = Daemon(
            DaemonSettings(
                source_url=f"mavlink://{pair.slave_path}",
                certificate_path="auto",
                diagnosis=False,
                identity_timeout_s=10.0,
            ),
            [sink],
        )
        assert daemon.certificate_file.name == "mavlink-fc-imu.yaml"
        try:
            _run_until(
                daemon, lambda: any(s["counters"]["frames"] >= len(block) for s in sink.lines)
            )
        finally:
            writer.stop()
    last = sink.lines[-1]
    assert last["certificate"]["datasheet"] == "mavlink-fc-imu"
    assert "imudiag calibrate" in last["certificate"]["note"]
    assert last["device"]["vendor"] == "0x3162 Holybro"
    assert last["device"]["units"] == {"gyro": "rad/s", "accel": "m/s^2"}
    # every sample read while waiting for the identity reached the monitor too
    assert last["counters"]["frames"] == len(block)
    assert sum(st["checked"] for st in last["f0"].values()) > 0


def test_certificate_auto_without_identity_names_the_source(tmp_path: Path):
    block = _static(2.0)
    with PtyPair() as pair:  # the native board sends no data-sheet key
        writer = DeviceWriter(pair, make_encoder("native", load_default()), _blocks(block), 2.0)
        writer.start()
        url = f"serial://{pair.slave_path}"
        with pytest.raises(SourceError) as err:
            Daemon(
                DaemonSettings(source_url=url, certificate_path="auto", identity_timeout_s=0.5),
                [CollectSink()],
            )
        writer.stop()
    assert url in str(err.value) and "no device identity within 0.5 s" in str(err.value)
    assert "--certificate PATH" in str(err.value)


def test_scaled_imu_in_mg_and_mrad_s_conformed_to_the_si_data_sheet():
    """SCALED_IMU samples (mg, mrad/s) against the SI data-sheet certificate: converted
    exactly by imudiag.units, said in the status, and the still unit passes F0."""
    sheet = load(datasheet_path("mavlink-fc-imu"))
    motion = multi_position(n_attitudes=1, dwell_s=4.0, rate_hz=RATE_HZ)
    block = simulate(sheet, motion, seed=4).samples
    sink = CollectSink()
    enc = MavlinkEncoder(sheet, message="scaled")
    with PtyPair() as pair:
        daemon = Daemon(
            DaemonSettings(
                source_url=f"mavlink://{pair.slave_path}?message=scaled",
                certificate_path=str(datasheet_path("mavlink-fc-imu")),
                diagnosis=False,
            ),
            [sink],
        )
        writer = DeviceWriter(pair, enc, _blocks(block), speed=8.0)
        _run_until(daemon, lambda: _frames(sink) >= len(block), writer)
    last = sink.lines[-1]
    assert last["device"]["message"] == "SCALED_IMU"
    assert last["unit_conversion"] == [
        {"triad": "gyro", "from": "mrad/s", "to": "rad/s", "factor": 0.001},
        {"triad": "accel", "from": "mg", "to": "m/s^2", "factor": 0.00980665},
    ]
    assert last["f0"]["accel"]["checked"] > 0 and last["faults"] == []
    # ok while the frames flow; once the fake autopilot has sent its last frame, a line
    # may already say no_data (its timeout is wall time, the writer runs at 8x)
    flowing = [s for s in sink.lines if s["state"] != "no_data"]
    assert flowing[-1]["counters"]["frames"] >= len(block) - 100  # the last second's line
    assert {s["state"] for s in flowing} == {"ok"}


def test_bench_scenario_runs_on_the_fake_autopilot(tmp_path: Path):
    """``device: mavlink`` in a bench scenario: the daemon (a real subprocess) reads the
    fake autopilot on the pty; an accelerometer fault, garbage and an unplug are judged as
    on the native board, with the counters exact."""
    from imudiag.bench import ScenarioError, loads, run_scenario

    scenario = loads(
        """
format: imudiag-bench-scenario/1
name: mavlink-smoke
motion: static
duration: 8.0
seed: 3
speed: 4.0
device: mavlink
injections:
  - {t: 2.0, kind: bias, sensor: az, value: 800.0,
     expect: [{triad: accel, cause: f0, within: 1.0}]}
  - {t: 3.5, kind: garbage, bytes: 500}
  - {t: 4.2, kind: crc, frames: 5}
  - {t: 5.0, kind: unplug, outage: 1.0, within: 1.5, recover_within: 3.0}
  - {t: 6.5, kind: duplicate, frames: 2}
  - {t: 7.0, kind: lost, frames: 10}
""",
        "mavlink-smoke.yaml",
    )
    report = run_scenario(scenario, diagnosis=False, workdir=tmp_path).report
    assert report["device"] == "mavlink"
    assert report["passed"], report
    with pytest.raises(ScenarioError, match="random garbage"):
        loads(
            "format: imudiag-bench-scenario/1\nname: x\nmotion: static\nduration: 4\n"
            "device: mavlink\ninjections:\n  - {t: 1.0, kind: garbage, bytes: 9, random: true}\n",
            "x.yaml",
        )
