"""A short seeded fuzz pass of the decoder, the CSV/NPZ readers and the certificate loader.

The long, time-bounded runs are ``python -m fuzz`` (hypothesis and atheris);
here every target gets a fixed-seed, bounded number of examples from the same
strategies and contracts (fuzz/targets.py), the crashes the fuzzers found are
regression tests, and every input saved under fuzz/crashes/ is replayed.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings

from fuzz.strategies import PROPERTIES
from fuzz.targets import (
    TARGETS,
    check_certificate,
    check_csv,
    check_decoder,
    check_npz,
    dump_doc,
    mutate_bytes,
    mutate_csv,
    npz_bytes,
    random_mutations,
    seed_certificate_doc,
    seed_columns,
    seed_csv,
    seed_npz,
    seed_stream,
)
from imudiag.certificate import CertificateError, default_certificate_path, loads
from imudiag.drivers.wire import Decoder, encode_samples
from imudiag.logs import LogError, open_log

CRASH_DIR = Path(__file__).resolve().parent.parent / "fuzz" / "crashes"

EXAMPLES = {"decoder": 80, "csv": 60, "npz": 60, "certificate": 40}


@pytest.mark.parametrize("target", sorted(EXAMPLES))
def test_seeded_hypothesis_pass(target: str) -> None:
    strategy, prop, _ = PROPERTIES[target]
    test = settings(
        max_examples=EXAMPLES[target],
        deadline=None,
        database=None,
        derandomize=True,
        suppress_health_check=list(HealthCheck),
    )(given(strategy)(prop))
    test()


def test_seeded_mutation_pass_every_target() -> None:
    """A numpy-seeded pass: valid seeds with random byte/text mutations, every target."""
    rng = np.random.default_rng(20261121)
    cert_text = dump_doc(seed_certificate_doc()).encode("utf-8")
    for i in range(40):
        muts = random_mutations(rng, int(rng.integers(1, 6)))
        stream = seed_stream(rng, int(rng.integers(1, 50)))
        check_decoder(mutate_bytes(stream, muts), sorted(rng.integers(0, len(stream), 3).tolist()))
        text = seed_csv(rng, int(rng.integers(1, 8)))
        text_ops = [
            (
                int(rng.integers(0, 10)),
                float(rng.random()),
                float(rng.random()),
                int(rng.integers(0, 100)),
            )
            for _ in range(2)
        ]
        check_csv(
            mutate_csv(text, text_ops).encode("utf-8"),
            block_size=int(rng.integers(1, 4)),
            gz=bool(i % 2),
        )
        check_npz(
            mutate_bytes(seed_npz(rng, 5, compressed=bool(i % 2)), muts),
            block_size=int(rng.integers(1, 4)),
        )
        check_certificate(mutate_bytes(cert_text, muts).decode("utf-8", "replace"))


def test_valid_seeds_are_accepted(tmp_path: Path) -> None:
    """The fuzzers start from inputs the code accepts (else they only test rejection)."""
    rng = np.random.default_rng(1)
    p = tmp_path / "a.csv"
    p.write_text(seed_csv(rng, 10))
    with open_log(p, 3) as r:
        assert sum(len(b) for b in r) == 10
    p = tmp_path / "a.npz"
    p.write_bytes(seed_npz(rng, 10, compressed=True))
    with open_log(p, 4) as r:
        assert sum(len(b) for b in r) == 10
        assert r.meta["device"] == "fuzz"
    assert loads(dump_doc(seed_certificate_doc())).sample_rate == 200


# -- regressions: crashes the fuzzers found ------------------------------------------------


def test_regression_certificate_integer_beyond_float_range() -> None:
    """fuzz/ found: a 400-digit integer raised OverflowError instead of CertificateError."""
    doc = seed_certificate_doc()
    doc["accel"]["limits"]["misalignment"][2] = 10**400
    with pytest.raises(CertificateError) as exc:
        loads(yaml.safe_dump(doc))
    assert exc.value.key == "accel.limits.misalignment[2]"
    check_certificate(yaml.safe_dump(doc))


def _npz_with_bad_local_header() -> bytes:
    """A valid NPZ whose first member's local header magic is damaged ('PK' -> 'QK')."""
    data = bytearray(seed_npz(np.random.default_rng(3), 4))
    assert data[:2] == b"PK"
    data[0] = ord("Q")
    return bytes(data)


def test_regression_npz_damaged_local_header(tmp_path: Path) -> None:
    """fuzz/ found: zipfile.BadZipFile escaped from the NPZ reader's header pass."""
    p = tmp_path / "bad.npz"
    p.write_bytes(_npz_with_bad_local_header())
    with pytest.raises(LogError) as exc:
        with open_log(p) as r:
            list(r)
    assert str(p) in str(exc.value) and "zip" in exc.value.reason
    check_npz(_npz_with_bad_local_header())


def test_regression_npz_unsupported_compression(tmp_path: Path) -> None:
    """A member with an unknown compression method is bad input, not NotImplementedError."""
    buf = io.BytesIO()
    cols = seed_columns(np.random.default_rng(4), 4)
    with zipfile.ZipFile(buf, "w") as zf:
        for name, arr in cols.items():
            b = io.BytesIO()
            np.save(b, arr)
            zf.writestr(name + ".npy", b.getvalue())
    data = bytearray(buf.getvalue())
    # compression method 99 in the first central-directory entry (zipfile reads that one)
    central = data.index(b"PK\x01\x02")
    data[central + 10 : central + 12] = (99).to_bytes(2, "little")
    p = tmp_path / "method.npz"
    p.write_bytes(bytes(data))
    with pytest.raises(LogError):
        with open_log(p) as r:
            list(r)


def test_npz_object_array_is_refused_not_unpickled(tmp_path: Path) -> None:
    cols = dict(seed_columns(np.random.default_rng(5), 4))
    cols["gx"] = np.array([object()] * 4, dtype=object)
    p = tmp_path / "obj.npz"
    p.write_bytes(npz_bytes(cols))
    with pytest.raises(LogError) as exc:
        with open_log(p) as r:
            list(r)
    assert "'gx'" in exc.value.reason


def test_npz_meta_not_an_object_is_refused(tmp_path: Path) -> None:
    cols = dict(seed_columns(np.random.default_rng(6), 4))
    cols["meta"] = np.array(json.dumps([1, 2]))
    p = tmp_path / "meta.npz"
    p.write_bytes(npz_bytes(cols))
    with pytest.raises(LogError):
        open_log(p)


def test_regression_decoder_sync_straddling_a_chunk_after_a_bad_frame() -> None:
    """atheris found: a failed frame whose last byte is the 0xAA of a real frame's sync,
    with the chunk ending there, lost the real frame (the output depended on chunking)."""
    real = encode_samples(7, np.array([1000]), np.arange(6).reshape(1, 6))
    false = b"\xaa\x55\x01\x22" + bytes(range(1, 36))  # 39 bytes, then the real frame
    data = false + real
    whole = Decoder()
    assert len(whole.feed(data)) + len(whole.finish()) == 1
    chunked = Decoder()
    out = [chunked.feed(data[:40]), chunked.feed(data[40:]), chunked.finish()]
    assert sum(len(b) for b in out) == 1
    assert chunked.counters == whole.counters
    assert whole.counters.crc_errors == 1 and whole.counters.skipped_bytes == 39
    check_decoder(data, [40])


def test_regression_certificate_impossible_date() -> None:
    """atheris found: YAML's date 2026-13-01 raised ValueError from the YAML loader."""
    text = default_certificate_path().read_text().replace("2026-11-01", "2026-13-01")
    with pytest.raises(CertificateError) as exc:
        loads(text, source="cert.yaml")
    assert "month" in exc.value.reason
    check_certificate(text)


def test_regression_npz_header_that_does_not_tokenize(tmp_path: Path) -> None:
    """atheris found: an .npy header numpy cannot tokenize raised tokenize.TokenError."""
    cols = seed_columns(np.random.default_rng(7), 4)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, arr in cols.items():
            b = io.BytesIO()
            np.save(b, arr)
            raw = b.getvalue()
            if name == "gx":  # an unterminated bracket in the header dict
                raw = raw.replace(b"'shape': (4,)", b"'shape': ((4,")
            zf.writestr(name + ".npy", raw)
    p = tmp_path / "header.npz"
    p.write_bytes(buf.getvalue())
    with pytest.raises(LogError) as exc:
        with open_log(p) as r:
            list(r)
    assert "'gx'" in exc.value.reason
    check_npz(buf.getvalue())


def test_regression_csv_lone_cr_last_line(tmp_path: Path) -> None:
    """hypothesis found: a last line of a lone "\r" was an error only in a block of its own."""
    text = seed_csv(np.random.default_rng(8), 5) + "\n\r"
    p = tmp_path / "cr.csv"
    p.write_text(text, newline="")
    for block in (1, 2, 5, 65536):
        with open_log(p, block) as r:
            assert sum(len(b) for b in r) == 5
    check_csv(text.encode(), block_size=1)


def test_saved_fuzz_crashes_replay() -> None:
    """Every input a fuzz run saved under fuzz/crashes/ must now pass its target's contract.

    The folder and its inputs are part of the tree (README "Fuzzing"): a missing folder, an
    empty one or an input no target claims fails here instead of passing with nothing run.
    """
    assert CRASH_DIR.is_dir(), f"{CRASH_DIR}: the saved fuzz crashes are missing"
    saved = sorted(CRASH_DIR.glob("*.bin"))
    assert saved, f"{CRASH_DIR}: no saved crash input (*.bin)"
    for path in saved:
        target = path.name.split("-")[0]
        assert target in TARGETS, f"{path.name}: no fuzz target {target!r}"
        TARGETS[target][0](path.read_bytes())
