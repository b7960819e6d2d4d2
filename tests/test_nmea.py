"""NMEA 0183-style status sentences and the non-blocking serial sink (real ptys, loop://)."""

from __future__ import annotations

import os
import re
import select
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from imudiag.service.nmea import (
    COUNTER_KEYS,
    MAX_SENTENCE_CHARS,
    NmeaError,
    SerialStatusSink,
    StatusLinkError,
    checksum,
    counters_sentence,
    decode_sentence,
    fault_sentences,
    health_sentence,
    parse_sentence,
    sentence,
    split_sentences,
    status_sentences,
)

STATUS_OK = {
    "t": 12.34,
    "state": "ok",
    "faults": [],
    "counters": {
        "bytes": 4000,
        "frames": 100,
        "crc_errors": 0,
        "skipped_bytes": 0,
        "lost": 0,
        "duplicates": 0,
    },
}
STATUS_FAULT = {
    "t": 95.25,
    "state": "fault",
    "faults": [
        {"triad": "accel", "sensor": "ax", "cause": "bias", "estimate": 151.25},
        {"triad": "accel", "sensor": None, "cause": "f0"},
        {"triad": "gyro", "sensor": "gx/gy", "cause": "misalignment", "estimate": -0.0071},
    ],
    "counters": {
        "bytes": 123456,
        "frames": 3000,
        "crc_errors": 2,
        "skipped_bytes": 17,
        "lost": 3,
        "duplicates": 1,
    },
    "f0": {"accel": {"checked": 9000, "failed": 12}, "gyro": {"checked": 0, "failed": 0}},
}


# ---------------------------------------------------------------------------
# format and checksum


def test_checksum_of_the_textbook_gga_sentence() -> None:
    """The NMEA 0183 GGA example found in every receiver manual: checksum 0x47."""
    line = "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
    assert checksum(line[1:-5]) == 0x47
    s = parse_sentence(line)
    assert s.address == "GPGGA" and s.fields[0] == "123519" and len(s.fields) == 14


def test_sentence_framing() -> None:
    text = sentence("PIMDX", ["a", 1, None, "2.5"])
    assert text.startswith("$PIMDX,a,1,,2.5*") and text.endswith("\r\n")
    body = text[1 : text.index("*")]
    assert text[-4:-2] == f"{checksum(body):02X}"
    assert parse_sentence(text).fields == ("a", "1", "", "2.5")


def test_health_fault_counters_round_trip() -> None:
    h = decode_sentence(health_sentence(STATUS_FAULT))
    assert h == {
        "type": "health",
        "t": 95.25,
        "state": "fault",
        "n_faults": 3,
        "f0_failed_ratio": {"gyro": None, "accel": pytest.approx(12 / 9000, abs=1e-6)},
    }
    fs = [decode_sentence(x) for x in fault_sentences(STATUS_FAULT)]
    assert [(f["index"], f["count"]) for f in fs] == [(1, 3), (2, 3), (3, 3)]
    assert [(f["triad"], f["sensor"], f["cause"]) for f in fs] == [
        ("accel", "ax", "bias"),
        ("accel", None, "f0"),
        ("gyro", "gx/gy", "misalignment"),
    ]
    assert fs[0]["estimate"] == pytest.approx(151.25)
    assert fs[1]["estimate"] is None
    assert fs[2]["estimate"] == pytest.approx(-0.0071)
    c = decode_sentence(counters_sentence(STATUS_FAULT))
    assert c == {"type": "counters", "t": 95.25, "counters": STATUS_FAULT["counters"]}


def test_cycle_is_health_faults_counters() -> None:
    assert [parse_sentence(s).address for s in status_sentences(STATUS_OK)] == ["PIMDH", "PIMDC"]
    addresses = [parse_sentence(s).address for s in status_sentences(STATUS_FAULT)]
    assert addresses == ["PIMDH", "PIMDF", "PIMDF", "PIMDF", "PIMDC"]


def test_no_data_before_the_first_sample() -> None:
    status = {"t": None, "state": "no_data", "faults": [], "counters": {}}
    h = decode_sentence(health_sentence(status))
    assert h["t"] is None and h["state"] == "no_data" and h["n_faults"] == 0
    c = decode_sentence(counters_sentence(status))
    assert c["counters"] == dict.fromkeys(COUNTER_KEYS)


def test_extreme_values_fit_in_82_characters() -> None:
    big = {k: 10**15 + 123 for k in COUNTER_KEYS}
    status = {
        "t": 9_999_999.99,
        "state": "degraded",
        "counters": big,
        "faults": [
            {
                "triad": "accel",
                "sensor": "ax/ay",
                "cause": "scale_factor",
                "estimate": -1.23456789e-300,
            }
        ],
        "f0": {
            "gyro": {"checked": 10**12, "failed": 10**12},
            "accel": {"checked": 10**12, "failed": 1},
        },
    }
    for s in status_sentences(status):
        assert len(s) <= MAX_SENTENCE_CHARS, s
        parse_sentence(s)
    c = decode_sentence(counters_sentence(status))
    assert c["counters"]["bytes"] == (10**15 + 123) % 10**9


counter = st.integers(min_value=0, max_value=10**18)
status_strategy = st.fixed_dictionaries(
    {
        "t": st.one_of(st.none(), st.floats(min_value=0, max_value=9_999_999.99)),
        "state": st.sampled_from(["ok", "degraded", "fault", "no_data"]),
        "faults": st.lists(
            st.fixed_dictionaries(
                {
                    "triad": st.sampled_from(["gyro", "accel"]),
                    "sensor": st.sampled_from(
                        [None, "gx", "gy", "gz", "ax", "ay", "az", "ax/ay", "gy/gz"]
                    ),
                    "cause": st.sampled_from(
                        [
                            "f0",
                            "bias",
                            "scale_factor",
                            "misalignment",
                            "stuck",
                            "noise",
                            "saturation",
                        ]
                    ),
                    "estimate": st.one_of(
                        st.none(), st.floats(allow_nan=False, allow_infinity=False)
                    ),
                }
            ),
            max_size=6,
        ),
        "counters": st.fixed_dictionaries({k: counter for k in COUNTER_KEYS}),
    }
)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(status_strategy)
def test_every_status_gives_valid_sentences(status: dict) -> None:
    lines = status_sentences(status)
    assert len(lines) == 2 + len(status["faults"])
    decoded = [decode_sentence(s) for s in lines]
    assert all(len(s) <= MAX_SENTENCE_CHARS and s.endswith("\r\n") for s in lines)
    assert decoded[0]["state"] == status["state"]
    assert decoded[0]["n_faults"] == len(status["faults"])
    for f, d in zip(status["faults"], decoded[1:-1], strict=True):
        assert (d["triad"], d["sensor"], d["cause"]) == (f["triad"], f["sensor"], f["cause"])
        if f["estimate"] is None:
            assert d["estimate"] is None
        else:
            assert d["estimate"] == pytest.approx(f["estimate"], rel=1e-5, abs=1e-300)
    assert decoded[-1]["counters"] == {k: v % 10**9 for k, v in status["counters"].items()}


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("PIMDH,1.00,ok,0,,*00\r\n", "does not start with '$'"),
        ("$PIMDH,1.00,ok,0,,\r\n", "no '*hh' checksum"),
        ("$PIMDH,1.00,ok,0,,*ZZ\r\n", "not two hex digits"),
        ("$PIMDH,1.00,ok,0,,*00\r\n", "checksum mismatch"),
        ("$PIMDH," + "1" * 80 + "*00\r\n", "over 82"),
        ("$PIMDH,1.00,\x01ok,0,,*00\r\n", "non-printable"),
    ],
)
def test_parser_rejects(line: str, reason: str) -> None:
    with pytest.raises(NmeaError, match=re.escape(reason)):
        parse_sentence(line)


def test_a_single_flipped_character_is_caught() -> None:
    good = health_sentence(STATUS_FAULT)
    for i in range(1, good.index("*")):
        bad = good[:i] + ("X" if good[i] != "X" else "Y") + good[i + 1 :]
        with pytest.raises(NmeaError):
            decode_sentence(bad)


def test_decoder_checks_fields() -> None:
    with pytest.raises(NmeaError, match="unknown sentence"):
        decode_sentence(sentence("PIMDZ", ["1"]))
    with pytest.raises(NmeaError, match="expected 5 fields"):
        decode_sentence(sentence("PIMDH", ["1", "ok"]))
    with pytest.raises(NmeaError, match="unknown state"):
        decode_sentence(sentence("PIMDH", ["1", "fine", "0", "", ""]))
    with pytest.raises(NmeaError, match="not an integer"):
        decode_sentence(sentence("PIMDF", ["1", "a", "1", "accel", "ax", "bias", ""]))


def test_reserved_characters_in_a_field_are_refused() -> None:
    with pytest.raises(NmeaError, match="reserved"):
        sentence("PIMDF", ["accel", "ax,ay"])
    with pytest.raises(NmeaError, match="reserved"):
        health_sentence({"t": 1.0, "state": "ok*", "faults": [], "counters": {}})


def test_split_sentences_resynchronises_on_dollar() -> None:
    a, b = status_sentences(STATUS_OK)
    stream = (
        b"garbage"
        + a[:20].encode()
        + b.encode()  # a cut short, then b whole
        + a.encode()
        + b"$PIMDC,12.3"
    )
    lines, rest = split_sentences(stream)
    assert lines == [b[:-2], a[:-2]]
    assert rest == b"$PIMDC,12.3"
    for line in lines:
        parse_sentence(line)


# ---------------------------------------------------------------------------
# the serial sink


def _read_all(fd: int, quiet_s: float = 0.3, limit_s: float = 10.0) -> bytes:
    """Read ``fd`` until nothing arrives for ``quiet_s`` seconds."""
    out = bytearray()
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], quiet_s)
        if not ready:
            break
        try:
            chunk = os.read(fd, 65536)
        except OSError:
            break
        if not chunk:
            break
        out += chunk
    return bytes(out)


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    path = os.ttyname(slave)
    try:
        yield master, path
    finally:
        for fd in (master, slave):
            try:
                os.close(fd)
            except OSError:
                pass


@pytest.mark.realtime
def test_sink_over_a_pty_writes_valid_sentences(pty_pair) -> None:
    master, path = pty_pair
    with SerialStatusSink(path, rate_hz=2.0) as sink:
        assert sink.publish(STATUS_OK, now_s=0.0)
        assert not sink.publish(STATUS_OK, now_s=0.2)  # not due, nothing changed
        assert sink.publish(STATUS_OK, now_s=0.5)  # 1 / 2 Hz later
        assert sink.publish(STATUS_FAULT, now_s=0.6)  # a change goes out at once
        assert not sink.publish(STATUS_FAULT, now_s=0.7)
        data = _read_all(master)
    lines, rest = split_sentences(data)
    assert rest == b""
    decoded = [decode_sentence(x) for x in lines]
    assert [d["type"] for d in decoded] == (
        ["health", "counters"] * 2 + ["health", "fault", "fault", "fault", "counters"]
    )
    assert decoded[-5]["state"] == "fault" and decoded[-5]["n_faults"] == 3
    assert sink.written == 9 and sink.dropped == 0 and sink.cycles == 3


@pytest.mark.realtime
def test_sink_accepts_serial_scheme_urls(pty_pair) -> None:
    master, path = pty_pair
    with SerialStatusSink(f"serial://{path}?baud=115200", rate_hz=1.0) as sink:
        assert sink.port is not None and sink.port.baudrate == 115200
        sink.publish(STATUS_OK, now_s=0.0)
        lines, _ = split_sentences(_read_all(master))
    assert [parse_sentence(x).address for x in lines] == ["PIMDH", "PIMDC"]


@pytest.mark.realtime
def test_sink_over_loop_url() -> None:
    with SerialStatusSink("loop://", rate_hz=1.0) as sink:
        for k in range(5):
            sink.publish(STATUS_FAULT if k == 3 else STATUS_OK, now_s=float(k))
        port = sink.port
        assert port is not None
        port.timeout = 0.1  # read() returns what arrived within 0.1 s
        deadline = time.monotonic() + 5.0
        data = b""
        while data.count(b"\r\n") < 13 and time.monotonic() < deadline:
            data += port.read(4096)
        data += port.read(4096)  # and nothing more
    lines, rest = split_sentences(data)
    assert rest == b"" and len(lines) == 2 * 4 + 5  # four ok cycles (H, C), one with 3 faults
    assert all(decode_sentence(x) for x in lines)


@pytest.mark.realtime
def test_blocked_pty_consumer_never_blocks_publish(pty_pair) -> None:
    """Nobody reads the pty until its buffer is full: publish() never waits for the port,
    it counts drops (judged on events: no wall-clock bound)."""
    master, path = pty_pair
    # a write to the full pty blocks for up to the write timeout: make it far longer than
    # the test, so no write times out and every drop below is the queue overflowing while
    # the writer is stuck (a publish that waited for the port would never drop)
    sink = SerialStatusSink(path, rate_hz=10.0, queue_size=16, write_timeout_s=60.0)
    n_cycles = 3000  # ~ 3000 x 5 sentences x 60 bytes, far beyond the pty buffer
    try:
        for k in range(n_cycles):
            sink.publish(STATUS_FAULT, now_s=k * 0.125)
        assert sink.cycles == n_cycles
        assert sink.dropped > 0
        assert sink.written < n_cycles * 5
    finally:
        sink.close(timeout_s=0.5)  # gives up on the stuck receiver: cancels the write
    # all sentences are accounted for: written, dropped (a partial write may hold a cut sentence)
    assert sink.written + sink.dropped == n_cycles * 5
    data = _read_all(master)
    lines, _ = split_sentences(data)
    good = 0
    for line in lines:
        try:
            decode_sentence(line)
            good += 1
        except NmeaError:
            pass  # a sentence cut short by a write timeout: the receiver resyncs
    # every sentence counted as written reached the pty intact (but a cut last one)
    assert sink.written > 0 and good >= sink.written - 2


@pytest.mark.realtime
def test_blocked_loop_consumer_counts_drops() -> None:
    """loop:// holds 4 KiB; nobody reads it: later sentences time out or are dropped."""
    sink = SerialStatusSink("loop://", rate_hz=10.0, queue_size=8, write_timeout_s=0.1)
    try:
        for k in range(200):
            sink.publish(STATUS_OK, now_s=k * 0.125)
    finally:
        sink.close(timeout_s=0.3)
    assert sink.dropped > 0
    assert sink.written + sink.dropped == 400
    shortest = min(len(x) for x in status_sentences(STATUS_OK))
    assert sink.written <= 4096 // shortest + 1  # what fits in loop://'s buffer


@pytest.mark.realtime
def test_port_failure_is_counted_and_never_raises(pty_pair) -> None:
    """The far end goes away (master closed): writes fail, the sink drops and retries."""
    master, path = pty_pair
    sink = SerialStatusSink(path, rate_hz=10.0, reopen_s=0.05)
    try:
        sink.publish(STATUS_OK, now_s=0.0)
        assert _read_all(master, quiet_s=0.2).count(b"\r\n") == 2
        os.close(master)
        for k in range(1, 20):
            sink.publish(STATUS_OK, now_s=k * 0.125)
            time.sleep(0.01)
        deadline = time.monotonic() + 5.0
        while sink.pending and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        sink.close(timeout_s=0.5)
    assert sink.errors >= 1
    assert sink.dropped >= 1
    assert sink.written + sink.dropped == 40


def test_bad_status_url_is_a_clear_error(tmp_path) -> None:
    missing = tmp_path / "no-such-tty"
    with pytest.raises(StatusLinkError, match=f"status link {missing}"):
        SerialStatusSink(str(missing))
    with pytest.raises(StatusLinkError, match="bad baud rate"):
        SerialStatusSink("serial:///dev/null?baud=fast")
    with pytest.raises(ValueError, match="rate_hz"):
        SerialStatusSink("loop://", rate_hz=0)
