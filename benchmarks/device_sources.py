"""CPU of each device protocol's path beside the native wire protocol's, in the same run.

The same simulated session (multi-position motion, white noise) is encoded by the bench
fakes' encoders: the native wire frames, iSensor SPI Buffer entry lines (ADIS16475-2,
16-bit burst), packed IIO records (the kernel's layout), WitMotion frames. Each stream is
decoded in the reads a daemon makes (5 ms of samples each, as ``read_interval_s``), and
each block goes through the per-sample monitor (:class:`imudiag.monitor.Monitor`) with a
certificate in the stream's units, as the daemon's loop does. Thread CPU time, best of
``--runs`` alternated runs; prints s of CPU per 60 s of samples and the ratio to the
native path at the same rate (1 kHz; WitMotion at 200 Hz, its top rate). Run::

    .venv/bin/python benchmarks/device_sources.py [--runs 3] [--seconds 60]
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core: set before numpy is imported

import argparse  # noqa: E402
import math  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from imudiag.bench.fake_iio import Channel, FakeIIODevice, pack_records  # noqa: E402
from imudiag.bench.fake_isensor import entry_lines  # noqa: E402
from imudiag.bench.fake_witmotion import encode_frames  # noqa: E402
from imudiag.certificate import Certificate, datasheet_certificate_path, load, load_default  # noqa: E402
from imudiag.drivers.base import parse_url  # noqa: E402
from imudiag.drivers.iio import IIORecordDecoder, IIOSource  # noqa: E402
from imudiag.drivers.isensor import MODELS, ISensorDecoder  # noqa: E402
from imudiag.drivers.wire import Decoder, encode_samples  # noqa: E402
from imudiag.drivers.witmotion import WitmotionDecoder  # noqa: E402
from imudiag.monitor import Monitor  # noqa: E402
from imudiag.samples import SampleBlock  # noqa: E402
from imudiag.sim import Effects, Simulator  # noqa: E402
from imudiag.sim.scenarios import scenario_motion  # noqa: E402

READ_S = 0.005  #: s of samples per daemon read


def session(cert: Certificate, rate: float, seconds: float) -> SampleBlock:
    motion = scenario_motion("multiposition", 1, {"n": "100", "dwell": "2", "turn": "1"})
    n = int(seconds * rate)
    block = Simulator(cert, Effects(), (), 1).step(motion.sample(rate, 0, n))
    block.temp = np.full(n, 25.0)
    return block


def chunks(data: bytes, n_samples: int, rate: float) -> list[bytes]:
    per = max(1, round(len(data) / n_samples * rate * READ_S))
    return [data[i : i + per] for i in range(0, len(data), per)]


def cpu(feed: Callable[[bytes], SampleBlock], parts: list[bytes], cert: Certificate) -> float:
    monitor = Monitor(cert)
    start = time.thread_time()
    n = 0
    for part in parts:
        block = feed(part)
        if len(block):
            monitor.update(block)
            n += len(block)
    monitor.flush()
    return time.thread_time() - start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    seconds = args.seconds
    cases: dict[str, tuple[float, Certificate, list[bytes], Callable[[], Callable]]] = {}

    for rate in (1000.0, 200.0):
        cert = load_default()
        cert.sample_rate = rate
        b = session(cert, rate, seconds)
        raw = np.rint(np.hstack([b.gyro, b.accel]))
        data = encode_samples(1, np.rint(b.t * 1e6), raw)
        cases[f"native {rate:g} Hz"] = (
            rate,
            cert,
            chunks(data, len(b), rate),
            lambda: Decoder().feed,
        )

    isc = load(datasheet_certificate_path("adis16475-2"))
    isc.sample_rate = 1000.0
    b = session(isc, 1000.0, seconds)
    m = MODELS["adis16475-2"]
    data = b"".join(entry_lines(b, m.gyro_lsb, m.accel_lsb))

    def isensor_decoder() -> Callable[[bytes], SampleBlock]:
        return ISensorDecoder(model=m).feed

    cases["isensor 1000 Hz"] = (1000.0, isc, chunks(data, len(b), 1000.0), isensor_decoder)

    wit = load(datasheet_certificate_path("witmotion-wt901"))
    b = session(wit, 200.0, seconds)
    data = encode_frames(b)
    cases["witmotion 200 Hz"] = (
        200.0,
        wit,
        chunks(data, len(b), 200.0),
        lambda: WitmotionDecoder(rate_hz=200.0).feed,
    )

    si_cert = _si_version(isc)
    gscale = math.radians(1 / 40) / 65536
    ascale = 0.25e-3 * 9.80665
    b = session(si_cert, 1000.0, seconds)  # rad/s and m/s^2 straight from the simulator
    chans = [
        *(Channel(f"anglvel_{a}", i, "le:s32/32>>0", scale=gscale) for i, a in enumerate("xyz")),
        *(
            Channel(f"accel_{a}", 3 + i, "le:s32/32>>0", scale=ascale / 65536)
            for i, a in enumerate("xyz")
        ),
        Channel("timestamp", 6, "le:s64/64>>0"),
    ]
    cols = {f"anglvel_{a}": np.rint(b.gyro[:, i] / gscale) for i, a in enumerate("xyz")}
    cols.update(
        {f"accel_{a}": np.rint(b.accel[:, i] / (ascale / 65536)) for i, a in enumerate("xyz")}
    )
    cols["timestamp"] = np.rint(b.t * 1e9).astype(np.int64)
    data = pack_records(chans, cols)
    tmp = Path(tempfile.mkdtemp())
    fake = FakeIIODevice(tmp / "root", tmp / "dev", "adis16475-2", chans, 0, 1000.0)
    src = IIOSource(parse_url(f"iio://adis16475?root={tmp / 'root'}&devdir={tmp / 'dev'}"))
    src._setup(fake.dir)  # the layout exactly as the source reads it from sysfs
    layout = src.decoder
    fake.close()

    def iio_decoder() -> Callable[[bytes], SampleBlock]:
        dec = IIORecordDecoder()
        dec.configure(layout.elements, layout.record_size, 1000.0)
        return dec.feed

    cases["iio 1000 Hz"] = (1000.0, si_cert, chunks(data, len(b), 1000.0), iio_decoder)

    best = {k: math.inf for k in cases}
    for _ in range(args.runs):
        for name, (_rate, cert, parts, make) in cases.items():
            best[name] = min(best[name], cpu(make(), parts, cert))
    print(f"CPU s per {seconds:g} s of samples (decode + per-sample monitor), best of {args.runs}")
    for name, (rate, *_rest) in cases.items():
        ref = best[f"native {rate:g} Hz"]
        print(f"  {name:18s} {best[name]:7.3f} s   {best[name] / ref:5.2f} x native at {rate:g} Hz")


def _si_version(cert: Certificate) -> Certificate:
    """The data-sheet certificate relabelled rad/s and m/s^2 (identity scale; its limits'
    numbers are kept: a certificate for the monitor's CPU cost only, not a conversion)."""
    from imudiag.certificate import loads

    text = datasheet_certificate_path("adis16475-2").read_text()
    text = text.replace("unit: deg/s", "unit: rad/s").replace("unit: g", "unit: m/s^2")
    out = loads(text)
    out.sample_rate = cert.sample_rate
    return out


if __name__ == "__main__":
    main()
