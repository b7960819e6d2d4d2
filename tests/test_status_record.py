"""Issue 12 item 15: the status record is built by the status module, from what the daemon
holds, with the contract's keys first and the verdict from the faults in force."""

from __future__ import annotations

from imudiag.certificate import load_default as load_certificate
from imudiag.monitor import Monitor
from imudiag.reports import CLASSES, STATUS_FORMAT
from imudiag.service.status import diagnosis_verdict, noise_object, status_record


def test_record_starts_with_the_contract_keys() -> None:
    cert = load_certificate()
    monitor = Monitor(cert)
    rec = status_record(
        t=12.3456789,
        state="ok",
        faults=[],
        counters={"frames": 3},
        link="connected",
        monitor=monitor,
        certificate=cert,
        reloads=2,
    )
    assert list(rec)[:6] == ["class", "format", "t", "state", "faults", "counters"]
    assert (rec["class"], rec["format"]) == (CLASSES[STATUS_FORMAT], STATUS_FORMAT)
    assert rec["t"] == 12.345679  # s, rounded to the microsecond
    assert set(rec["f0"]) == {"accel", "gyro"} and rec["certificate"]["reloads"] == 2
    assert rec["f0"]["accel"]["last"] is None  # no sample yet: null, never NaN in JSON


def test_verdict_is_the_faults_in_force_never_a_latch() -> None:
    fault = {"triad": "accel", "sensor": "ax", "cause": "bias"}
    assert diagnosis_verdict([fault], [], raised=1) == {
        "accel": "fault",
        "gyro": "ok",
        "raised": 1,
    }
    # the fault has cleared: ok again, and only the counter remembers it
    assert diagnosis_verdict([], ["gyro"], raised=1) == {
        "accel": "ok",
        "gyro": "undetermined",
        "raised": 1,
    }


def test_no_noise_object_before_a_figure() -> None:
    assert noise_object(None, load_certificate(), 600.0) is None
