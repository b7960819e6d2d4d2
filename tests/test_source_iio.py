"""``iio://``: a fake sysfs tree and a real FIFO in a temporary directory, laid out as the
kernel does (Documentation/ABI/testing/sysfs-bus-iio); the packed records are built
here, by hand, with ``struct`` from the scan elements' ``type`` strings: gyro
``be:s32/32>>0`` (indices 0-2), accelerometer ``le:s16/16>>0`` (3-5), a temperature
channel the reader must switch off (6), timestamp ``le:s64/64>>0`` (7). Each element
sits at the next multiple of its size: gyro at 0, 4, 8, accel at 12, 14, 16, the
timestamp at 24; 32-byte records.
"""

from __future__ import annotations

import math
import struct
import threading

import numpy as np
import pytest

from imudiag import units
from imudiag.bench.fake_iio import Channel, FakeIIODevice, pack_records
from imudiag.certificate import datasheet_path, load
from imudiag.drivers.base import open_source
from imudiag.drivers.iio import ScanType, record_layout
from imudiag.drivers.reconnect import ReconnectingSource
from imudiag.errors import BadInput, SourceError
from imudiag.samples import SampleBlock
from tests.device_sessions import DaemonThread, judge_session, session_samples
from tests.helpers import read_samples, read_until_state

#: the real-time tier (tests/conftest.py):
#: a FIFO written by a fake kernel and a daemon thread, timed on the wall clock
pytestmark = pytest.mark.realtime

G = 9.80665
GYRO_SCALE = math.radians(1 / 40) / 65536  #: rad/s per LSB (ADIS16475-2, 32-bit output)
ACCEL_SCALE = 0.25e-3 * G  #: m/s^2 per LSB (ADIS16475, 16-bit output)
AZ_OFFSET = 8.0  #: in_accel_z_offset, LSB: value = (raw + offset) * scale
T0_NS = 1_764_331_200_000_000_000  #: the first time stamp, ns (CLOCK_REALTIME-like)
CHANNELS = [
    *(Channel(f"anglvel_{a}", i, "be:s32/32>>0", scale=GYRO_SCALE) for i, a in enumerate("xyz")),
    Channel("accel_x", 3, "le:s16/16>>0"),
    Channel("accel_y", 4, "le:s16/16>>0"),
    Channel("accel_z", 5, "le:s16/16>>0", offset=AZ_OFFSET),
    Channel("temp0", 6, "le:s16/16>>0", scale=1.0, enabled=True),
    Channel("timestamp", 7, "le:s64/64>>0"),
]
RECORD = 32


def records(block: SampleBlock, t0_ns: int = T0_NS) -> bytes:
    """The records of ``block`` (rad/s, m/s^2), packed by hand."""
    g = np.rint(block.gyro / GYRO_SCALE).astype(np.int64)
    a = np.rint(block.accel / ACCEL_SCALE).astype(np.int64)
    a[:, 2] -= int(AZ_OFFSET)
    ts = t0_ns + np.rint(block.t * 1e9).astype(np.int64)
    out = bytearray()
    for i in range(len(block)):
        out += struct.pack(">3i", *g[i])  # bytes 0..11
        out += struct.pack("<3h", *a[i])  # bytes 12..17
        out += bytes(6)  # padding to the timestamp's 8-byte alignment
        out += struct.pack("<q", ts[i])  # bytes 24..31
    assert len(out) == RECORD * len(block)
    return bytes(out)


def still(n: int, t0: float = 0.0, rate: float = 200.0) -> SampleBlock:
    t = t0 + np.arange(n) / rate
    return SampleBlock(
        t=t,
        gyro=np.tile([0.01, -0.02, 0.005], (n, 1)),
        accel=np.tile([0.1, -0.2, G], (n, 1)),
    )


@pytest.fixture
def tree(tmp_path, monkeypatch):
    root, devdir = tmp_path / "sys" / "bus" / "iio" / "devices", tmp_path / "dev"
    root.mkdir(parents=True)
    # a device that is not the IMU comes first
    other = FakeIIODevice(root, devdir, "ads1015", [Channel("voltage0", 0, "be:s12/16>>4")], 0)
    dev = FakeIIODevice(
        root, devdir, "adis16475-2", CHANNELS, 1, 2000, shared={"in_accel_scale": ACCEL_SCALE}
    )
    monkeypatch.setenv("IMUDIAG_IIO_ROOT", str(root))
    monkeypatch.setenv("IMUDIAG_IIO_DEV", str(devdir))
    yield dev
    dev.close()
    other.close()


def test_layout_of_the_kernel_types():
    types = {c.name: ScanType.parse(c.type, c.name) for c in CHANNELS if c.name != "temp0"}
    layout, size = record_layout(
        [(c.name, c.index, types[c.name]) for c in CHANNELS if c.name in types]
    )
    assert dict(layout) == {
        "anglvel_x": 0, "anglvel_y": 4, "anglvel_z": 8,
        "accel_x": 12, "accel_y": 14, "accel_z": 16, "timestamp": 24,
    }  # fmt: skip
    assert size == RECORD
    st = ScanType.parse("be:s12/16>>4", "t")
    raw = np.array([(0x800 << 4) | 0xF, (0x7FF << 4)], dtype=np.uint16)  # -2048, +2047
    assert st.decode(raw).tolist() == [-2048, 2047]


def test_finds_by_name_configures_and_scales(tree):
    with open_source("iio://adis16475?rate=200") as src:
        assert tree.enabled() == {c.name: c.name != "temp0" for c in CHANNELS}
        assert tree.buffer_enabled()
        assert (tree.dir / "sampling_frequency").read_text().strip() == "200"
        tree.write(records(still(30)))
        got = read_samples(src, 30)
        info = src.device_info
    assert not tree.buffer_enabled()  # closing disables the buffer
    assert len(got) == 30
    assert np.allclose(got.t, np.arange(30) / 200.0, atol=1e-9)
    assert np.allclose(got.gyro, [0.01, -0.02, 0.005], atol=GYRO_SCALE)
    assert np.allclose(got.accel, [0.1, -0.2, G], atol=ACCEL_SCALE / 2)
    assert got.meta["units"] == {"gyro": "rad/s", "accel": "m/s^2"}
    assert info["product"] == "ADIS16475-2" and info["vendor"] == "Analog Devices"
    assert info["datasheet"] == "adis16475-2" and info["iio_device"] == "iio:device1"
    assert {"serial", "firmware"} <= set(info) and info["record_bytes"] == RECORD


def test_named_directly_and_the_bench_encoder_agrees(tree):
    with open_source("iio://iio:device1") as src:
        block = still(10)
        cols = {f"anglvel_{a}": np.rint(block.gyro[:, i] / GYRO_SCALE) for i, a in enumerate("xyz")}
        cols.update(
            {f"accel_{a}": np.rint(block.accel[:, i] / ACCEL_SCALE) for i, a in enumerate("xyz")}
        )
        cols["accel_z"] -= AZ_OFFSET
        cols["timestamp"] = T0_NS + np.rint(block.t * 1e9).astype(np.int64)
        enabled = [c for c in CHANNELS if c.name != "temp0"]
        data = pack_records(enabled, cols)
        assert data == records(block)
        tree.write(data)
        assert len(read_samples(src, 10)) == 10


def test_repeated_and_missing_time_stamps_are_counted(tree):
    block = still(40)
    data = records(block)
    rec = [data[i * RECORD : (i + 1) * RECORD] for i in range(40)]
    stream = rec[:10] + [rec[9]] + rec[10:20] + rec[23:]  # one repeat, three lost
    with open_source("iio://adis16475?rate=200") as src:
        tree.write(b"".join(stream[:15]) + stream[15][:20])  # a record split across reads
        tree.write(stream[15][20:] + b"".join(stream[16:]))
        got = read_samples(src, 37)
        c = src.counters
    assert len(got) == 37 and c.duplicates == 1 and c.lost == 3
    assert c.bytes == len(b"".join(stream)) and c.crc_errors == 0
    assert np.allclose(got.t, np.delete(block.t, [20, 21, 22]), atol=1e-9)


def test_session_reaches_ok_and_names_the_bias_within_the_native_time(tree, tmp_path):
    """The device gives rad/s and m/s^2; the data-sheet certificate is in deg/s and g: the
    daemon converts exactly (imudiag.units) and judges as the native protocol does."""
    cert = load(datasheet_path("adis16475-2"))
    cert.sample_rate = 200.0
    cert_path = tmp_path / "adis16475-2-200hz.yaml"
    cert.save(cert_path)
    block = session_samples(cert)  # deg/s and g
    si = SampleBlock(
        t=block.t,
        gyro=block.gyro * units.factor("gyro", "deg/s", "rad/s"),
        accel=block.accel * units.factor("accel", "g", "m/s^2"),
    )
    data = records(si)
    with DaemonThread("iio://adis16475?rate=200", str(cert_path)) as d:
        d.wait_connected()
        writer = threading.Thread(target=tree.write, args=(data,), daemon=True)
        writer.start()
        t_end = float(block.t[-1] - block.t[0])
        d.wait(lambda s: s["t"] is not None and s["t"] >= t_end - 1e-6, timeout_s=120)
        last = d.sink.lines[-1]
    writer.join(5)
    assert last["counters"]["frames"] == len(block) and last["counters"]["lost"] == 0
    assert {c["triad"]: (c["from"], c["to"]) for c in last["unit_conversion"]} == {
        "gyro": ("rad/s", "deg/s"),
        "accel": ("m/s^2", "g"),
    }
    judge_session(d.sink.lines)


def test_units_the_certificate_cannot_take_are_refused(tree):
    """A counts certificate (the bundled one) cannot judge m/s^2: the daemon stops with the
    error ``diagnose`` gives such a log (exit 2 from the command line), naming the source
    and the certificate's unit; nothing is converted by a guess."""
    d = DaemonThread("iio://adis16475?rate=200", None)
    errors: list[BadInput] = []

    def run() -> None:
        try:
            d.daemon.run()
        except BadInput as exc:
            errors.append(exc)

    d.thread = threading.Thread(target=run, name="daemon", daemon=True)
    with d:
        d.wait_connected()
        tree.write(records(still(40)))
        d.thread.join(30)
    assert len(errors) == 1, "the daemon went on with units it cannot convert"
    assert "iio://adis16475" in str(errors[0]) and "output_unit is 'count'" in str(errors[0])


def test_unplug_and_replug_recover(tree):
    src = ReconnectingSource("iio://adis16475?rate=200", min_backoff_s=0.02, max_backoff_s=0.1)
    try:
        src.open()
        assert src.state == "connected"
        tree.write(records(still(20)))
        got1 = read_samples(src, 20)
        tree.unplug()
        assert read_until_state(src, "reconnecting", 50) == "reconnecting"
        assert "device gone" in (src.last_error or "")
        src.read(0.05)  # an attempt while the device is absent fails and backs off
        assert "no device" in (src.last_error or "") or "no such device" in (src.last_error or "")
        tree.plug()
        assert read_until_state(src, "connected", 200) == "connected" and src.reconnects == 1
        tree.write(records(still(20, t0=0.1)))
        got2 = read_samples(src, 20)
    finally:
        src.close()
    assert len(got1) == 20 and len(got2) == 20 and got2.t[0] > got1.t[-1]
    assert np.allclose(np.diff(np.concatenate([got1.t, got2.t])), 0.005)


def test_missing_device_and_non_imu_are_refused(tree):
    with pytest.raises(SourceError, match="no device of that name"):
        open_source("iio://bmi160").open()
    with pytest.raises(SourceError, match="not an IMU"):
        open_source("iio://ads1015").open()


def test_timeline_gives_the_same_times_and_counts_in_any_read_size():
    """The daemon's small reads take a plain-Python path: it must agree with the
    vectorised one on times, duplicates, losses and restarts."""
    from imudiag.drivers.devicestream import Timeline
    from imudiag.drivers.wire import Counters

    rng = np.random.default_rng(3)
    for _ in range(100):
        n = int(rng.integers(5, 300))
        ticks = 1000 + np.cumsum(rng.choice([0, 1, 1, 1, 1, 2, 3, -5], size=n))
        results = []
        for pieces in (1, max(1, n // 5)):  # one big block, then reads of about 5
            tl, c = Timeline(1.0, None, 1.0), Counters()
            t = np.concatenate([tl.place(p, c)[1] for p in np.array_split(ticks, pieces)])
            results.append((t, c, tl.restarts))
        (t1, c1, r1), (t2, c2, r2) = results
        assert np.allclose(t1, t2) and c1 == c2 and r1 == r2


def test_a_bench_scenario_served_by_the_fake_device(tmp_path):
    """`python -m imudiag.bench.fake_device iio`: the bench's sensor-faults scenario on a
    fake ADIS16475-2, read in m/s^2 (gravity on -z, then the +38-limit az bias)."""
    from imudiag.bench.fake_device import serve
    from imudiag.bench.scenario import load_bundled

    scenario = load_bundled("sensor-faults").with_options(speed=10.0)
    root, devdir = tmp_path / "devices", tmp_path / "dev"
    fake, thread = serve("iio", scenario, "adis16475-2", 200.0, root=root, devdir=devdir)
    try:
        with open_source(f"iio://adis16475?root={root}&devdir={devdir}&rate=200") as src:
            got = read_samples(src, 700, timeout_s=20)
    finally:
        thread.join(5)
        fake.close()
    assert len(got) >= 700 and np.allclose(got.t, np.arange(len(got)) / 200.0)
    g = units.factor("accel", "g", "m/s^2")
    assert got.accel[:50, 2].mean() == pytest.approx(-g, abs=0.01)
    jump = got.accel[450:650, 2].mean() - got.accel[:350, 2].mean()  # after / before t = 2 s
    assert jump == pytest.approx(800 / 21.0 * 0.002 * g, abs=0.01)
