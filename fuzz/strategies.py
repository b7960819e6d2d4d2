"""Hypothesis strategies and properties for the fuzz targets (:mod:`fuzz.targets`).

Each property draws either arbitrary bytes/text or a valid seed input run
through drawn mutations, so both the rejection paths and the deep paths of a
nearly valid input are exercised; hypothesis shrinks a failure to a small case.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
from hypothesis import strategies as st

from .targets import (
    BAD_VALUES,
    COLUMNS,
    N_BYTE_OPS,
    N_TEXT_OPS,
    check_certificate,
    check_csv,
    check_decoder,
    check_npz,
    dump_doc,
    mutate_bytes,
    mutate_csv,
    mutate_doc,
    npz_bytes,
    seed_certificate_doc,
    seed_columns,
    seed_csv,
    seed_npz,
    seed_stream,
)

byte_ops = st.lists(
    st.tuples(
        st.integers(0, N_BYTE_OPS - 1), st.floats(0, 1), st.integers(0, 255), st.integers(1, 64)
    ),
    max_size=8,
)
text_ops = st.lists(
    st.tuples(
        st.integers(0, N_TEXT_OPS - 1), st.floats(0, 1), st.floats(0, 1), st.integers(0, 100)
    ),
    min_size=1,
    max_size=6,
)
doc_ops = st.lists(
    st.tuples(st.integers(0, 4), st.floats(0, 1), st.integers(0, len(BAD_VALUES) - 1)),
    min_size=1,
    max_size=4,
)
seeds = st.integers(0, 2**32 - 1)


# -- decoder ---------------------------------------------------------------------------


@st.composite
def decoder_inputs(draw: Callable[..., Any]) -> tuple[bytes, list[int]]:
    """Random bytes, or a board stream with byte mutations; plus chunk cut points."""
    if draw(st.booleans()):
        data = draw(st.binary(max_size=2000))
    else:
        rng = np.random.default_rng(draw(seeds))
        data = mutate_bytes(seed_stream(rng, draw(st.integers(1, 80))), draw(byte_ops))
    cuts = draw(st.lists(st.integers(0, max(len(data), 0)), max_size=12))
    return data, cuts


def prop_decoder(x: tuple[bytes, list[int]]) -> None:
    check_decoder(*x)


# -- CSV ---------------------------------------------------------------------------------


@st.composite
def csv_inputs(draw: Callable[..., Any]) -> tuple[bytes, int, bool]:
    """Random bytes, or a valid CSV log with text and byte mutations; block size; gzip."""
    kind = draw(st.integers(0, 3))
    if kind == 0:
        data = draw(st.binary(max_size=600))
    else:
        rng = np.random.default_rng(draw(seeds))
        text = seed_csv(rng, draw(st.integers(0, 12)))
        if kind >= 2:
            text = mutate_csv(text, draw(text_ops))
        data = text.encode("utf-8")
        if kind == 3:
            data = mutate_bytes(data, draw(byte_ops))
    return data, draw(st.integers(1, 5)), draw(st.booleans())


def prop_csv(x: tuple[bytes, int, bool]) -> None:
    check_csv(x[0], block_size=x[1], gz=x[2])


# -- NPZ ---------------------------------------------------------------------------------

_DTYPES = ("<f8", "<f4", ">f8", "<i8", "<i2", "|u1", "|b1", "<c16", "<U3", "O", "<m8[s]")


@st.composite
def npz_arrays(draw: Callable[..., Any]) -> dict[str, Any]:
    """Arrays for an NPZ log: valid columns with drawn breakage (dtype, shape, length, meta)."""
    rng = np.random.default_rng(draw(seeds))
    n = draw(st.integers(0, 10))
    cols: dict[str, Any] = dict(seed_columns(rng, n))
    for name in draw(st.lists(st.sampled_from(COLUMNS), max_size=3)):
        op = draw(st.integers(0, 5))
        if op == 0:
            cols.pop(name, None)
        elif op == 1 and name in cols:
            dt = draw(st.sampled_from(_DTYPES))
            try:
                with np.errstate(all="ignore"), warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    cols[name] = np.asarray(cols[name]).astype(dt)
            except (TypeError, ValueError, OverflowError):
                cols[name] = np.asarray(cols[name]).astype(str)
        elif op == 2 and name in cols:
            cols[name] = np.asarray(cols[name])[: max(n - 1, 0)]
        elif op == 3 and name in cols:
            cols[name] = np.asarray(cols[name]).reshape(-1, 1)
        elif op == 4 and name in cols and np.size(cols[name]):
            with warnings.catch_warnings():  # complex -> float drops the imaginary part
                warnings.simplefilter("ignore")
                arr = np.array(cols[name], dtype=float).reshape(-1)
            arr[draw(st.integers(0, arr.size - 1))] = draw(
                st.sampled_from([np.nan, np.inf, -1.0, 1e300])
            )
            cols[name] = arr
        elif op == 5:
            cols[name + draw(st.sampled_from(["", "_x", ".npy"]))] = np.zeros(3)
    meta_kind = draw(st.integers(0, 4))
    if meta_kind == 1:
        cols["meta"] = np.array(json.dumps({"sample_rate": 200}))
    elif meta_kind == 2:
        cols["meta"] = np.array("{not json")
    elif meta_kind == 3:
        cols["meta"] = np.array([1, 2, 3])
    elif meta_kind == 4:
        cols["meta"] = np.array(json.dumps([1, 2]).encode())
    return cols


@st.composite
def npz_inputs(draw: Callable[..., Any]) -> tuple[bytes, int]:
    """An NPZ made from drawn arrays, or a valid one with byte mutations, or random bytes."""
    kind = draw(st.integers(0, 2))
    if kind == 0:
        data = npz_bytes(draw(npz_arrays()), draw(st.booleans()))
    elif kind == 1:
        rng = np.random.default_rng(draw(seeds))
        data = mutate_bytes(
            seed_npz(rng, draw(st.integers(1, 10)), draw(st.booleans())), draw(byte_ops)
        )
    else:
        data = draw(st.binary(max_size=400))
    return data, draw(st.integers(1, 5))


def prop_npz(x: tuple[bytes, int]) -> None:
    check_npz(x[0], block_size=x[1])


# -- certificate ----------------------------------------------------------------------------


@st.composite
def certificate_inputs(draw: Callable[..., Any]) -> str:
    """A certificate with structured mutations, YAML text with byte mutations, or any text."""
    kind = draw(st.integers(0, 2))
    if kind == 0:
        return dump_doc(mutate_doc(seed_certificate_doc(), draw(doc_ops)))
    if kind == 1:
        text = dump_doc(seed_certificate_doc()).encode("utf-8")
        return mutate_bytes(text, draw(byte_ops)).decode("utf-8", "replace")
    return draw(st.text(max_size=300))


def prop_certificate(text: str) -> None:
    check_certificate(text)


#: name -> (strategy, property, example bytes of a failure for the crash file)
PROPERTIES: dict[str, tuple[Any, Callable[[Any], None], Callable[[Any], bytes]]] = {
    "decoder": (decoder_inputs(), prop_decoder, lambda x: x[0]),
    "csv": (csv_inputs(), prop_csv, lambda x: x[0]),
    "npz": (npz_inputs(), prop_npz, lambda x: x[0]),
    "certificate": (certificate_inputs(), prop_certificate, lambda x: x.encode("utf-8")),
}
