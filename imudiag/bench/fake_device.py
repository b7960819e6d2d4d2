"""Any bench scenario on a fake device (as gpsfake serves a log to gpsd): the motion and the
sensor faults of an ``imudiag bench`` scenario, simulated with the device's data-sheet
certificate, served in the device's own protocol::

    python -m imudiag.bench.fake_device witmotion --scenario sensor-faults --link /tmp/wt901
    python -m imudiag.bench.fake_device isensor --model adis16475-2 --link /tmp/isensor0
    python -m imudiag.bench.fake_device iio --model adis16475-2 --root /tmp/iio/devs \
        --devdir /tmp/iio/dev

then ``imudiag run --source witmotion:///tmp/wt901?rate=200`` (or ``isensor://``,
``iio://adis16475?root=...&devdir=...``) with the data-sheet certificate. A scenario's
fault values are stated against its own certificate (counts on the native board): each
bias, scale-factor or misalignment fault keeps its size in limits on the device
(:func:`device_faults`), so its expectations keep their meaning. Transport injections
(garbage, CRC, unplug, ...) are the native protocol's and are not replayed here.
"""

from __future__ import annotations

import argparse
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from imudiag import certificate as certmod
from imudiag.certificate import Certificate
from imudiag.samples import SampleBlock
from imudiag.sim import Fault
from imudiag.sim.scenarios import scenario_motion

from .fake_iio import (
    ADIS16475_2_ACCEL_SCALE,
    ADIS16475_2_GYRO_SCALE,
    FakeIIODevice,
    imu_channels,
    pack_records,
)
from .fake_isensor import ISENSOR_LSB, FakeISensorBoard, entry_lines
from .fake_witmotion import encode_frames
from .pty import BoardWriter, PtyPair
from .scenario import BenchScenario, load, load_bundled
from .simulated import simulated_blocks

_SCALED = ("bias", "scale_factor", "misalignment")


def device_faults(
    scenario: BenchScenario, scenario_cert: Certificate, device_cert: Certificate
) -> list[Fault]:
    """The scenario's sensor faults for a device with ``device_cert``: bias, scale-factor
    and misalignment values keep their size in the two certificates' limits; the others
    (stuck, noise multiplier, dead at its default) carry over as they are."""
    out = []
    for inj in scenario.sensor_injections:
        f = inj.fault()
        if f.kind in _SCALED and f.value is not None:
            triad = "gyro" if f.sensor.startswith("g") else "accel"
            lim_s = getattr(scenario_cert.triad(triad).limits, f.kind)
            lim_d = getattr(device_cert.triad(triad).limits, f.kind)
            f = Fault(
                f.kind, f.sensor, f.t_s, f.value / float(np.mean(lim_s)) * float(np.mean(lim_d))
            )
        elif f.kind == "stuck":
            f = Fault(f.kind, f.sensor, f.t_s, None)
        out.append(f)
    return out


def scenario_blocks(
    scenario: BenchScenario, device_cert: Certificate, rate_hz: float
) -> Iterator[SampleBlock]:
    """The scenario's samples in the device certificate's units, ``chunk_s`` at a time."""
    scen_cert = (
        certmod.load(scenario.certificate) if scenario.certificate else certmod.load_default()
    )
    motion = scenario_motion(scenario.motion, scenario.seed, scenario.motion_params)
    faults = device_faults(scenario, scen_cert, device_cert)
    return simulated_blocks(
        device_cert,
        motion,
        rate_hz,
        scenario.seed,
        faults,
        chunk_s=scenario.chunk_s,
        duration_s=scenario.duration_s,
    )


def _paced(blocks: Iterator[SampleBlock], speed: float, chunk_s: float) -> Iterator[SampleBlock]:
    start = time.monotonic()
    for i, block in enumerate(blocks):
        delay = start + i * chunk_s / speed - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        yield block


def serve(
    device: str,
    scenario: BenchScenario,
    model: str,
    rate_hz: float,
    link: Path | None = None,
    root: Path | None = None,
    devdir: Path | None = None,
) -> tuple[object, threading.Thread]:
    """Start serving ``scenario`` on a fake ``device`` (witmotion, isensor, iio); returns
    the fake (PtyPair, FakeISensorBoard or FakeIIODevice) and the feeding thread."""
    key = "witmotion-wt901" if device == "witmotion" else model
    cert = certmod.load(certmod.datasheet_path(key))
    blocks = _paced(scenario_blocks(scenario, cert, rate_hz), scenario.speed, scenario.chunk_s)
    if device == "witmotion":
        assert link is not None, "witmotion needs a link path"
        pair = PtyPair(link=link)
        writer = BoardWriter(pair, (encode_frames(b) for b in blocks))
        writer.start()
        return pair, writer
    if device == "isensor":
        assert link is not None, "isensor needs a link path"
        if model not in ISENSOR_LSB:
            raise ValueError(f"the fake board knows {', '.join(ISENSOR_LSB)}, not {model!r}")
        glsb, alsb = ISENSOR_LSB[model]
        pair = PtyPair(link=link)
        part, _, dash = model.removeprefix("adis").partition("-")
        board = FakeISensorBoard(pair, prod_id=int(part), range_model=int(dash or 3))
        board.start()
        count = [1]

        def feed() -> None:
            for b in blocks:
                lines = entry_lines(b, glsb, alsb, first_count=count[0])
                count[0] += len(lines)
                board.queue(lines)

        thread = threading.Thread(target=feed, daemon=True, name="fake-isensor-feed")
        thread.start()
        return board, thread
    if device == "iio":
        assert root is not None and devdir is not None, "iio needs root and devdir"
        g = cert.gyro.output_unit
        if g != "deg/s":
            raise ValueError(f"{key}: gyro in {g}, expected deg/s")
        # the ADIS16475-2's 32-bit LSB sizes (an m/s^2 part: 1/4000 m/s^2 per 16-bit LSB)
        ascale = ADIS16475_2_ACCEL_SCALE if cert.accel.output_unit == "g" else 1 / 4000 / 65536
        chans = imu_channels(ADIS16475_2_GYRO_SCALE, ascale)
        fake = FakeIIODevice(root, devdir, model, chans, 0, rate_hz)
        gyro_counts = 40 * 65536  # per deg/s
        accel_counts = 4000 * 65536  # per g (or per m/s^2 for the m/s^2 parts)

        def feed_iio() -> None:
            for b in blocks:
                cols = {
                    f"anglvel_{a}": np.rint(b.gyro[:, i] * gyro_counts) for i, a in enumerate("xyz")
                }
                cols.update(
                    {
                        f"accel_{a}": np.rint(b.accel[:, i] * accel_counts)
                        for i, a in enumerate("xyz")
                    }
                )
                cols["timestamp"] = np.rint(b.t * 1e9).astype(np.int64)
                fake.write(pack_records(chans, cols))

        thread = threading.Thread(target=feed_iio, daemon=True, name="fake-iio-feed")
        thread.start()
        return fake, thread
    raise ValueError(f"unknown fake device {device!r}: witmotion, isensor, iio")


def main(argv: list[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("device", choices=("witmotion", "isensor", "iio"))
    ap.add_argument("--scenario", default="sensor-faults", help="bundled name or a YAML file")
    ap.add_argument("--model", default="adis16475-2", help="ADIS range model (isensor, iio)")
    ap.add_argument("--rate", type=float, default=200.0, help="samples per second, Hz")
    ap.add_argument("--speed", type=float, default=None, help="pace, x real time")
    ap.add_argument("--link", type=Path, help="pty symlink (witmotion, isensor)")
    ap.add_argument("--root", type=Path, help="IIO devices directory (iio)")
    ap.add_argument("--devdir", type=Path, help="directory of the iio:deviceN FIFO (iio)")
    args = ap.parse_args(argv)
    path = Path(args.scenario)
    scenario = load(path) if path.suffix in (".yaml", ".yml") else load_bundled(args.scenario)
    scenario = scenario.with_options(speed=args.speed)
    _fake, thread = serve(
        args.device, scenario, args.model, args.rate, args.link, args.root, args.devdir
    )
    try:
        while thread.is_alive():
            thread.join(0.2)
        time.sleep(2.0)  # let the reader take the last bytes
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
