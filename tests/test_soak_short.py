"""A few simulated minutes of the soak (``python -m soak``): the real daemon, injected faults.

The daemon (built from the bundled configuration, diagnosis on) reads the
``soak://`` byte transport through the reconnecting source and the wire
decoder: CRC errors, dropped and duplicated frames, garbage, unplugs and ADC
errors at a high rate, and sensor-fault episodes. Its counters must equal the
injected tally exactly and every status line must be well-formed.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from imudiag.certificate import load_default
from imudiag.drivers.wire import Decoder, encode_info
from soak.run import EpisodeJudge, run_soak
from soak.status_check import StatusLineError, StatusStream, check_status_line
from soak.stream import BIAS_EPISODE_COUNTS, GROUP_SAMPLES, SoakStream, Unplug


@pytest.fixture(scope="module")
def soak_result():
    """Four simulated minutes at 1 kHz, every event kind at 20x the default rate."""
    return run_soak(
        hours=4 / 60,
        rate_hz=1000.0,
        seed=3,
        error_rate=20.0,
        episode_every_s=50.0,
        rss_every_s=10.0,
    )


def test_soak_passes_with_exact_counters(soak_result) -> None:
    r = soak_result
    assert r.passed, r.failures
    assert r.counters == r.expected_counters
    assert r.adc_errors == r.expected_adc_errors > 0
    assert r.reconnects == r.expected_reconnects > 0
    assert r.samples == 240_000
    assert r.t_last == pytest.approx((240_000 - 1) / 1000.0, abs=1e-9)


def test_soak_exercised_every_fault_kind(soak_result) -> None:
    r = soak_result
    for kind in ("crc", "drop", "dup", "garbage", "unplug", "adc"):
        assert r.events[kind] > 0, kind
    c = r.counters
    assert c["crc_errors"] == r.events["crc"]
    assert c["duplicates"] == r.events["dup"]
    assert c["skipped_bytes"] > 40 * c["crc_errors"]  # garbage and unplug remnants too
    assert c["lost"] > c["crc_errors"]
    assert r.episodes == 3 and r.episodes_detected == 3
    assert r.status_lines >= 100 and not r.status_errors  # at most one per read
    json.dumps(r.as_dict(), allow_nan=True)


def test_stream_tally_matches_its_own_bytes() -> None:
    """Unit check of the generator: frames and bytes add up to what it emitted."""
    s = SoakStream(
        load_default(),
        duration_s=30.0,
        rate_hz=1000.0,
        seed=5,
        error_rate=50.0,
        episode_every_s=None,
    )
    total = unplugs = 0
    while not s.exhausted:
        for piece in s.next_pieces():
            if isinstance(piece, Unplug):
                unplugs += 1
            else:
                total += len(piece)
    inj = s.injected
    assert unplugs == inj.reconnects > 0
    info_bytes = s.groups * len(encode_info(0, 0, s._info))
    # every byte is an info frame, a delivered or duplicated sample frame, or skipped
    assert total == info_bytes + 40 * (inj.frames + inj.duplicates) + inj.skipped_bytes
    assert s.total_samples == 30_000 and s.groups == -(-30_000 // GROUP_SAMPLES)


def test_bias_episode_is_in_the_samples() -> None:
    s = SoakStream(
        load_default(),
        duration_s=80.0,
        rate_hz=1000.0,
        seed=0,
        error_rate=0.0,
        episode_every_s=30.0,
    )
    assert len(s.episodes) == 1
    ep = s.episodes[0]
    assert ep.kind == "bias" and ep.t_start == 30.0
    dec = Decoder()
    blocks = []
    while not s.exhausted:
        blocks.append(dec.feed(b"".join(p for p in s.next_pieces() if isinstance(p, bytes))))
    t = np.concatenate([b.t for b in blocks])
    az = np.concatenate([b.accel[:, 2] for b in blocks])
    base = s._base_raw[: len(t), 5]
    inside = (t >= ep.t_start) & (t < ep.t_end)
    np.testing.assert_array_equal(az[inside] - base[inside], BIAS_EPISODE_COUNTS)
    np.testing.assert_array_equal(az[~inside], base[~inside])


def test_status_checker_rejects_malformed_lines() -> None:
    good = {
        "class": "STATUS",
        "format": "imudiag-status/1",
        "t": 1.0,
        "state": "ok",
        "faults": [],
        "counters": {
            k: 0 for k in ("bytes", "frames", "crc_errors", "skipped_bytes", "lost", "duplicates")
        },
    }
    check_status_line(good)
    for bad in (
        {**good, "state": "fine"},
        {**good, "t": "1"},
        {**good, "faults": [{"cause": "f0"}]},
        {**good, "counters": {**good["counters"], "lost": -1}},
        {k: v for k, v in good.items() if k != "counters"},
        {k: v for k, v in good.items() if k != "class"},
        {**good, "format": "imudiag-status/2"},
    ):
        with pytest.raises(StatusLineError):
            check_status_line(bad)
    stream = StatusStream()
    stream.write(json.dumps(good) + "\n" + json.dumps({**good, "t": 0.5}) + "\nnot json\n")
    assert stream.lines == 3 and len(stream.errors) == 2


def test_episode_judge_counts_false_alarms() -> None:
    from soak.stream import Episode

    judge = EpisodeJudge([Episode("bias", 100.0, 110.0)])
    judge.observe(50.0, [{"triad": "gyro", "sensor": "gz", "cause": "f0"}])  # outside: false
    judge.observe(51.0, [])
    judge.observe(101.0, [{"triad": "accel", "cause": "f0"}])  # the episode
    assert judge.detected == [True] and judge.false_alarms == 1


def test_counters_dict_has_every_counter() -> None:
    """Counters.as_dict is written out by hand (speed): it must list every field."""
    from dataclasses import fields

    from imudiag.drivers.base import Counters

    c = Counters(*range(1, len(fields(Counters)) + 1))
    assert c.as_dict() == {f.name: getattr(c, f.name) for f in fields(Counters)}
