"""``isensor://``: an ADIS16475-2 behind a fake iSensor SPI Buffer board on a real pty.

The board's command line is answered by :class:`imudiag.bench.fake_isensor.FakeISensorBoard`;
the streamed buffer entries are built here, by hand, from the board's
REGISTER_DEFINITION.md (UTC, timestamp, BUF_SIG = sum of the other words, DATA) and the
ADIS1647x burst (a reply word, DIAG_STAT, gyro x y z, accel x y z, TEMP_OUT, DATA_CNTR,
checksum = byte sum of DIAG_STAT .. DATA_CNTR), with the data sheet's LSB sizes.
"""

from __future__ import annotations

import numpy as np
import pytest

from imudiag.bench.fake_isensor import FakeISensorBoard
from imudiag.bench.pty import PtyPair
from imudiag.certificate import datasheet_path, load
from imudiag.drivers.base import open_source
from imudiag.drivers.isensor import MODELS
from imudiag.drivers.reconnect import ReconnectingSource
from imudiag.errors import SourceError
from imudiag.samples import FLAG_ADC_ERROR, FLAG_SELF_TEST, SampleBlock
from tests.device_sessions import RATE_HZ, DaemonThread, judge_session, session_samples
from tests.helpers import read_samples, read_until_state

#: the real-time tier (tests/conftest.py): ptys and a daemon thread against a fake iSensor board
pytestmark = pytest.mark.realtime

GYRO_LSB = 1 / 40  #: ADIS16475-2: deg/s per LSB of the 16-bit output (data sheet Table 1)
ACCEL_LSB = 1 / 4000  #: ADIS16475: g per LSB (0.25 mg)
TEMP_LSB = 0.1  #: degC per LSB


def entry(ts_us: int, count: int, gyro, accel, diag: int = 0, temp_c: float = 25.0) -> bytes:
    """One buffer entry line of an ADIS16475 16-bit burst."""
    g = [int(round(v / GYRO_LSB)) & 0xFFFF for v in gyro]
    a = [int(round(v / ACCEL_LSB)) & 0xFFFF for v in accel]
    burst = [diag, *g, *a, int(round(temp_c / TEMP_LSB)) & 0xFFFF, count & 0xFFFF]
    checksum = sum((w & 0xFF) + (w >> 8) for w in burst) & 0xFFFF
    data = [0x0000, *burst, checksum]  # DATA_0 is the reply while the command word goes out
    head = [0x0000, 0x0000, ts_us & 0xFFFF, (ts_us >> 16) & 0xFFFF]
    sig = (sum(head) + sum(data)) & 0xFFFF
    return (",".join(f"{w:04X}" for w in [*head, sig, *data]) + "\r\n").encode("ascii")


def lines_of(block: SampleBlock, first_count: int = 1) -> list[bytes]:
    ts = np.rint(block.t * 1e6).astype(np.int64)
    return [
        entry(int(ts[i]) & 0xFFFFFFFF, first_count + i, block.gyro[i], block.accel[i])
        for i in range(len(block))
    ]


def still(n: int, t0: float = 0.001) -> SampleBlock:
    t = t0 + np.arange(n) / RATE_HZ
    return SampleBlock(
        t=t,
        gyro=np.tile([0.5, -0.25, 1.0], (n, 1)),
        accel=np.tile([0.01, -0.02, 1.0], (n, 1)),
    )


@pytest.fixture
def board():
    with PtyPair() as pair:
        fake = FakeISensorBoard(pair, prod_id=16475, range_model=2, serial=0x0A1B)
        fake.start()
        yield pair, fake
        fake.stop()


def test_identity_configuration_and_values(board):
    pair, fake = board
    with open_source(f"isensor://{pair.slave_path}?rate=200") as src:
        fake.queue(lines_of(still(30)))
        got = read_samples(src, 30)
        info = src.device_info
    assert len(got) == 30
    assert np.allclose(got.gyro[0], [0.5, -0.25, 1.0], atol=GYRO_LSB / 2)
    assert np.allclose(got.accel[0], [0.01, -0.02, 1.0], atol=ACCEL_LSB / 2)
    assert np.allclose(got.t, 0.001 + np.arange(30) / RATE_HZ, atol=1e-9)
    assert np.allclose(got.temp, 25.0)
    assert got.meta["units"] == {"gyro": "deg/s", "accel": "g"}
    assert info["vendor"] == "Analog Devices" and info["product"] == "ADIS16475-2"
    assert info["serial"] == "0A1B" and info["firmware"] == "1.07"
    assert info["datasheet"] == "adis16475-2" and datasheet_path("adis16475-2")
    assert info["board"]["firmware"] == "1.18"
    # the buffered burst capture was configured as the board's documents say
    cmds = fake.commands
    assert cmds.index("stream 1") < cmds.index("write 0 FF")
    assert "write 13 68" in cmds and "write 12 0" in cmds  # BUF_WRITE_0 = 0x6800
    assert "write 4 16" in cmds  # BUF_LEN = 22 bytes
    assert "write 64 9" in cmds  # DEC_RATE 9: 2000 Hz / 10 = 200 Hz


def test_every_supported_part_has_its_table_row_and_certificate():
    for part in ("adis16470", "adis16475", "adis16477", "adis16495", "adis16505", "adis16507"):
        names = [m for m in MODELS if m.startswith(part)]
        assert names, part
        for name in names:
            cert = load(datasheet_path(name))
            assert cert.accel.output_unit == MODELS[name].accel_unit
            assert cert.gyro.output_unit == "deg/s"


def test_session_reaches_ok_and_names_the_bias_within_the_native_time(board, tmp_path):
    pair, fake = board
    cert = load(datasheet_path("adis16475-2"))
    cert.sample_rate = RATE_HZ  # the rate this session runs at (DEC_RATE 9)
    cert_path = tmp_path / "adis16475-2-200hz.yaml"
    cert.save(cert_path)
    block = session_samples(cert)
    url = f"isensor://{pair.slave_path}?rate=200"
    with DaemonThread(url, str(cert_path)) as d:
        d.wait_connected()
        fake.queue(lines_of(block))
        t_end = float(block.t[-1])
        d.wait(lambda s: s["t"] is not None and s["t"] >= t_end - 1e-6, timeout_s=120)
        last = d.sink.lines[-1]
    c = last["counters"]
    assert c["frames"] == len(block) and c["crc_errors"] == 0 and c["lost"] == 0
    judge_session(d.sink.lines)


def test_garbage_and_checksum_errors_are_counted_and_skipped(board):
    pair, fake = board
    block = still(60)
    lines = lines_of(block)
    garbage = b"\x00\xffnot an entry\r\n" + bytes(range(32, 100)) + b"\n"
    bad_sig = bytearray(lines[20])
    bad_sig[22] = ord("0") if bad_sig[22] != ord("0") else ord("1")  # a digit of SIG
    bad_burst = entry(int(round(block.t[30] * 1e6)), 31, block.gyro[30], block.accel[30])
    words = bad_burst.decode().strip().split(",")
    words[-1] = f"{(int(words[-1], 16) + 1) & 0xFFFF:04X}"  # the IMU's checksum off by one
    words[4] = f"{(int(words[4], 16) + 1) & 0xFFFF:04X}"  # (BUF_SIG kept consistent)
    bad_burst = (",".join(words) + "\r\n").encode()
    stream = [*lines[:10], garbage, *lines[10:20], bytes(bad_sig), *lines[21:30], bad_burst]
    stream += lines[31:]
    with open_source(f"isensor://{pair.slave_path}") as src:
        fake.queue(stream)
        got = read_samples(src, 58, timeout_s=5)
        c = src.counters
        dec = src.decoder
    assert len(got) == 58
    assert c.crc_errors == 2
    assert c.skipped_bytes == len(garbage) + len(bad_sig) + len(bad_burst)
    assert c.lost == 2  # DATA_CNTR 21 and 31 never arrived
    assert c.bytes == dec.frame_bytes + c.skipped_bytes + dec.pending_bytes
    assert np.allclose(got.t, np.delete(block.t, [20, 30]), atol=1e-9)


def test_self_test_command_flags_samples_and_diag_stat_sets_adc_error():
    with PtyPair() as pair:
        fake = FakeISensorBoard(pair, prod_id=16475, range_model=2, self_test_fails=True)
        fake.start()
        try:
            with open_source(f"isensor://{pair.slave_path}?rate=200") as src:
                fake.queue(lines_of(still(20)))
                before = read_samples(src, 20)
                src.write_command("SELFTEST")
                fake.queue(lines_of(still(40, t0=0.101), first_count=21))
                after = read_samples(src, 40)
                info = src.device_info
        finally:
            fake.stop()
    assert fake.self_tests == 1
    assert before.flags is not None and not np.any(before.flags)
    assert after.flags is not None
    flagged = (after.flags & FLAG_SELF_TEST) != 0
    assert flagged[0] and np.count_nonzero(flagged) == 10  # 0.05 s at 200 Hz
    assert np.all(after.flags[~flagged] & FLAG_ADC_ERROR)  # DIAG_STAT bit 5: sensor failure
    assert info["self_test"]["result"] == "fail" and info["self_test"]["count"] == 1


def test_unplug_and_replug_recover(tmp_path):
    link = tmp_path / "imu0"
    first = PtyPair(link=link)
    fake1 = FakeISensorBoard(first, prod_id=16475, range_model=2)
    fake1.start()
    src = ReconnectingSource(f"isensor://{link}", min_backoff_s=0.02, max_backoff_s=0.1)
    try:
        src.open()
        fake1.queue(lines_of(still(40)))
        got1 = read_samples(src, 40)
        fake1.stop()
        first.close_master()
        assert read_until_state(src, "reconnecting", 50) == "reconnecting"
        first.close()
        with PtyPair(link=link) as second:
            fake2 = FakeISensorBoard(second, prod_id=16475, range_model=2)
            fake2.start()
            try:
                assert read_until_state(src, "connected") == "connected"
                assert src.reconnects == 1
                fake2.queue(lines_of(still(40, t0=0.201), first_count=41))
                got2 = read_samples(src, 40)
            finally:
                fake2.stop()
    finally:
        src.close()
        first.close()
    assert len(got1) == 40 and len(got2) == 40 and got2.t[0] > got1.t[-1]
    assert src.counters.frames == 80 and src.counters.lost == 0


def test_unknown_part_and_silent_port_are_refused():
    with PtyPair() as pair:
        fake = FakeISensorBoard(pair, prod_id=16999)
        fake.start()
        try:
            with pytest.raises(SourceError, match="PROD_ID 16999 is not a supported part"):
                open_source(f"isensor://{pair.slave_path}").open()
        finally:
            fake.stop()
    with PtyPair() as pair, pytest.raises(SourceError, match="no answer"):
        open_source(f"isensor://{pair.slave_path}?timeout=0.3").open()


def test_daemon_sends_the_self_test_command(board):
    pair, fake = board
    cert = str(datasheet_path("adis16475-2"))
    with DaemonThread(f"isensor://{pair.slave_path}?rate=200", cert) as d:
        d.wait_connected()
        fake.queue(lines_of(still(40)))
        d.wait(lambda s: s["counters"]["frames"] >= 40)
        d.daemon.request_command("SELFTEST")
        d.daemon.request_command("REBOOT")  # not a command of the device: noted, not sent
        d.wait(lambda s: fake.self_tests == 1)  # the board has run it (an event, any line)
        fake.queue(lines_of(still(40, t0=0.201), first_count=41))
        noted = d.wait(lambda s: s["counters"]["frames"] >= 80 and "notes" in s)
        info = d.daemon.source.device_info
    assert fake.self_tests == 1
    assert info["self_test"] == {"count": 1, "result": "pass", "t": pytest.approx(0.201)}
    device = noted["device"]  # what the daemon is talking to, in its status
    assert device["product"] == "ADIS16475-2" and device["prod_id"] == 16475
    assert device["serial"] == "0A1B" and device["firmware"] == "1.07"
    assert device["datasheet"] == "adis16475-2" and device["self_test"]["result"] == "pass"
    assert any("'REBOOT' not sent" in n for n in noted["notes"])


def crc32_bitwise(data: bytes) -> int:
    """CRC-32 as the ADIS16495 data sheet states it (IEEE 802.3 polynomial 0x04C11DB7,
    initial value 0xFFFFFFFF, final XOR 0xFFFFFFFF, bits least significant first), one
    bit at a time: the test's own, not the source's table-driven zlib."""
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0xEDB88320 if crc & 1 else 0)  # 0x04C11DB7 reflected
    return crc ^ 0xFFFFFFFF


def entry_1649x(
    ts_us: int, count: int, gyro, accel, sys_e_flag: int = 0, two_ids: bool = False
) -> bytes:
    """One buffer entry of an ADIS16495-2 burst (ADIS1649x data sheet: burst ID 0xA5A5,
    twice at a fast SPI clock, SYS_E_FLAG, TEMP_OUT, then each output as _LOW and _OUT
    words, DATA_CNT, then CRC_LWR and CRC_UPR: the CRC-32 of the words SYS_E_FLAG ..
    DATA_CNT, each low byte first)."""
    g_lsb, a_lsb = 450 / 18000 / 65536, 8 / 32000 / 65536  # deg/s and g per 32-bit LSB
    body = [sys_e_flag, int(round(25.0 / 0.0125))]
    for v, lsb in [*((x, g_lsb) for x in gyro), *((x, a_lsb) for x in accel)]:
        raw = int(round(v / lsb)) & 0xFFFFFFFF
        body += [raw & 0xFFFF, raw >> 16]
    body += [count & 0xFFFF]
    crc = crc32_bitwise(b"".join(w.to_bytes(2, "little") for w in body))
    words = [0xA5A5, 0xA5A5] if two_ids else [0xA5A5]
    words += [*body, crc & 0xFFFF, crc >> 16]
    data = [0x0000, *words] + [0x0000] * (19 - len(words))  # 20 words: BUF_LEN 40
    head = [0, 0, ts_us & 0xFFFF, ts_us >> 16]
    sig = (sum(head) + sum(data)) & 0xFFFF
    return (",".join(f"{w:04X}" for w in [*head, sig, *data]) + "\r\n").encode("ascii")


def with_word(line: bytes, index: int, value: int) -> bytes:
    """``line`` (an entry) with word ``index`` (of DATA_0..) replaced and its line
    signature made good again: only the burst's own check can fail."""
    words = [int(w, 16) for w in line.strip().split(b",")]
    words[5 + index] = value
    words[4] = (sum(words) - words[4]) & 0xFFFF
    return (",".join(f"{w:04X}" for w in words) + "\r\n").encode("ascii")


def test_adis16495_burst_crc32_mismatches_are_counted_and_skipped():
    """A burst whose CRC-32 fails (a flipped output bit, a flipped CRC bit) under a good
    line signature is a checksum error and no sample; one with two leading burst IDs (a
    fast SPI clock) decodes and checks from the second."""
    with PtyPair() as pair:
        fake = FakeISensorBoard(pair, prod_id=16495)
        fake.start()
        try:
            with open_source(f"isensor://{pair.slave_path}?model=adis16495-2") as src:
                lines = [
                    entry_1649x(
                        1000 + 500 * i, i, [0.5, -1.0, 2.0], [0.0, 0.0, 1.0], two_ids=i == 7
                    )
                    for i in range(12)
                ]
                word = int(lines[3].split(b",")[5 + 5], 16)  # DATA_5: X_GYRO_OUT
                lines[3] = with_word(lines[3], 5, word ^ 0x0004)
                crc_upr = int(lines[9].split(b",")[5 + 18], 16)
                lines[9] = with_word(lines[9], 18, crc_upr ^ 0x8000)
                fake.queue(lines)
                got = read_samples(src, 10)
                c = src.counters
        finally:
            fake.stop()
    assert len(got) == 10 and c.crc_errors == 2 and c.lost == 2
    kept = [i for i in range(12) if i not in (3, 9)]
    assert np.allclose(got.t, 0.001 + 0.0005 * np.array(kept))
    assert np.allclose(got.gyro, [0.5, -1.0, 2.0], atol=1e-6)  # the two-ID burst too
    assert np.allclose(got.accel, [0.0, 0.0, 1.0], atol=1e-8)


def test_crc32_bitwise_is_the_ieee_crc():
    assert crc32_bitwise(b"123456789") == 0xCBF43926  # the CRC-32 check value


def test_adis16495_32_bit_burst():
    with PtyPair() as pair:
        fake = FakeISensorBoard(pair, prod_id=16495, serial=0x00C3, firmware=0x0105)
        fake.start()
        try:
            with open_source(f"isensor://{pair.slave_path}?model=adis16495-2") as src:
                lines = [
                    entry_1649x(1000 + 500 * i, i, [0.123456, -45.5, 300.0], [0.0012, -0.5, 1.0])
                    for i in range(10)
                ]
                lines[4] = entry_1649x(3000, 4, [0, 0, 0], [0, 0, 1.0], sys_e_flag=0x0020)
                fake.queue(lines)
                got = read_samples(src, 10)
                info = src.device_info
        finally:
            fake.stop()
    assert "write 13 7C" in fake.commands and "write 4 28" in fake.commands  # 0x7C00, 40 B
    assert info["product"] == "ADIS16495-2" and info["serial"] == "00C3"
    assert info["firmware"] == "1.05" and info["datasheet"] == "adis16495-2"
    assert len(got) == 10 and np.allclose(got.t, 0.001 + 0.0005 * np.arange(10))
    assert np.allclose(got.gyro[0], [0.123456, -45.5, 300.0], atol=1e-6)
    assert np.allclose(got.accel[0], [0.0012, -0.5, 1.0], atol=1e-8)
    assert np.allclose(got.temp, 25.0)
    assert got.flags is not None and got.flags[4] & FLAG_ADC_ERROR
    assert not np.any(np.delete(got.flags, 4))
    with pytest.raises(SourceError, match="model=adis16495-2"):
        with PtyPair() as pair:
            fake = FakeISensorBoard(pair, prod_id=16495)
            fake.start()
            try:
                open_source(f"isensor://{pair.slave_path}").open()
            finally:
                fake.stop()


def test_a_bench_scenario_served_by_the_fake_device(tmp_path):
    """`python -m imudiag.bench.fake_device isensor`: the bench's sensor-faults scenario on
    a fake ADIS16475-2 behind the board (the +38-limit az bias from t = 2 s)."""
    from imudiag.bench.fake_device import serve
    from imudiag.bench.scenario import load_bundled

    scenario = load_bundled("sensor-faults").with_options(speed=10.0)
    link = tmp_path / "isensor0"
    board, thread = serve("isensor", scenario, "adis16475-2", 200.0, link=link)
    try:
        with open_source(f"isensor://{link}") as src:
            got = read_samples(src, 700, timeout_s=20)
            info = src.device_info
    finally:
        board.stop()
        board.pair.close()
    assert info["product"] == "ADIS16475-2" and len(got) >= 700  # whole 0.05 s chunks
    assert np.allclose(got.t, np.arange(len(got)) / 200.0)
    jump = got.accel[450:650, 2].mean() - got.accel[:350, 2].mean()
    assert jump == pytest.approx(800 / 21.0 * 0.002, abs=0.002)
