"""Fuzz targets: the frame decoder, the CSV and NPZ log readers, the certificate loader.

Each ``check_*`` function takes one input and raises :class:`FuzzFailure`
(or lets an unexpected exception through) when the code under test breaks
its contract:

- decoder: never raises; the byte accounting is exact
  (``bytes == frame_bytes + skipped_bytes`` after ``finish``); ``seq``
  strictly increasing, ``t`` non-decreasing, every counter >= 0; the output
  does not depend on how the bytes were chunked;
- CSV / NPZ readers: the only exception is :class:`imudiag.logs.LogError`; an
  accepted log has finite values, ``t`` strictly increasing across blocks,
  ``flags`` in 0..65535, and reads the same (data, or the same rejection)
  whatever the block size;
- certificate loader: the only exception is
  :class:`imudiag.certificate.CertificateError`; an accepted certificate has
  finite numbers and positive scale factors, runs its sensor model forward and
  inverse, and reads back the same after ``dumps``.

Also here: valid seed inputs for each target and the generic mutators the
hypothesis strategies and the seeded passes use.
"""

from __future__ import annotations

import copy
import gzip
import io
import json
import math
import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from imudiag.certificate import (
    CertificateError,
    default_certificate_path,
    loads,
)
from imudiag.drivers.wire import Decoder, encode_frame, encode_info, encode_samples
from imudiag.logs import LogError, open_log
from imudiag.samples import SampleBlock


class FuzzFailure(AssertionError):
    """The code under test broke its contract on a fuzz input."""


def _require(cond: bool, message: str) -> None:
    if not cond:
        raise FuzzFailure(message)


# -- frame decoder -------------------------------------------------------------------


def _decode(data: bytes, cuts: Sequence[int]) -> tuple[Decoder, SampleBlock]:
    dec = Decoder()
    blocks = []
    prev = 0
    for c in sorted({min(max(int(c), 0), len(data)) for c in cuts}) + [len(data)]:
        blocks.append(dec.feed(data[prev:c]))
        prev = c
    blocks.append(dec.finish())
    return dec, SampleBlock.concat(blocks)


def check_decoder(data: bytes, cuts: Sequence[int] = ()) -> None:
    """The wire decoder on ``data`` fed in pieces cut at ``cuts``."""
    dec, out = _decode(data, cuts)
    c = dec.counters
    _require(c.bytes == len(data), f"bytes {c.bytes} != {len(data)} fed")
    _require(
        c.bytes == dec.frame_bytes + c.skipped_bytes,
        f"accounting: bytes {c.bytes} != frame {dec.frame_bytes} + skipped {c.skipped_bytes}",
    )
    _require(min(c.as_dict().values()) >= 0, f"negative counter: {c}")
    _require(c.frames == len(out), f"frames {c.frames} != samples out {len(out)}")
    if len(out):
        _require(
            out.seq is not None and bool(np.all(np.diff(out.seq) > 0)),
            "seq not strictly increasing",
        )
        _require(bool(np.all(np.diff(out.t) >= 0)), "t goes backwards")
        _require(
            bool(np.all(np.isfinite(out.gyro)) and np.all(np.isfinite(out.accel))),
            "non-finite outputs",
        )
    if cuts:
        dec1, whole = _decode(data, ())
        _require(dec1.counters == c, f"counters depend on chunking: {dec1.counters} vs {c}")
        _require(
            len(whole) == len(out)
            and (
                not len(out)
                or (
                    np.array_equal(whole.t, out.t)
                    and np.array_equal(whole.gyro, out.gyro)
                    and np.array_equal(whole.accel, out.accel)
                )
            ),
            "samples depend on chunking",
        )


def seed_stream(rng: np.random.Generator, n: int = 60) -> bytes:
    """A plausible board stream: sample frames, an info frame, an unknown frame type."""
    raw = rng.integers(-(2**31), 2**31, (n, 6))
    seq = int(rng.integers(0, 65536))
    t0 = int(rng.integers(0, 2**32))
    k = n // 2
    return b"".join(
        [
            encode_samples(seq, t0 + 5000 * np.arange(k), raw[:k], rng.normal(25, 5, k)),
            encode_info(seq + k, t0 + 5000 * k, {"serial": "0001", "rate_hz": 200}),
            encode_frame(0x7E, seq + k + 1, t0 + 5000 * k + 1, rng.bytes(8)),
            encode_samples(seq + k + 2, t0 + 5000 * (k + 1 + np.arange(n - k)), raw[k:]),
        ]
    )


# -- byte and text mutations ------------------------------------------------------------

#: A mutation: (op, position fraction 0..1, value 0..255, length 1..64).
Mutation = tuple[int, float, int, int]
N_BYTE_OPS = 8


def mutate_bytes(data: bytes, ops: Sequence[Mutation]) -> bytes:
    """Apply byte mutations: flip, overwrite, insert, delete, repeat, swap, sync, truncate."""
    b = bytearray(data)
    for op, frac, value, length in ops:
        i = min(int(frac * len(b)), max(len(b) - 1, 0))
        if op == 0 and b:
            b[i] ^= 1 << (value % 8)
        elif op == 1 and b:
            b[i] = value
        elif op == 2:
            b[i:i] = bytes([value]) * length
        elif op == 3:
            del b[i : i + length]
        elif op == 4:
            b[i:i] = b[i : i + length]
        elif op == 5 and len(b) > 1:
            j = (i + length) % len(b)
            b[i], b[j] = b[j], b[i]
        elif op == 6:
            b[i:i] = b"\xaa\x55" + bytes([value])
        elif op == 7:
            del b[i + length :]
    return bytes(b)


def random_mutations(rng: np.random.Generator, k: int) -> list[Mutation]:
    """``k`` random byte mutations (the seeded, non-hypothesis form)."""
    return [
        (
            int(rng.integers(0, N_BYTE_OPS)),
            float(rng.random()),
            int(rng.integers(0, 256)),
            int(rng.integers(1, 65)),
        )
        for _ in range(k)
    ]


#: Tokens that break a numeric CSV field in interesting ways.
BAD_TOKENS = (
    "nan",
    "NaN",
    "inf",
    "-inf",
    "",
    "x",
    "1e999",
    "-1e999",
    "0x10",
    " 1",
    "+1",
    "1.5.2",
    "1,5",
    "\u00e9",
    "1e",
    "--1",
    "1_000",
    "True",
    "\x00",
    "9" * 400,
)

#: A text mutation: (op, line fraction, field fraction, token index).
TextMutation = tuple[int, float, float, int]
N_TEXT_OPS = 10


def mutate_csv(text: str, ops: Sequence[TextMutation]) -> str:
    """Line/field mutations of CSV text: bad tokens, lost and extra fields, moved lines..."""
    lines = text.split("\n")
    for op, lf, ff, tok in ops:
        if not lines:
            lines = [""]
        i = min(int(lf * len(lines)), len(lines) - 1)
        fields = lines[i].split(",")
        j = min(int(ff * len(fields)), len(fields) - 1)
        token = BAD_TOKENS[tok % len(BAD_TOKENS)]
        if op == 0:
            fields[j] = token
            lines[i] = ",".join(fields)
        elif op == 1 and len(fields) > 1:
            del fields[j]
            lines[i] = ",".join(fields)
        elif op == 2:
            fields.insert(j, "0")
            lines[i] = ",".join(fields)
        elif op == 3:
            del lines[i]
        elif op == 4:
            lines.insert(i, lines[i])
        elif op == 5 and len(lines) > 1:
            k = min(int(ff * len(lines)), len(lines) - 1)
            lines[i], lines[k] = lines[k], lines[i]
        elif op == 6:
            lines.insert(i, "# " + token + ": " + token)
        elif op == 7:
            lines.insert(i, "")
        elif op == 8:
            lines[i] = lines[i] + "\r"
        else:
            lines = lines[: i + 1]
    return "\n".join(lines)


# -- CSV and NPZ readers -----------------------------------------------------------------------


def _read_all(path: Path, block_size: int) -> tuple[str, Any]:
    """Read a whole log: ("ok", (meta, block)) or ("error", line) for a LogError."""
    try:
        with open_log(path, block_size) as reader:
            blocks = []
            last_t = -math.inf
            for b in reader:
                _require(len(b) > 0, "empty block yielded")
                _require(len(b) <= block_size, f"block of {len(b)} > block_size {block_size}")
                for name, arr in (("t", b.t), ("gyro", b.gyro), ("accel", b.accel)):
                    _require(bool(np.all(np.isfinite(arr))), f"accepted non-finite {name}")
                if b.temp is not None:
                    _require(bool(np.all(np.isfinite(b.temp))), "accepted non-finite temp")
                if b.flags is not None:
                    _require(b.flags.dtype == np.uint16, f"flags dtype {b.flags.dtype}")
                if b.seq is not None:
                    _require(bool(np.all(b.seq >= 0)), "accepted negative seq")
                _require(
                    float(b.t[0]) > last_t and bool(np.all(np.diff(b.t) > 0)),
                    "accepted t not strictly increasing",
                )
                last_t = float(b.t[-1])
                blocks.append(b)
            meta = dict(reader.meta)
    except LogError as exc:
        _require(str(path) in str(exc), f"LogError does not name the file: {exc}")
        _require(bool(exc.reason), "LogError without a reason")
        return "error", exc.line
    return "ok", (meta, SampleBlock.concat(blocks))


def _same(a: tuple[str, Any], b: tuple[str, Any]) -> bool:
    if a[0] != b[0]:
        return False
    if a[0] == "error":
        return True
    (ma, x), (mb, y) = a[1], b[1]
    if ma != mb or len(x) != len(y):
        return False
    for name in ("t", "gyro", "accel", "temp", "flags", "seq"):
        u, v = getattr(x, name), getattr(y, name)
        if (u is None) != (v is None) or (u is not None and not np.array_equal(u, v)):
            return False
    return True


def check_log_file(path: Path, block_size: int) -> None:
    """A log file read with ``block_size`` and with the default: same outcome, valid data."""
    small = _read_all(path, max(1, block_size))
    big = _read_all(path, 65536)
    _require(
        _same(small, big),
        f"outcome depends on block size: {small[0]} (block {block_size}) vs {big[0]}",
    )


def check_log_bytes(data: bytes, suffix: str, block_size: int) -> None:
    """``data`` written to a temporary ``*suffix`` file, then :func:`check_log_file`."""
    fd, name = tempfile.mkstemp(suffix=suffix, prefix="imudiag-fuzz-")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        check_log_file(Path(name), block_size)
    finally:
        os.unlink(name)


def check_csv(data: bytes, block_size: int = 3, gz: bool = False) -> None:
    """The CSV reader (``.csv``, or ``.csv.gz`` of ``data`` when ``gz``)."""
    if gz:
        data = gzip.compress(data, mtime=0)
    check_log_bytes(data, ".csv.gz" if gz else ".csv", block_size)


def check_npz(data: bytes, block_size: int = 3) -> None:
    """The NPZ reader on ``data`` as a ``.npz`` file."""
    check_log_bytes(data, ".npz", block_size)


COLUMNS = ("t", "gx", "gy", "gz", "ax", "ay", "az", "temp", "seq", "flags")


def seed_columns(rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """A valid sample log's columns: n samples at 200 Hz, counts around 32768."""
    return {
        "t": 100.0 + np.arange(n) / 200.0,
        **{c: np.round(32768 + rng.normal(0, 50, n)) for c in ("gx", "gy", "gz", "ax", "ay", "az")},
        "temp": np.round(25 + rng.normal(0, 0.1, n), 2),
        "seq": np.arange(n, dtype=np.int64) + 7,
        "flags": (rng.random(n) < 0.1).astype(np.int64) * 4,
    }


def csv_text(
    cols: dict[str, np.ndarray],
    order: Sequence[str] | None = None,
    meta: dict[str, str] | None = None,
) -> str:
    """CSV text of ``cols`` with the header in ``order`` and ``# key: value`` metadata."""
    names = list(order or cols)
    lines = [f"# {k}: {v}" for k, v in (meta or {}).items()]
    lines.append(",".join(names))
    n = len(next(iter(cols.values())))
    for i in range(n):
        lines.append(
            ",".join(
                repr(float(cols[c][i])) if cols[c].dtype.kind == "f" else str(int(cols[c][i]))
                for c in names
            )
        )
    return "\n".join(lines) + "\n"


def seed_csv(rng: np.random.Generator, n: int = 12) -> str:
    """A valid CSV log with metadata, columns in a shuffled order, optional columns."""
    cols = seed_columns(rng, n)
    names = list(COLUMNS[:7]) + [c for c in COLUMNS[7:] if rng.random() < 0.7]
    order = [names[i] for i in rng.permutation(len(names))]
    return csv_text(cols, order, {"sample_rate": "200", "device": "fuzz"})


def npz_bytes(arrays: dict[str, Any], compressed: bool = False) -> bytes:
    """An NPZ file's bytes holding ``arrays`` (object arrays are pickled, as numpy does)."""
    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return buf.getvalue()


def seed_npz(rng: np.random.Generator, n: int = 12, compressed: bool = False) -> bytes:
    """A valid NPZ log with a JSON meta array."""
    cols = seed_columns(rng, n)
    arrays: dict[str, Any] = {
        k: v for k, v in cols.items() if k in COLUMNS[:7] or rng.random() < 0.7
    }
    arrays["meta"] = np.array(json.dumps({"sample_rate": 200, "device": "fuzz"}))
    return npz_bytes(arrays, compressed)


# -- certificate loader ------------------------------------------------------------------------


def check_certificate(text: str) -> None:
    """The certificate loader on YAML ``text``."""
    try:
        cert = loads(text, source="fuzz.yaml")
    except CertificateError as exc:
        _require(bool(exc.key) and bool(exc.reason), f"CertificateError without key/reason: {exc}")
        return
    for triad in (cert.gyro, cert.accel):
        for name in ("scale_factor", "scale_factor_error", "bias"):
            v = getattr(triad, name)
            _require(v.shape == (3,) and bool(np.all(np.isfinite(v))), f"accepted bad {name}: {v}")
        _require(bool(np.all(triad.scale_factor > 0)), "accepted a non-positive scale factor")
        x = np.array([[0.1, -0.2, 0.3]])
        with np.errstate(all="ignore"):  # huge but finite accepted values may overflow
            u = triad.forward(x)
            _require(u.shape == (1, 3), "forward shape")
            triad.inverse(u)  # must not raise on an accepted certificate
    for v in (cert.gravity, cert.earth_rate, cert.sample_rate):
        _require(math.isfinite(v), f"accepted non-finite environment/sample_rate {v}")
    again = loads(cert.dumps(), source="fuzz-roundtrip.yaml")
    _require(again.to_dict() == cert.to_dict(), "certificate changes when written and read back")


def seed_certificate_doc() -> dict[str, Any]:
    """The bundled certificate as a YAML document (plain Python types)."""
    return yaml.safe_load(default_certificate_path().read_text(encoding="utf-8"))


def doc_paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key path of a nested dict/list document (containers and leaves)."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += doc_paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += doc_paths(v, prefix + (i,))
    return out


#: Replacement values for certificate fields.
BAD_VALUES: tuple[Any, ...] = (
    None,
    True,
    "x",
    "",
    [],
    {},
    [1.0, 2.0],
    [1.0, 2.0, 3.0, 4.0],
    [[1.0]],
    float("nan"),
    float("inf"),
    -float("inf"),
    0,
    -1,
    1e308,
    -1e308,
    5e-324,
    "1.0",
    10**400,
    {"a": 1},
    [None, None, None],
    ["a", "b", "c"],
    1e6,
    -1e6,
    "deg/s",
    "rad/s",
    "g",
    "m/s^2",
    0.5,
)

#: A certificate mutation: (op, path fraction, value index).
DocMutation = tuple[int, float, int]


def mutate_doc(doc: Any, ops: Sequence[DocMutation]) -> Any:
    """Structured mutations: replace a value, delete a key, add an unknown key, duplicate."""
    doc = copy.deepcopy(doc)
    for op, pf, vi in ops:
        paths = doc_paths(doc)
        path = paths[min(int(pf * len(paths)), len(paths) - 1)]
        value = copy.deepcopy(BAD_VALUES[vi % len(BAD_VALUES)])
        if not path:
            if op == 0:
                doc = value
            continue
        parent: Any = doc
        for k in path[:-1]:
            parent = parent[k]
        key = path[-1]
        if op == 0:
            parent[key] = value
        elif op == 1:
            del parent[key]
        elif op == 2 and isinstance(parent, dict):
            parent[f"unknown_{vi}"] = value
        elif op == 3 and isinstance(parent, list):
            parent.append(copy.deepcopy(parent[key]))
        elif (
            op == 4 and isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool)
        ):
            parent[key] = -parent[key] if vi % 2 else parent[key] * 1e12
    return doc


def dump_doc(doc: Any) -> str:
    """YAML text of a (possibly mutated) document; unrepresentable values become text."""
    try:
        return yaml.safe_dump(doc, sort_keys=False)
    except yaml.YAMLError:
        return repr(doc)


#: Every target by name: (check function taking bytes, description).
TARGETS: dict[str, tuple[Callable[[bytes], None], str]] = {
    "decoder": (lambda b: check_decoder(b, [len(b) // 3, len(b) // 2]), "wire frame decoder"),
    "csv": (lambda b: check_csv(b), "CSV log reader"),
    "npz": (lambda b: check_npz(b), "NPZ log reader"),
    "certificate": (
        lambda b: check_certificate(b.decode("utf-8", "replace")),
        "certificate loader",
    ),
}
